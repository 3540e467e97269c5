//! Settings files: `face track --config FILE`, `body track --config FILE` and
//! `streampf config --print-default`.
//!
//! A settings file is TOML with one table per tracker, `[face]` for `face track` and `[body]` for
//! `body track`; its keys are the long options' names as the command line spells them
//! (`particles = 2000`, `detect-every = 3`, `backend = "gpu"`, `detect = true`). The file is
//! turned into those options and handed to clap with the command line's, so a setting is checked
//! by exactly the rules of its flag, and every flag is a setting without a second list to keep.
//! An option given on the command line wins over the file, and so does one that conflicts with
//! it (an input named on the command line drops the file's `synthetic = true`).

use std::ffi::OsString;
use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use clap::parser::ValueSource;
use clap::{ArgAction, ArgMatches, Command};

/// The tables of a settings file and the `track` command each one configures.
pub const SECTIONS: [&str; 2] = ["face", "body"];

/// The command that a table configures: `streampf SECTION track`.
fn track_command<'a>(root: &'a Command, section: &str) -> Option<&'a Command> {
    root.find_subcommand(section)?.find_subcommand("track")
}

/// Options that are not settings: the file itself, help.
fn is_setting(arg: &clap::Arg) -> bool {
    let id = arg.get_id().as_str();
    arg.get_long().is_some() && id != "config" && id != "help" && id != "version"
}

/// The command line with the settings of a `--config FILE` added.
pub struct WithSettings {
    pub argv: Vec<OsString>,
    /// The settings file that was read, if any.
    pub file: Option<PathBuf>,
}

/// Returns the command line with the settings of `--config FILE` added, when `face track` or
/// `body track` was given one; otherwise the command line as it was.
///
/// `root` is the program's whole command. Parsing errors of the command line itself are left
/// to the caller's strict parse.
pub fn with_config_file(root: &Command, argv: Vec<OsString>) -> anyhow::Result<WithSettings> {
    let unchanged = |argv| Ok(WithSettings { argv, file: None });
    let Ok(matches) = root.clone().ignore_errors(true).try_get_matches_from(&argv) else {
        return unchanged(argv);
    };
    let Some((section, section_matches)) = matches.subcommand() else {
        return unchanged(argv);
    };
    let Some(("track", track_matches)) = section_matches.subcommand() else {
        return unchanged(argv);
    };
    let Some(command) = track_command(root, section) else {
        return unchanged(argv);
    };
    let Ok(Some(path)) = track_matches.try_get_one::<PathBuf>("config") else {
        return unchanged(argv);
    };
    let table = read_settings(root, path)?;
    let Some(settings) = table.get(section) else {
        bail!(
            "{} has no [{section}] table: the settings of `{section} track` go there",
            path.display()
        );
    };
    let options = options_from_table(command, settings, track_matches)
        .with_context(|| format!("in [{section}] of {}", path.display()))?;
    Ok(WithSettings {
        argv: insert_after_subcommand(argv, &[section, "track"], options),
        file: Some(path.clone()),
    })
}

/// Reads and checks a settings file: TOML, known tables only, and in each table known keys
/// only (whichever table the command at hand uses, so that a typo anywhere is reported).
pub fn read_settings(root: &Command, path: &Path) -> anyhow::Result<toml::Table> {
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("cannot read the settings file {}", path.display()))?;
    let table: toml::Table = text
        .parse()
        .with_context(|| format!("{} is not valid TOML", path.display()))?;
    for (section, value) in &table {
        let Some(command) = track_command(root, section).filter(|_| SECTIONS.contains(&&**section))
        else {
            bail!(
                "{}: unknown table [{section}] (the tables are {})",
                path.display(),
                SECTIONS.map(|s| format!("[{s}]")).join(", ")
            );
        };
        let Some(settings) = value.as_table() else {
            bail!(
                "{}: `{section}` must be a table, [{section}]",
                path.display()
            );
        };
        for key in settings.keys() {
            if !command
                .get_arguments()
                .any(|a| is_setting(a) && a.get_long() == Some(key))
            {
                bail!(
                    "{}: unknown setting `{key}` in [{section}] (the settings are the long \
                     options of `streampf {section} track`; `streampf config --print-default` \
                     lists them)",
                    path.display()
                );
            }
        }
    }
    Ok(table)
}

/// The command-line options that a table stands for, leaving out those the command line gives
/// itself or contradicts.
fn options_from_table(
    command: &Command,
    settings: &toml::Value,
    given: &ArgMatches,
) -> anyhow::Result<Vec<OsString>> {
    let on_command_line = |arg: &clap::Arg| {
        given.value_source(arg.get_id().as_str()) == Some(ValueSource::CommandLine)
    };
    let mut options = Vec::new();
    let Some(settings) = settings.as_table() else {
        return Ok(options);
    };
    for (key, value) in settings {
        let Some(arg) = command
            .get_arguments()
            .find(|a| is_setting(a) && a.get_long() == Some(key))
        else {
            bail!("unknown setting `{key}`");
        };
        // Conflicts are declared on either side (the input conflicts with --synthetic).
        let conflicts = |a: &clap::Arg, b: &clap::Arg| {
            command
                .get_arg_conflicts_with(a)
                .iter()
                .any(|c| c.get_id() == b.get_id())
        };
        let overridden = on_command_line(arg)
            || command
                .get_arguments()
                .filter(|other| on_command_line(other))
                .any(|other| conflicts(arg, other) || conflicts(other, arg));
        if overridden {
            continue;
        }
        let flag = matches!(arg.get_action(), ArgAction::SetTrue);
        let is_list = matches!(value, toml::Value::Array(_));
        let values: Vec<&toml::Value> = match value {
            toml::Value::Array(items) => items.iter().collect(),
            single => vec![single],
        };
        for value in values {
            match (flag, value) {
                (true, toml::Value::Boolean(true)) => options.push(format!("--{key}").into()),
                (true, toml::Value::Boolean(false)) => {}
                (true, other) => bail!("`{key}` is a switch: true or false, not {other}"),
                (false, value) => {
                    check_value_type(key, arg, value)?;
                    let text = match value {
                        toml::Value::String(text) => text.clone(),
                        other => other.to_string(),
                    };
                    // A default changes nothing, and given explicitly it would trip an option
                    // that requires another (`--lag-smoother` needs `--smooth-lag`).
                    let defaults = arg.get_default_values();
                    if !is_list && defaults.len() == 1 && defaults[0].to_string_lossy() == text {
                        continue;
                    }
                    options.push(format!("--{key}={text}").into());
                }
            }
        }
    }
    Ok(options)
}

