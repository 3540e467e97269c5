//! A likelihood's readbacks ride in the filter's one staging buffer and come back in the step's
//! report by name: random section counts and lengths after the filter's own sections, a
//! likelihood swapped for one with other sections, and the errors of a bad request.

mod common;

use pf_core::batch::{BatchConfig, BatchShape};
use pf_gpu::stream::DeviceStream;
use pf_gpu::{
    GpuContext, GpuError, GpuFilter, GpuLikelihood, GpuResampler, LikelihoodInputs,
    LikelihoodPhase, NoLikelihood, ReadbackSource,
};
use proptest::prelude::*;

const NAMES: [&str; 4] = ["first", "second", "third", "fourth"];

/// A likelihood that measures nothing and asks for its own streams back.
struct Sections {
    streams: Vec<DeviceStream<u32>>,
    names: Vec<&'static str>,
}

impl GpuLikelihood for Sections {
    fn prepare(&mut self, _: &GpuContext, _: &LikelihoodInputs<'_>) -> Result<(), GpuError> {
        Ok(())
    }
    fn record(&self, _: LikelihoodPhase, _: &mut pf_gpu::wgpu::ComputePass<'_>) {}
    fn readbacks(&self) -> Vec<ReadbackSource<'_>> {
        self.names
            .iter()
            .zip(&self.streams)
            .map(|(name, s)| ReadbackSource::of(name, s))
            .collect()
    }
}

fn filter(ctx: &GpuContext, targets: usize, particles: usize, best: usize) -> GpuFilter {
    let shape = BatchShape {
        targets,
        particles,
        dims: 2,
    };
    let config = BatchConfig {
        shape,
        seed: 7,
        sigma: vec![0.1; 2],
        bounds: None,
        angular: vec![false; 2],
        ess_threshold: f64::INFINITY,
        best,
        annealing: Default::default(),
        motion: Default::default(),
    };
    GpuFilter::new(
        ctx,
        &config,
        GpuResampler::Systematic,
        &vec![1.0; shape.state_len()],
    )
    .unwrap()
}

proptest! {
    #![proptest_config(common::property::config(12))]

    #[test]
    fn sections_come_back_by_name_after_the_filters_own(
        targets in 1usize..5,
        particles in 1usize..300,
        best in 0usize..2,
        contents in prop::collection::vec(prop::collection::vec(any::<u32>(), 1..200), 1..=4),
        swapped in prop::collection::vec(any::<u32>(), 1..50),
    ) {
        let Some(ctx) = common::gpu_context("likelihood readbacks") else { return Ok(()) };
        let mut filter = filter(&ctx, targets, particles, best.min(particles));
        let streams = contents
            .iter()
            .map(|c| DeviceStream::from_slice(&ctx, "section", c).unwrap())
            .collect();
        let sections = Sections { streams, names: NAMES[..contents.len()].to_vec() };
        for _ in 0..2 {
            let report = filter.step(&ctx, &sections).unwrap();
            // The filter's own sections are untouched by the likelihood's (the states are all 1).
            prop_assert!(report.estimates.iter().all(|&e| (e - 1.0).abs() < 0.5));
            prop_assert_eq!(report.stats.len(), targets);
            for (name, want) in NAMES.iter().zip(&contents) {
                prop_assert_eq!(&report.likelihood.get::<u32>(name).unwrap(), want);
            }
            prop_assert!(report.likelihood.get::<u32>("absent").is_err());
        }
        // Another likelihood: the staging buffer follows its sections, and none is left over.
        let other = Sections {
            streams: vec![DeviceStream::from_slice(&ctx, "swapped", &swapped).unwrap()],
            names: vec!["second"],
        };
        let report = filter.step(&ctx, &other).unwrap();
        prop_assert_eq!(report.likelihood.get::<u32>("second").unwrap(), swapped);
        prop_assert!(report.likelihood.get::<u32>("first").is_err());
        let report = filter.step(&ctx, &NoLikelihood).unwrap();
        prop_assert!(report.likelihood.is_empty());
    }
}

#[test]
fn two_sections_of_one_name_are_refused() {
    let Some(ctx) = common::gpu_context("likelihood readbacks") else {
        return;
    };
    let mut filter = filter(&ctx, 2, 64, 0);
    let stream = || DeviceStream::from_slice(&ctx, "section", &[1u32, 2, 3]).unwrap();
    let twice = Sections {
        streams: vec![stream(), stream()],
        names: vec!["same", "same"],
    };
    let err = filter.step(&ctx, &twice).unwrap_err().to_string();
    assert!(err.contains("two sections named \"same\""), "{err}");
    // The filter still steps afterwards.
    assert!(filter.step(&ctx, &NoLikelihood).is_ok());
}

#[test]
fn recording_a_step_for_a_likelihood_the_staging_was_not_fitted_for_copies_nothing() {
    let Some(ctx) = common::gpu_context("likelihood readbacks") else {
        return;
    };
    let mut filter = filter(&ctx, 1, 32, 0);
    let sections = Sections {
        streams: vec![DeviceStream::from_slice(&ctx, "section", &[7u32; 5]).unwrap()],
        names: vec!["first"],
    };
    // record_step does not fit the staging buffer: the section has nowhere to go, and is skipped.
    let mut encoder = ctx.device.create_command_encoder(&Default::default());
    filter.record_step(&ctx, &mut encoder, &sections);
    ctx.queue.submit([encoder.finish()]);
    // A full step fits it and reads the section back.
    let report = filter.step(&ctx, &sections).unwrap();
    assert_eq!(report.likelihood.get::<u32>("first").unwrap(), [7; 5]);
}
