//! WGSL kernels: the engine's sources from `shaders/engine/` (include_str!), checked by naga,
//! built into pipelines. A tracker's kernels live in `shaders/<tracker>/` and are launched from
//! its own crate through the same [`Kernel`].

use crate::context::GpuContext;
use crate::error::GpuError;

/// The WGSL files of the generic stages. `PHILOX` and `COMMON` are libraries prepended to the
/// stage files (see [`stage_source`]).
pub mod sources {
    /// Philox4x32-10 and counter-based Gaussians (a library).
    pub const PHILOX: &str = include_str!("../../../shaders/engine/philox.wgsl");
    /// `Params`, `TargetStats` and helpers shared by the stages (a library).
    pub const COMMON: &str = include_str!("../../../shaders/engine/common.wgsl");
    /// The diffusion stage (with the move of one value it shares with the fused layer).
    pub const DIFFUSE: &str = concat!(
        include_str!("../../../shaders/engine/move_particle.wgsl"),
        "\n",
        include_str!("../../../shaders/engine/diffuse.wgsl")
    );
    /// The normalisation stage (with the normalisation of one target it shares with the fused
    /// layer).
    pub const NORMALISE: &str = concat!(
        include_str!("../../../shaders/engine/normalise_target.wgsl"),
        "\n",
        include_str!("../../../shaders/engine/normalise.wgsl")
    );
    /// The resamplers (with the one-workgroup resampling of a target it shares with the fused
    /// layer).
    pub const RESAMPLE: &str = concat!(
        include_str!("../../../shaders/engine/resample_target.wgsl"),
        "\n",
        include_str!("../../../shaders/engine/resample.wgsl")
    );
    /// The fused annealing layer: normalise the previous layer, resample, gather and move, one
    /// workgroup per target (`STAGE_CAPACITY` set to M by `filter::fused`).
    pub const LAYER: &str = concat!(
        include_str!("../../../shaders/engine/normalise_target.wgsl"),
        "\n",
        include_str!("../../../shaders/engine/resample_target.wgsl"),
        "\n",
        include_str!("../../../shaders/engine/move_particle.wgsl"),
        "\n",
        include_str!("../../../shaders/engine/layer.wgsl")
    );
    /// Fixed-lag smoothing from the ancestry, summarised on the device, and the step kept in
    /// the lag window's ring (with the window's parameters and the weighted cloud's statistics).
    pub const LAG_SUMMARY: &str = concat!(
        include_str!("../../../shaders/engine/lag_params.wgsl"),
        "\n",
        include_str!("../../../shaders/engine/lag_cloud.wgsl"),
        "\n",
        include_str!("../../../shaders/engine/lag_summary.wgsl")
    );
    /// The particles' lineage through a frame's resamplings.
    pub const LINEAGE: &str = include_str!("../../../shaders/engine/lineage.wgsl");
    /// The gather stage.
    pub const GATHER: &str = include_str!("../../../shaders/engine/gather.wgsl");
    /// The estimates.
    pub const ESTIMATE: &str = include_str!("../../../shaders/engine/estimate.wgsl");
    /// The hand-written toy likelihood.
    pub const TOY_LIKELIHOOD: &str = include_str!("../../../shaders/engine/toy_likelihood.wgsl");
    /// Philox blocks and Gaussian draws for the bit-exact tests.
    pub const RANDOM: &str = include_str!("../../../shaders/engine/random.wgsl");

