//! `cargo xtask structure`: the shape of the code, checked from its syntax (syn).
//!
//! - **Import circles**: files that import each other, directly or around a loop. A file
//!   imports another when it names one of that file's items through a `crate::` or `super::`
//!   path (in a `use` or in code); a module and the modules inside it count as one, so a parent
//!   re-exporting its child's items and the child using its parent's are not a circle.
//! - **Long files**: over [`MAX_FILE_LINES`] lines, not counting `#[cfg(test)]` modules; a file
//!   that is mostly constant tables is data, not code, and is not counted.
//! - **Long functions**: over [`MAX_FN_LINES`] lines, outside tests.
//!
//! Library and binary sources are checked (`crates/*/src`, `xtask/src`); tests, benches and
//! examples are not. What is still over the limits is listed, one finding a line, in
//! `xtask/structure-allowed.txt`: the check fails on a finding that is not listed (so nothing
//! new goes over) and on a listed one that is gone (so the list only shrinks).

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use syn::spanned::Spanned;
use syn::visit::Visit;

/// The most lines a source file may have, tests aside.
pub const MAX_FILE_LINES: usize = 600;
/// The most lines a function may have, outside tests.
pub const MAX_FN_LINES: usize = 80;
/// A file whose constant and static items fill this share of its lines is a data table.
const DATA_TABLE_SHARE: f64 = 0.8;

const ALLOWED: &str = "xtask/structure-allowed.txt";

pub fn structure(root: &Path, args: &[String]) -> anyhow::Result<()> {
    let mut write_allowed = false;
    for a in args {
        match a.as_str() {
            // Rewrites the list from today's findings (after a change that removes some).
            "--write-allowed" => write_allowed = true,
            other => bail!("unknown option {other:?} for `structure` (it takes --write-allowed)"),
        }
    }
    let mut findings = BTreeSet::new();
    for krate in crate_roots(root)? {
        findings.extend(check_crate(root, &krate)?);
    }
    let allowed_path = root.join(ALLOWED);
    if write_allowed {
        let mut text = String::from(
            "# Findings of `cargo xtask structure` still to fix (see xtask/src/structure.rs).\n",
        );
        for f in &findings {
            text.push_str(f);
            text.push('\n');
        }
        std::fs::write(&allowed_path, text)?;
        println!("structure: wrote {} findings to {ALLOWED}", findings.len());
        return Ok(());
    }
    let allowed: BTreeSet<String> = std::fs::read_to_string(&allowed_path)
        .unwrap_or_default()
        .lines()
        .filter(|l| !l.trim().is_empty() && !l.starts_with('#'))
        .map(str::to_string)
        .collect();
    let new: Vec<_> = findings.difference(&allowed).collect();
    let gone: Vec<_> = allowed.difference(&findings).collect();
    for f in &new {
        eprintln!("structure: {f}");
    }
    for f in &gone {
        eprintln!("structure: fixed, remove it from {ALLOWED}: {f}");
    }
    if !new.is_empty() || !gone.is_empty() {
        bail!(
            "{} new finding(s), {} listed finding(s) gone (limits: {MAX_FILE_LINES} lines a file, \
             {MAX_FN_LINES} a function, no import circles)",
            new.len(),
            gone.len()
        );
    }
    println!(
        "structure: no import circle, file or function over the limits beyond the {} listed in \
         {ALLOWED}",
        allowed.len()
    );
    Ok(())
}

/// A crate's source folder and its root files (lib.rs and main.rs are separate crates).
struct CrateSource {
    src: PathBuf,
}

fn crate_roots(root: &Path) -> anyhow::Result<Vec<CrateSource>> {
    let mut roots = vec![CrateSource {
        src: root.join("xtask/src"),
    }];
    let mut crates: Vec<_> = std::fs::read_dir(root.join("crates"))?
        .flatten()
        .map(|e| e.path().join("src"))
        .filter(|p| p.is_dir())
        .collect();
    crates.sort();
    roots.extend(crates.into_iter().map(|src| CrateSource { src }));
    Ok(roots)
}

/// A source file: its path from the workspace root and its module path in its crate.
struct SourceFile {
    shown: String,
    module: Vec<String>,
    syntax: syn::File,
    lines: usize,
}

