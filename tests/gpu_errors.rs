//! The GPU runtime's failures are typed errors with clear messages, never panics.

mod common;

use pf_core::batch::{BatchConfig, BatchShape};

use pf_gpu::{ContextOptions, DeviceStream, GpuContext, GpuError, GpuFilter, GpuResampler, Kernel};

#[test]
fn invalid_shader_is_a_typed_error_naming_the_kernel_and_the_line() {
    let Some(ctx) = common::gpu_context("invalid_shader") else {
        return;
    };
    let source = "@compute @workgroup_size(1)\nfn main() {\n    let x: u32 = ;\n}\n";
    match Kernel::new(&ctx, "broken kernel", source, "main") {
        Err(GpuError::Shader { kernel, message }) => {
            assert_eq!(kernel, "broken kernel");
            assert!(
                message.contains(":3:"),
                "the message points at line 3: {message}"
            );
        }
        other => panic!("expected a shader error, got {other:?}"),
    }
    // Valid WGSL, but no such entry point: caught by the pipeline's error scope.
    let valid = "@compute @workgroup_size(1) fn main() {}";
    match Kernel::new(&ctx, "wrong entry", valid, "no_such_entry") {
        Err(GpuError::Shader { kernel, message }) => {
            assert_eq!(kernel, "wrong entry");
            assert!(!message.is_empty());
        }
        other => panic!("expected a shader error, got {other:?}"),
    }
}

#[test]
fn over_limit_buffer_request_is_a_typed_error() {
    let Some(ctx) = common::gpu_context("over_limit_buffer") else {
        return;
    };
    let limit = ctx
        .limits()
        .max_storage_buffer_binding_size
        .min(ctx.limits().max_buffer_size);
    let too_many = (limit / 4 + 1) as usize;
    match DeviceStream::<f32>::zeroed(&ctx, "particle states", too_many) {
        Err(err @ GpuError::BufferTooLarge { .. }) => {
            let msg = err.to_string();
            assert!(
                msg.contains("particle states") && msg.contains(&limit.to_string()),
                "{msg}"
            );
        }
        other => panic!("expected BufferTooLarge, got {other:?}"),
    }
}

#[test]
fn missing_adapter_is_a_typed_error_that_says_what_to_install() {
    let options = ContextOptions {
        adapter_name: Some("no-such-adapter-anywhere".into()),
        ..ContextOptions::for_tests()
    };
    match GpuContext::new(&options) {
        Err(err @ GpuError::NoAdapter { .. }) => {
            let msg = err.to_string();
            assert!(msg.contains("mesa-vulkan-drivers"), "{msg}");
            assert!(msg.contains("no-such-adapter-anywhere"), "{msg}");
        }
        other => panic!("expected NoAdapter, got {other:?}"),
    }
}

#[test]
fn software_adapters_are_used_only_when_asked_for() {
    let Some(adapters) = common::require_gpu("software_adapters_are_used_only_when_asked_for")
    else {
        return;
    };
    let options = ContextOptions {
        adapter_name: None,
        ..ContextOptions::default()
    };
    let result = GpuContext::new(&options);
    if adapters.iter().all(|a| a.is_software()) {
        assert!(
            matches!(result, Err(GpuError::OnlySoftwareAdapters { .. })),
            "{result:?}"
        );
    } else {
        assert!(!result.unwrap().adapter().is_software());
    }
}

#[test]
fn wrong_lengths_and_configurations_are_typed_errors() {
    let Some(ctx) = common::gpu_context("wrong_lengths") else {
        return;
    };
    let stream = DeviceStream::<f32>::zeroed(&ctx, "weights", 10).unwrap();
    assert!(matches!(
        stream.upload(&ctx, &[1.0; 9]),
        Err(GpuError::LengthMismatch { .. })
    ));
    let shape = BatchShape::new(2, 10, 3).unwrap();
    let good = BatchConfig {
        shape,
        seed: 1,
        sigma: vec![0.1; 3],
        bounds: None,
        angular: vec![false; 3],
        ess_threshold: 0.5,
        best: 0,
        annealing: Default::default(),
        motion: Default::default(),
    };
    let states = vec![0.0; shape.state_len()];
    let bad_sigma = BatchConfig {
        sigma: vec![0.1; 2],
        ..good.clone()
    };
    assert!(matches!(
        GpuFilter::new(&ctx, &bad_sigma, GpuResampler::Systematic, &states),
        Err(GpuError::Core(_))
    ));
    assert!(matches!(
        GpuFilter::new(&ctx, &good, GpuResampler::Systematic, &states[1..]),
        Err(GpuError::LengthMismatch { .. })
    ));
    assert!(GpuFilter::new(&ctx, &good, GpuResampler::Systematic, &states).is_ok());
}

#[test]
fn every_adapter_can_be_opened_and_run_a_step() {
    let Some(_) = common::require_gpu("every_adapter_can_be_opened") else {
        return;
    };
    let contexts = GpuContext::all(&ContextOptions::for_tests()).unwrap();
    assert!(!contexts.is_empty());
    let shape = BatchShape::new(2, 64, 2).unwrap();
    let config = BatchConfig {
        shape,
        seed: 3,
        sigma: vec![0.1; 2],
        bounds: None,
        angular: vec![false, true],
        ess_threshold: f64::INFINITY,
        best: 16,
        annealing: Default::default(),
        motion: Default::default(),
    };
    for ctx in &contexts {
        let mut filter = GpuFilter::new(
            ctx,
            &config,
            GpuResampler::Systematic,
            &vec![0.5; shape.state_len()],
        )
        .unwrap();
        let report = filter.step(ctx, &pf_gpu::NoLikelihood).unwrap();
        assert_eq!(report.estimates.len(), 4);
        assert!(report.stats.iter().all(|s| s.status == 0));
    }
}
