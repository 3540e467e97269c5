//! WGSL kernels: sources from `shaders/` (include_str!), checked by naga, built into pipelines.

use crate::context::GpuContext;
use crate::error::GpuError;

/// The WGSL files of the generic stages. `PHILOX` and `COMMON` are libraries prepended to the
/// stage files (see [`stage_source`]).
pub mod sources {
    /// Philox4x32-10 and counter-based Gaussians (a library).
    pub const PHILOX: &str = include_str!("../../../shaders/philox.wgsl");
    /// `Params`, `TargetStats` and helpers shared by the stages (a library).
    pub const COMMON: &str = include_str!("../../../shaders/common.wgsl");
    /// The diffusion stage.
    pub const DIFFUSE: &str = include_str!("../../../shaders/diffuse.wgsl");
    /// The normalisation stage.
    pub const NORMALISE: &str = include_str!("../../../shaders/normalise.wgsl");
    /// The resamplers.
    pub const RESAMPLE: &str = include_str!("../../../shaders/resample.wgsl");
    /// The gather stage.
    pub const GATHER: &str = include_str!("../../../shaders/gather.wgsl");
    /// The estimates.
    pub const ESTIMATE: &str = include_str!("../../../shaders/estimate.wgsl");
    /// The hand-written toy likelihood.
    pub const TOY_LIKELIHOOD: &str = include_str!("../../../shaders/toy_likelihood.wgsl");
    /// Philox blocks and Gaussian draws for the bit-exact tests.
    pub const RANDOM: &str = include_str!("../../../shaders/random.wgsl");
    /// The body paper's capsule likelihood (paper layout and fast kernel).
    pub const CAPSULE_LIKELIHOOD: &str = include_str!("../../../shaders/capsule_likelihood.wgsl");
    /// The body's forward kinematics and log-likelihood.
    pub const BODY_KINEMATICS: &str = include_str!("../../../shaders/body_kinematics.wgsl");
    /// The face likelihood.
    pub const FACE_LIKELIHOOD: &str = include_str!("../../../shaders/face_likelihood.wgsl");
    /// The Viola–Jones detector (its launcher is `face_tracker::detect::gpu`).
    pub const HAAR_CASCADE: &str = include_str!("../../../shaders/haar_cascade.wgsl");

    /// Every stage file, by name, for the validation tests.
    pub const STAGES: [(&str, &str); 7] = [
        ("toy_likelihood.wgsl", TOY_LIKELIHOOD),
        ("face_likelihood.wgsl", FACE_LIKELIHOOD),
        ("diffuse.wgsl", DIFFUSE),
        ("normalise.wgsl", NORMALISE),
        ("resample.wgsl", RESAMPLE),
        ("gather.wgsl", GATHER),
        ("estimate.wgsl", ESTIMATE),
    ];
}

/// A stage file with the libraries it uses prepended.
pub fn stage_source(stage: &str) -> String {
    [sources::PHILOX, sources::COMMON, stage].join("\n")
}

/// Parses and validates WGSL with naga (the one wgpu uses); the error names line and column.
pub fn validate_wgsl(source: &str) -> Result<(), String> {
    use wgpu::naga;
    let module = naga::front::wgsl::parse_str(source).map_err(|e| e.emit_to_string(source))?;
    naga::valid::Validator::new(
        naga::valid::ValidationFlags::all(),
        naga::valid::Capabilities::all(),
    )
    .validate(&module)
    .map_err(|e| e.emit_to_string(source))?;
    Ok(())
}

/// The size and each member's (name, offset) of the WGSL struct `name` in `source`, laid out by
/// naga as the GPU lays it out.
pub fn wgsl_struct_layout(source: &str, name: &str) -> Result<(u32, Vec<(String, u32)>), String> {
    use wgpu::naga;
    let module = naga::front::wgsl::parse_str(source).map_err(|e| e.emit_to_string(source))?;
    let mut layouter = naga::proc::Layouter::default();
    layouter
        .update(module.to_ctx())
        .map_err(|e| e.to_string())?;
    let (handle, ty) = module
        .types
        .iter()
        .find(|(_, t)| t.name.as_deref() == Some(name))
        .ok_or_else(|| format!("no struct {name}"))?;
    let naga::TypeInner::Struct { members, .. } = &ty.inner else {
        return Err(format!("{name} is not a struct"));
    };
    let fields = members
        .iter()
        .map(|m| (m.name.clone().unwrap_or_default(), m.offset))
        .collect();
    Ok((layouter[handle].size, fields))
}