fn check_crate(root: &Path, krate: &CrateSource) -> anyhow::Result<Vec<String>> {
    let mut files = Vec::new();
    for path in rust_files(&krate.src)? {
        let text = std::fs::read_to_string(&path)?;
        let syntax =
            syn::parse_file(&text).with_context(|| format!("parsing {}", path.display()))?;
        let relative = path.strip_prefix(&krate.src).unwrap_or(&path);
        files.push(SourceFile {
            shown: path
                .strip_prefix(root)
                .unwrap_or(&path)
                .display()
                .to_string(),
            module: module_path(relative),
            syntax,
            lines: text.lines().count(),
        });
    }
    let mut findings = Vec::new();
    for file in &files {
        findings.extend(long_file(file));
        findings.extend(long_functions(file));
    }
    findings.extend(import_circles(&files));
    Ok(findings)
}

fn rust_files(dir: &Path) -> anyhow::Result<Vec<PathBuf>> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for entry in std::fs::read_dir(&d)?.flatten() {
            let p = entry.path();
            if p.is_dir() {
                stack.push(p);
            } else if p.extension().is_some_and(|e| e == "rs") {
                out.push(p);
            }
        }
    }
    out.sort();
    Ok(out)
}

/// `a/b.rs` → [a, b]; `a/mod.rs` → [a]; `lib.rs`, `main.rs` → [] (and `bin/x.rs` → [bin, x],
/// which is never imported).
fn module_path(relative: &Path) -> Vec<String> {
    let mut parts: Vec<String> = relative
        .iter()
        .map(|p| p.to_string_lossy().trim_end_matches(".rs").to_string())
        .collect();
    if matches!(
        parts.last().map(String::as_str),
        Some("mod" | "lib" | "main")
    ) {
        parts.pop();
    }
    parts
}

fn is_cfg_test(attrs: &[syn::Attribute]) -> bool {
    attrs.iter().any(|a| {
        (a.path().is_ident("cfg") || a.path().is_ident("test"))
            && a.meta
                .require_list()
                .map_or(a.path().is_ident("test"), |l| {
                    l.tokens.to_string() == "test"
                })
    })
}

fn line_span(node: &impl Spanned) -> usize {
    let span = node.span();
    span.end().line.saturating_sub(span.start().line) + 1
}

fn long_file(file: &SourceFile) -> Option<String> {
    let mut test_lines = 0;
    let mut table_lines = 0;
    for item in &file.syntax.items {
        match item {
            syn::Item::Mod(m) if is_cfg_test(&m.attrs) => test_lines += line_span(m),
            syn::Item::Const(c) => table_lines += line_span(c),
            syn::Item::Static(s) => table_lines += line_span(s),
            _ => {}
        }
    }
    let code = file.lines.saturating_sub(test_lines);
    let is_table = table_lines as f64 >= DATA_TABLE_SHARE * code as f64;
    (code > MAX_FILE_LINES && !is_table).then(|| format!("file-lines {}", file.shown))
}

/// Every function (free, in an impl or a trait with a body) outside test code.
struct Functions<'a> {
    file: &'a str,
    context: Vec<String>,
    found: Vec<String>,
}

impl Functions<'_> {
    fn check(&mut self, name: &syn::Ident, attrs: &[syn::Attribute], node: &impl Spanned) {
        if !is_cfg_test(attrs) && line_span(node) > MAX_FN_LINES {
            let mut path = self.context.clone();
            path.push(name.to_string());
            self.found
                .push(format!("fn-lines {}::{}", self.file, path.join("::")));
        }
    }
}

impl<'ast> Visit<'ast> for Functions<'_> {
    fn visit_item_mod(&mut self, m: &'ast syn::ItemMod) {
        if !is_cfg_test(&m.attrs) {
            self.context.push(m.ident.to_string());
            syn::visit::visit_item_mod(self, m);
            self.context.pop();
        }
    }
    fn visit_item_fn(&mut self, f: &'ast syn::ItemFn) {
        self.check(&f.sig.ident, &f.attrs, f);
    }
    fn visit_item_impl(&mut self, i: &'ast syn::ItemImpl) {
        if is_cfg_test(&i.attrs) {
            return;
        }
        let ty = &i.self_ty;
        self.context.push(quote_type(ty));
        syn::visit::visit_item_impl(self, i);
        self.context.pop();
    }
    fn visit_impl_item_fn(&mut self, f: &'ast syn::ImplItemFn) {
        self.check(&f.sig.ident, &f.attrs, f);
    }
    fn visit_trait_item_fn(&mut self, f: &'ast syn::TraitItemFn) {
        if f.default.is_some() {
            self.check(&f.sig.ident, &f.attrs, f);
        }
    }
}