    /// Every stage file, by name, for the validation tests.
    pub const STAGES: [(&str, &str); 9] = [
        ("toy_likelihood.wgsl", TOY_LIKELIHOOD),
        ("diffuse.wgsl", DIFFUSE),
        ("normalise.wgsl", NORMALISE),
        ("resample.wgsl", RESAMPLE),
        ("gather.wgsl", GATHER),
        ("estimate.wgsl", ESTIMATE),
        ("layer.wgsl", LAYER),
        ("lineage.wgsl", LINEAGE),
        ("lag_summary.wgsl", LAG_SUMMARY),
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

/// Test helper (for the engine's and the trackers' tests): the Rust mirror of a WGSL struct has
/// its size, and each WGSL member (padding aside) sits at the offset of the Rust field of the same
/// name (`fields`: name, `offset_of!`). Panics, naming the member, when it does not.
pub fn assert_mirrors_wgsl(source: &str, name: &str, rust_size: usize, fields: &[(&str, usize)]) {
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
    checks: ShaderChecks,
}

/// Whether wgpu adds its own runtime checks to a kernel's compiled code.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ShaderChecks {
    /// wgpu's defaults: every dynamic index into a workgroup or function array clamped into
    /// range, and every loop given a counter that ends it after 2^64 iterations. For WGSL the
    /// project has not written (a plug-in model's, [`crate::model::WgslModel`]).
    #[default]
    Checked,
    /// Neither (nor the clamps of `textureLoad`'s coordinates): for the project's own kernels,
    /// whose indices stay in range and whose loops end by their own logic, as their
    /// GPU-against-CPU tests and `tests/trusted_kernels.rs` hold them. Used on Vulkan only
    /// ([`GpuContext::checks_every_kernel`]), whose robust buffer access (every Vulkan device has
    /// it and wgpu turns it on) keeps a storage buffer's accesses inside it either way. What it
    /// saves is the hot loops' counters and clamps: on an NVIDIA H200 the toy plug-in's
    /// five-layer step took 129 µs of GPU time checked and 122 µs with the engine's kernels
    /// trusted (its own kernel keeps the checks), the body's capsule weighing 4.0 ms and 3.7 ms
    /// (docs/BENCHMARKS.md, "Trusted kernels"). A kernel that broke the promise would index past
    /// a workgroup or function array: garbage on a GPU, and on a software adapter (whose
    /// workgroup memory is the host's) the host process's memory, which is why the tests run the
    /// kernels there trusted and checked and compare the bits.
    Trusted,
}

/// The checks a kernel asking for `asked` is built with on `ctx`: every check where the context
/// checks every kernel ([`GpuContext::checks_every_kernel`]: asked for, or off Vulkan).
fn effective_checks(ctx: &GpuContext, asked: ShaderChecks) -> ShaderChecks {
    if ctx.checks_every_kernel() {
        ShaderChecks::Checked
    } else {
        asked
    }
}

impl ShaderChecks {
    fn runtime_checks(self) -> wgpu::ShaderRuntimeChecks {
        let mut checks = wgpu::ShaderRuntimeChecks::checked();
        let trusted = self == Self::Trusted;
        checks.bounds_checks = !trusted;
        checks.force_loop_bounding = !trusted;
        checks
    }
}

/// How a [`Kernel`] is built beyond its source: the values of its `override` constants, whether
/// its workgroup memory starts zeroed, and whether wgpu checks its indices and loops.
#[derive(Debug, Clone, Copy)]
pub struct KernelOptions<'a> {
    /// `(name, value)` of each pipeline-overridable constant set (the others keep their WGSL
    /// defaults).
    pub constants: &'a [(&'a str, f64)],
    /// WebGPU zeroes a workgroup's memory before it starts (wgpu's default), a store by every
    /// invocation and a barrier in each workgroup. A kernel that writes every workgroup value
    /// before it reads it can do without (`false`), which pays in kernels of many small
    /// workgroups.
    pub zero_workgroup_memory: bool,
    /// wgpu's runtime checks ([`ShaderChecks::Checked`] unless the kernel is the project's own).
    pub checks: ShaderChecks,
}

impl Default for KernelOptions<'_> {
    fn default() -> Self {
        Self {
            constants: &[],
            zero_workgroup_memory: true,
            checks: ShaderChecks::Checked,
        }
    }
}

impl KernelOptions<'static> {
    /// The defaults for one of the project's own kernels: [`ShaderChecks::Trusted`].
    pub fn trusted() -> Self {
        Self {
            checks: ShaderChecks::Trusted,
            ..Self::default()
        }
    }
}