/// Test helper: the Rust mirror of a WGSL struct has its size, and each WGSL member (padding
/// aside) sits at the offset of the Rust field of the same name (`fields`: name, `offset_of!`).
#[cfg(test)]
pub(crate) fn assert_mirrors_wgsl(
    source: &str,
    name: &str,
    rust_size: usize,
    fields: &[(&str, usize)],
) {
    let (size, members) = wgsl_struct_layout(source, name).unwrap();
    assert_eq!(
        size as usize, rust_size,
        "struct {name}: WGSL size {size}, Rust {rust_size}"
    );
    for (member, offset) in members.iter().filter(|(m, _)| !m.starts_with("_pad")) {
        let rust = fields
            .iter()
            .find(|(f, _)| f == member)
            .unwrap_or_else(|| panic!("{name}.{member} has no Rust field of that name"));
        assert_eq!(
            *offset as usize, rust.1,
            "{name}.{member}: WGSL offset {offset}, Rust {}",
            rust.1
        );
    }
}

/// One compute entry point built into a pipeline, with the layout of its bind group 0.
#[derive(Debug)]
pub struct Kernel {
    name: String,
    pipeline: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
}

impl Kernel {
    /// Builds `entry` of `source`. Invalid WGSL is a [`GpuError::Shader`] with naga's message.
    pub fn new(ctx: &GpuContext, name: &str, source: &str, entry: &str) -> Result<Self, GpuError> {
        validate_wgsl(source).map_err(|message| GpuError::Shader {
            kernel: name.to_string(),
            message,
        })?;
        let built = ctx.scoped(&format!("building kernel {name}"), || {
            let module = ctx
                .device
                .create_shader_module(wgpu::ShaderModuleDescriptor {
                    label: Some(name),
                    source: wgpu::ShaderSource::Wgsl(source.into()),
                });
            let pipeline = ctx
                .device
                .create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                    label: Some(name),
                    layout: None,
                    module: &module,
                    entry_point: Some(entry),
                    compilation_options: Default::default(),
                    cache: None,
                });
            let layout = pipeline.get_bind_group_layout(0);
            (pipeline, layout)
        });
        let (pipeline, layout) = built.map_err(|e| GpuError::Shader {
            kernel: name.to_string(),
            message: e.to_string(),
        })?;
        Ok(Self {
            name: name.to_string(),
            pipeline,
            layout,
        })
    }

    /// The kernel's label.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// The compute pipeline.
    pub fn pipeline(&self) -> &wgpu::ComputePipeline {
        &self.pipeline
    }

    /// A bind group 0 for this kernel from `(binding, resource)` pairs (created once, reused).
    pub fn bind(
        &self,
        ctx: &GpuContext,
        entries: &[(u32, wgpu::BindingResource<'_>)],
    ) -> Result<wgpu::BindGroup, GpuError> {
        let entries: Vec<wgpu::BindGroupEntry> = entries
            .iter()
            .map(|(binding, resource)| wgpu::BindGroupEntry {
                binding: *binding,
                resource: resource.clone(),
            })
            .collect();
        ctx.scoped(&format!("binding kernel {}", self.name), || {
            ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some(&self.name),
                layout: &self.layout,
                entries: &entries,
            })
        })
    }

    /// Records one dispatch of `groups` workgroups.
    pub fn record(
        &self,
        pass: &mut wgpu::ComputePass<'_>,
        bind_group: &wgpu::BindGroup,
        groups: [u32; 3],
    ) {
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, bind_group, &[]);
        pass.dispatch_workgroups(groups[0], groups[1], groups[2]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_stage_kernel_parses_and_validates() {
        for (file, stage) in sources::STAGES {
            if let Err(message) = validate_wgsl(&stage_source(stage)) {
                panic!("{file}:\n{message}");
            }
        }
        let random = [sources::PHILOX, sources::RANDOM].join("\n");
        if let Err(message) = validate_wgsl(&random) {
            panic!("random.wgsl:\n{message}");
        }
        if let Err(message) = validate_wgsl(sources::CAPSULE_LIKELIHOOD) {
            panic!("capsule_likelihood.wgsl:\n{message}");
        }
        if let Err(message) = validate_wgsl(sources::BODY_KINEMATICS) {
            panic!("body_kinematics.wgsl:\n{message}");
        }
        if let Err(message) = validate_wgsl(sources::HAAR_CASCADE) {
            panic!("haar_cascade.wgsl:\n{message}");
        }
    }

    #[test]
    fn every_wgsl_file_in_shaders_is_covered() {
        // A new shader file must be added to the validated list (and to ARCHITECTURE.md).
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shaders");
        let mut on_disk: Vec<String> = std::fs::read_dir(&dir)
            .unwrap()
            .filter_map(|e| e.ok())
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .filter(|n| n.ends_with(".wgsl"))
            .collect();
        on_disk.sort();
        let mut known: Vec<String> = sources::STAGES.iter().map(|(f, _)| f.to_string()).collect();
        known.extend(
            [
                "philox.wgsl",
                "common.wgsl",
                "random.wgsl",
                "capsule_likelihood.wgsl",
                "body_kinematics.wgsl",
                "haar_cascade.wgsl",
            ]
            .map(String::from),
        );
        known.sort();
        assert_eq!(on_disk, known);
    }

    /// Every shader file with the libraries it is compiled with.
    fn every_module() -> Vec<(&'static str, String)> {
        let mut modules: Vec<(&str, String)> = sources::STAGES
            .iter()
            .map(|(file, stage)| (*file, stage_source(stage)))
            .collect();
        modules.push(("random.wgsl", [sources::PHILOX, sources::RANDOM].join("\n")));
        modules.push((
            "capsule_likelihood.wgsl",
            sources::CAPSULE_LIKELIHOOD.into(),
        ));
        modules.push(("body_kinematics.wgsl", sources::BODY_KINEMATICS.into()));
        modules.push(("haar_cascade.wgsl", sources::HAAR_CASCADE.into()));
        modules
    }

    #[test]
    fn architecture_kernel_table_names_every_entry_point() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../ARCHITECTURE.md");
        let doc = std::fs::read_to_string(&path).unwrap();
        let table = doc
            .split("## Kernels")
            .nth(1)
            .and_then(|s| s.split("\n## ").next())
            .expect("ARCHITECTURE.md has a Kernels section");
        let mut missing = Vec::new();
        for (file, source) in every_module() {
            let module = wgpu::naga::front::wgsl::parse_str(&source).unwrap();
            for entry in &module.entry_points {
                let named = table.lines().any(|l| {
                    l.starts_with(&format!("| `{file}`"))
                        && l.contains(&format!("`{}`", entry.name))
                });
                if !named {
                    missing.push(format!("{file}: {}", entry.name));
                }
            }
        }
        assert!(
            missing.is_empty(),
            "ARCHITECTURE.md's kernel table lacks {missing:?}"
        );
    }

    /// The Rust items a shader's comments name (`pf_core::batch::diffuse`, `a::{b, c}`): the
    /// last segment of each path.
    fn named_items(comment: &str) -> Vec<String> {
        let mut names = Vec::new();
        for start in ["pf_core::", "pf_gpu::", "body_tracker::", "face_tracker::"] {
            for (at, _) in comment.match_indices(start) {
                let rest = &comment[at..];
                let end = rest
                    .find(|c: char| !(c.is_alphanumeric() || c == '_' || c == ':'))
                    .unwrap_or(rest.len());
                let path = rest[..end].trim_end_matches(':');
                if rest[end..].starts_with('{') && path.len() < end {
                    let group = &rest[end + 1..rest.find('}').unwrap_or(rest.len())];
                    names.extend(group.split(',').map(|n| n.trim().to_string()));
                } else if let Some(last) = path.rsplit("::").next() {
                    names.push(last.to_string());
                }
            }
        }
        names
    }

    #[test]
    fn every_rust_item_a_shader_names_exists() {
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
        let mut code = String::new();
        let mut files = Vec::new();
        for krate in ["pf-core", "pf-gpu", "body-tracker", "face-tracker"] {
            let mut stack = vec![root.join("crates").join(krate).join("src")];
            while let Some(dir) = stack.pop() {
                for entry in std::fs::read_dir(&dir).unwrap().flatten() {
                    let path = entry.path();
                    if path.is_dir() {
                        stack.push(path);
                    } else {
                        files.push(path.file_stem().unwrap().to_string_lossy().into_owned());
                        code.push_str(&std::fs::read_to_string(&path).unwrap());
                    }
                }
            }
        }
        let mut missing = Vec::new();
        for entry in std::fs::read_dir(root.join("shaders")).unwrap().flatten() {
            let source = std::fs::read_to_string(entry.path()).unwrap();
            let comments: String = source
                .lines()
                .filter_map(|l| l.trim_start().strip_prefix("//"))
                .collect::<Vec<_>>()
                .join(" ");
            for name in named_items(&comments) {
                let defined = ["fn ", "struct ", "enum ", "trait ", "mod ", "type "]
                    .iter()
                    .any(|kind| code.contains(&format!("{kind}{name}")))
                    || files.contains(&name);
                if !defined {
                    missing.push(format!("{}: {name}", entry.file_name().to_string_lossy()));
                }
            }
        }
        assert!(
            missing.is_empty(),
            "shader comments name items that do not exist: {missing:?}"
        );
    }

    #[test]
    fn invalid_wgsl_is_reported_with_its_location() {
        let err = validate_wgsl("fn broken( { }").unwrap_err();
        assert!(err.contains("expected"), "{err}");
        let err = validate_wgsl("@compute @workgroup_size(1) fn main() { let x: u32 = 1.5; }")
            .unwrap_err();
        assert!(!err.is_empty());
    }
}