/// A type's last path segment (`Foo` of `crate::a::Foo<T>`), to name an impl's functions.
fn quote_type(ty: &syn::Type) -> String {
    match ty {
        syn::Type::Path(p) => p
            .path
            .segments
            .last()
            .map_or_else(|| "_".into(), |s| s.ident.to_string()),
        _ => "_".into(),
    }
}

fn long_functions(file: &SourceFile) -> Vec<String> {
    let mut visitor = Functions {
        file: &file.shown,
        context: Vec::new(),
        found: Vec::new(),
    };
    visitor.visit_file(&file.syntax);
    visitor.found
}

/// The module paths a file names through `crate::` and `super::` (absolute, from the crate root).
struct Imports {
    here: Vec<String>,
    found: BTreeSet<Vec<String>>,
}

impl Imports {
    /// An absolute module path for `segments` (as written), or `None` if it is not relative to
    /// this crate.
    fn resolve(&self, segments: &[String]) -> Option<Vec<String>> {
        let first = segments.first()?;
        if first == "crate" {
            return Some(segments[1..].to_vec());
        }
        if first == "super" {
            let mut base = self.here.clone();
            let mut rest = segments;
            while rest.first().is_some_and(|s| s == "super") {
                base.pop()?;
                rest = &rest[1..];
            }
            base.extend(rest.iter().cloned());
            return Some(base);
        }
        None
    }

    fn add(&mut self, segments: Vec<String>) {
        if let Some(path) = self.resolve(&segments) {
            self.found.insert(path);
        }
    }

    fn use_tree(&mut self, prefix: &mut Vec<String>, tree: &syn::UseTree) {
        match tree {
            syn::UseTree::Path(p) => {
                prefix.push(p.ident.to_string());
                self.use_tree(prefix, &p.tree);
                prefix.pop();
            }
            syn::UseTree::Name(n) => {
                let mut path = prefix.clone();
                path.push(n.ident.to_string());
                self.add(path);
            }
            syn::UseTree::Rename(r) => {
                let mut path = prefix.clone();
                path.push(r.ident.to_string());
                self.add(path);
            }
            syn::UseTree::Glob(_) => self.add(prefix.clone()),
            syn::UseTree::Group(g) => {
                for t in &g.items {
                    self.use_tree(prefix, t);
                }
            }
        }
    }
}

impl<'ast> Visit<'ast> for Imports {
    fn visit_item_mod(&mut self, m: &'ast syn::ItemMod) {
        // Inline modules other than tests are rare; their `super` would be this file's module.
        if !is_cfg_test(&m.attrs) {
            syn::visit::visit_item_mod(self, m);
        }
    }
    fn visit_item_use(&mut self, u: &'ast syn::ItemUse) {
        if !is_cfg_test(&u.attrs) {
            self.use_tree(&mut Vec::new(), &u.tree);
        }
    }
    fn visit_path(&mut self, p: &'ast syn::Path) {
        let segments: Vec<String> = p.segments.iter().map(|s| s.ident.to_string()).collect();
        self.add(segments);
        syn::visit::visit_path(self, p);
    }
}

/// One finding per set of files that import each other (a strongly connected component of the
/// import graph with more than one file).
fn import_circles(files: &[SourceFile]) -> Vec<String> {
    let by_module: BTreeMap<&[String], usize> = files
        .iter()
        .enumerate()
        .map(|(i, f)| (f.module.as_slice(), i))
        .collect();
    let mut edges: Vec<BTreeSet<usize>> = vec![BTreeSet::new(); files.len()];
    for (i, file) in files.iter().enumerate() {
        let mut imports = Imports {
            here: file.module.clone(),
            found: BTreeSet::new(),
        };
        imports.visit_file(&file.syntax);
        for path in imports.found {
            // The file of the deepest module the path names.
            let target = (0..=path.len())
                .rev()
                .find_map(|n| by_module.get(&path[..n]).copied());
            let Some(j) = target else { continue };
            let (a, b) = (&file.module, &files[j].module);
            let nested = a.starts_with(b) || b.starts_with(a);
            if j != i && !nested {
                edges[i].insert(j);
            }
        }
    }
    strongly_connected(&edges)
        .into_iter()
        .filter(|c| c.len() > 1)
        .map(|c| {
            let mut names: Vec<&str> = c.iter().map(|&i| files[i].shown.as_str()).collect();
            names.sort();
            format!("import-circle {}", names.join(" "))
        })
        .collect()
}