impl Kernel {
    /// Builds `entry` of `source`, with wgpu's runtime checks. Invalid WGSL is a
    /// [`GpuError::Shader`] with naga's message.
    pub fn new(ctx: &GpuContext, name: &str, source: &str, entry: &str) -> Result<Self, GpuError> {
        Self::with_options(ctx, name, source, entry, KernelOptions::default())
    }

    /// Builds `entry` of one of the project's own kernels, without wgpu's index and loop checks
    /// ([`ShaderChecks::Trusted`] says what that promises).
    pub fn trusted(
        ctx: &GpuContext,
        name: &str,
        source: &str,
        entry: &str,
    ) -> Result<Self, GpuError> {
        Self::with_options(ctx, name, source, entry, KernelOptions::trusted())
    }

    /// Builds `entry` of `source` with `options` (its override constants, its workgroup
    /// memory's zeroing).
    pub fn with_options(
        ctx: &GpuContext,
        name: &str,
        source: &str,
        entry: &str,
        options: KernelOptions<'_>,
    ) -> Result<Self, GpuError> {
        validate_wgsl(source).map_err(|message| GpuError::Shader {
            kernel: name.to_string(),
            message,
        })?;
        let checks = effective_checks(ctx, options.checks);
        let built = ctx.scoped(&format!("building kernel {name}"), || {
            let descriptor = wgpu::ShaderModuleDescriptor {
                label: Some(name),
                source: wgpu::ShaderSource::Wgsl(source.into()),
            };
            // SAFETY: the checks are dropped only for ShaderChecks::Trusted, the project's own
            // kernels (or a model its author trusts), whose indices stay in range and whose loops
            // end (see its doc), and only on Vulkan, whose robust buffer access bounds storage
            // buffers either way (effective_checks).
            let module = unsafe {
                ctx.device
                    .create_shader_module_trusted(descriptor, checks.runtime_checks())
            };
            let pipeline = ctx
                .device
                .create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                    label: Some(name),
                    layout: None,
                    module: &module,
                    entry_point: Some(entry),
                    compilation_options: wgpu::PipelineCompilationOptions {
                        constants: options.constants,
                        zero_initialize_workgroup_memory: options.zero_workgroup_memory,
                    },
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
            checks,
        })
    }

    /// The kernel's label.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Whether it was built with wgpu's runtime checks.
    pub fn checks(&self) -> ShaderChecks {
        self.checks
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
    fn every_engine_stage_parses_and_validates() {
        for (file, stage) in sources::STAGES {
            if let Err(message) = validate_wgsl(&stage_source(stage)) {
                panic!("{file}:\n{message}");
            }
        }
        let random = [sources::PHILOX, sources::RANDOM].join("\n");
        if let Err(message) = validate_wgsl(&random) {
            panic!("random.wgsl:\n{message}");
        }
    }

    #[test]
    fn invalid_wgsl_is_reported_with_its_location() {
        let err = validate_wgsl("fn broken( { }").unwrap_err();
        assert!(err.contains("expected"), "{err}");
        let err = validate_wgsl("@compute @workgroup_size(1) fn main() { let x: u32 = 1.5; }")
            .unwrap_err();
        assert!(!err.is_empty());
    }

    /// The survival rule's bisection runs as many steps on the GPU as its CPU twin, or the two
    /// would choose different exponents and every particle after them would differ.
    #[test]
    fn the_gpu_bisects_as_many_steps_as_the_cpu() {
        use wgpu::naga;
        let source = stage_source(sources::NORMALISE);
        let module = naga::front::wgsl::parse_str(&source).expect("normalise.wgsl parses");
        let (_, constant) = (module.constants.iter())
            .find(|(_, c)| c.name.as_deref() == Some("SURVIVAL_BISECTION_STEPS"))
            .expect("normalise_target.wgsl declares SURVIVAL_BISECTION_STEPS");
        let steps = match module.global_expressions[constant.init] {
            naga::Expression::Literal(naga::Literal::U32(steps)) => steps,
            ref other => panic!("SURVIVAL_BISECTION_STEPS is {other:?}, not a u32 literal"),
        };
        assert_eq!(steps, pf_core::anneal::SURVIVAL_BISECTION_STEPS);
    }
}