/// What TOML type a setting's value must have: the type its option parses into. A number
/// written as a string (`particles = "200"`) or a path written as a number (`out = 5`) is a
/// mistake in the file, reported as one instead of being read as the text it would be on a
/// command line.
fn check_value_type(key: &str, arg: &clap::Arg, value: &toml::Value) -> anyhow::Result<()> {
    use std::any::TypeId;
    let parses_into = arg.get_value_parser().type_id();
    let integer = [
        TypeId::of::<u8>(),
        TypeId::of::<u16>(),
        TypeId::of::<u32>(),
        TypeId::of::<u64>(),
        TypeId::of::<usize>(),
        TypeId::of::<i32>(),
        TypeId::of::<i64>(),
    ]
    .into_iter()
    .any(|t| parses_into == t);
    let float = parses_into == TypeId::of::<f32>() || parses_into == TypeId::of::<f64>();
    let switch = parses_into == TypeId::of::<bool>();
    // An option that takes a number or a word (`--scene-cut 0.25` or `off`) takes either.
    let number_or_word = parses_into == TypeId::of::<crate::face::SceneCutArg>();
    let fits = match value {
        toml::Value::Integer(_) => integer || float || number_or_word,
        toml::Value::Float(_) => float || number_or_word,
        toml::Value::Boolean(_) => switch,
        toml::Value::String(_) => !(integer || float || switch),
        _ => false,
    };
    if fits {
        return Ok(());
    }
    let expected = if integer {
        "a whole number"
    } else if float {
        "a number"
    } else if number_or_word {
        "a number or text in quotes"
    } else if switch {
        "true or false"
    } else {
        "text in quotes"
    };
    bail!("`{key}` takes {expected}, not {value}")
}

/// Puts `options` straight after the subcommand's own name (`face track`), ahead of anything
/// the user typed after it, `--` and positional inputs included.
fn insert_after_subcommand(
    mut argv: Vec<OsString>,
    path: &[&str],
    options: Vec<OsString>,
) -> Vec<OsString> {
    let mut at = 1;
    for name in path {
        match argv[at.min(argv.len())..].iter().position(|a| a == name) {
            Some(offset) => at += offset + 1,
            None => return argv,
        }
    }
    argv.splice(at..at, options);
    argv
}

/// Every setting of every table with its default, as a TOML file; options without a default
/// are written as comments. `streampf config --print-default`.
pub fn default_settings(root: &Command) -> String {
    let mut text = String::from(
        "# streampf settings: `streampf face track --config FILE` reads [face],\n\
         # `streampf body track --config FILE` reads [body]. Keys are the long options' names;\n\
         # options on the command line win. Unknown keys are errors.\n",
    );
    for section in SECTIONS {
        let Some(command) = track_command(root, section) else {
            continue;
        };
        text.push_str(&format!("\n[{section}]\n"));
        for arg in command
            .get_arguments()
            .filter(|a| is_setting(a) && !a.is_hide_set())
        {
            let Some(key) = arg.get_long() else { continue };
            if let Some(help) = arg.get_help() {
                push_comment(&mut text, &help.to_string());
            }
            let defaults: Vec<String> = arg
                .get_default_values()
                .iter()
                .map(|v| toml_literal(&v.to_string_lossy()))
                .collect();
            match (defaults.as_slice(), arg.get_action()) {
                ([], ArgAction::SetTrue) => text.push_str(&format!("{key} = false\n")),
                ([one], _) => text.push_str(&format!("{key} = {one}\n")),
                ([], ArgAction::Append) => {
                    text.push_str(&format!("# {key} = []  (none by default)\n"))
                }
                ([], _) => text.push_str(&format!("# {key} =  (unset by default)\n")),
                (many, _) => text.push_str(&format!("{key} = [{}]\n", many.join(", "))),
            }
        }
    }
    text
}

/// Appends `help` as comment lines of at most about 96 characters.
fn push_comment(text: &mut String, help: &str) {
    let mut line = String::from("#");
    for word in help.split_whitespace() {
        if line.len() + word.len() > 95 && line.len() > 1 {
            text.push_str(&line);
            text.push('\n');
            line = String::from("#");
        }
        line.push(' ');
        line.push_str(word);
    }
    text.push_str(&line);
    text.push('\n');
}

/// A default value as TOML writes it: numbers and booleans bare, everything else a string.
fn toml_literal(text: &str) -> String {
    if text == "true" || text == "false" || text.parse::<i64>().is_ok() {
        return text.to_string();
    }
    match text.parse::<f64>() {
        Ok(x) if x.is_finite() && text.contains('.') => text.to_string(),
        _ => toml::Value::String(text.to_string()).to_string(),
    }
}