/// Tarjan's strongly connected components.
fn strongly_connected(edges: &[BTreeSet<usize>]) -> Vec<Vec<usize>> {
    struct State<'a> {
        edges: &'a [BTreeSet<usize>],
        index: Vec<Option<usize>>,
        low: Vec<usize>,
        on_stack: Vec<bool>,
        stack: Vec<usize>,
        next: usize,
        out: Vec<Vec<usize>>,
    }
    fn visit(s: &mut State, v: usize) {
        s.index[v] = Some(s.next);
        s.low[v] = s.next;
        s.next += 1;
        s.stack.push(v);
        s.on_stack[v] = true;
        for &w in s.edges[v].iter() {
            match s.index[w] {
                None => {
                    visit(s, w);
                    s.low[v] = s.low[v].min(s.low[w]);
                }
                Some(iw) if s.on_stack[w] => s.low[v] = s.low[v].min(iw),
                _ => {}
            }
        }
        if Some(s.low[v]) == s.index[v] {
            let mut component = Vec::new();
            while let Some(w) = s.stack.pop() {
                s.on_stack[w] = false;
                component.push(w);
                if w == v {
                    break;
                }
            }
            s.out.push(component);
        }
    }
    let n = edges.len();
    let mut s = State {
        edges,
        index: vec![None; n],
        low: vec![0; n],
        on_stack: vec![false; n],
        stack: Vec::new(),
        next: 0,
        out: Vec::new(),
    };
    for v in 0..n {
        if s.index[v].is_none() {
            visit(&mut s, v);
        }
    }
    s.out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn file(module: &[&str], code: &str) -> SourceFile {
        SourceFile {
            shown: format!("{}.rs", module.join("/")),
            module: module.iter().map(|s| s.to_string()).collect(),
            syntax: syn::parse_file(code).unwrap(),
            lines: code.lines().count(),
        }
    }

    #[test]
    fn two_siblings_that_import_each_other_are_a_circle() {
        let files = [
            file(&["a"], "use crate::b::B; pub struct A;"),
            file(&["b"], "pub struct B; fn f() -> super::a::A { todo!() }"),
            file(&["c"], "use crate::a::A;"),
        ];
        assert_eq!(import_circles(&files), ["import-circle a.rs b.rs"]);
    }

    #[test]
    fn a_parent_and_its_child_are_not_a_circle() {
        let files = [
            file(&["a"], "mod child; pub use child::C; pub struct A;"),
            file(&["a", "child"], "use super::A; pub struct C;"),
        ];
        assert!(import_circles(&files).is_empty());
    }

    #[test]
    fn a_loop_of_three_is_one_circle_and_tests_do_not_count() {
        let files = [
            file(&["a"], "use crate::b::B;"),
            file(&["b"], "use crate::c::C;"),
            file(&["c"], "use crate::a::A;"),
            file(&["d"], "#[cfg(test)] mod tests { use crate::e::E; }"),
            file(&["e"], "use crate::d::D;"),
        ];
        assert_eq!(import_circles(&files), ["import-circle a.rs b.rs c.rs"]);
    }

    #[test]
    fn long_functions_and_files_are_found_outside_tests() {
        let body = "let x = 1;\n".repeat(MAX_FN_LINES);
        let code = format!(
            "fn long() {{\n{body}}}\nfn short() {{}}\nimpl S {{ fn method() {{\n{body}}} }}\n\
             #[cfg(test)] mod tests {{ fn long_test() {{\n{body}}} }}\n"
        );
        let f = file(&["m"], &code);
        assert_eq!(
            long_functions(&f),
            ["fn-lines m.rs::long", "fn-lines m.rs::S::method"]
        );
        assert_eq!(long_file(&f), None);
        let many = "fn f() {}\n".repeat(MAX_FILE_LINES + 1);
        assert_eq!(long_file(&file(&["m"], &many)).unwrap(), "file-lines m.rs");
        let table = format!(
            "const T: [u8; 2] = [\n{}];\n",
            "0,\n".repeat(MAX_FILE_LINES)
        );
        assert_eq!(long_file(&file(&["m"], &table)), None);
    }
}
