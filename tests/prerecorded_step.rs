//! Recording the next step while the GPU runs this one (`pf_gpu::filter`'s prerecording) against
//! recording every step when it is submitted: the same particles, bit for bit, whatever happens
//! between the steps. Two filters of one fresh random configuration (shapes with edge cases, one
//! to three layers, fixed or survival β, the fused and the staged layout) take the same fresh
//! random sequence of actions: lone steps, two steps in flight, steps of a few stages, another
//! likelihood, the same likelihood prepared again, the layout switched, the lineage kept, the
//! dispatches profiled. After every action their reports and particles must be the same bytes;
//! a prerecorded step that outlived what it recorded (a likelihood swapped, a layout switched)
//! would weigh or move differently.

mod common;

use pf_core::anneal::{Annealing, Tempering};
use pf_core::batch::{BatchConfig, BatchShape, gaussian_clouds};
use pf_gpu::toy::ToyGaussianLikelihood;
use pf_gpu::{GpuContext, GpuFilter, GpuLikelihood, GpuResampler, GpuStage, StepLayout};
use proptest::prelude::*;

const D: usize = 7;
const SIGMA: [f32; D] = [0.3, 0.2, 0.4, 0.1, 0.25, 0.15, 0.35];

#[derive(Debug, Clone, Copy)]
enum Action {
    /// One whole step, submitted alone and waited for.
    Step,
    /// Two whole steps in flight, then both finished.
    TwoInFlight,
    /// A step of the stages up to the likelihood (no normalisation or estimate).
    FewStages,
    /// A whole step weighed by the second likelihood.
    OtherLikelihood,
    /// The first likelihood prepared again (its bind groups built anew).
    Reprepare,
    /// The other layout from the next step on (where the fused one fits).
    SwitchLayout,
    /// The particles' lineage kept from now on.
    KeepLineage,
    /// Dispatch profiling switched.
    Profile(bool),
}

fn action() -> impl Strategy<Value = Action> {
    prop_oneof![
        4 => Just(Action::Step),
        2 => Just(Action::TwoInFlight),
        1 => Just(Action::FewStages),
        2 => Just(Action::OtherLikelihood),
        1 => Just(Action::Reprepare),
        1 => Just(Action::SwitchLayout),
        1 => Just(Action::KeepLineage),
        1 => any::<bool>().prop_map(Action::Profile),
    ]
}

#[derive(Debug, Clone)]
struct Case {
    targets: usize,
    particles: usize,
    layers: usize,
    survival: bool,
    seed: u64,
    actions: Vec<Action>,
}

fn case() -> impl Strategy<Value = Case> {
    (
        1usize..4,
        prop_oneof![Just(1usize), 2usize..300, Just(256), Just(257), Just(1000)],
        1usize..4,
        any::<bool>(),
        any::<u64>(),
        prop::collection::vec(action(), 1..12),
    )
        .prop_map(
            |(targets, particles, layers, survival, seed, actions)| Case {
                targets,
                particles,
                layers,
                survival,
                seed,
                actions,
            },
        )
}

/// One side of the comparison: a filter and its two likelihoods.
struct Side {
    filter: GpuFilter,
    first: ToyGaussianLikelihood,
    second: ToyGaussianLikelihood,
}

impl Side {
    fn new(ctx: &GpuContext, case: &Case, prerecording: bool) -> Side {
        let shape = BatchShape::new(case.targets, case.particles, D).unwrap();
        let annealing = if case.survival {
            Annealing::survival(case.layers, 0.5, 0.7)
        } else {
            let mut a = Annealing::survival(case.layers, 0.5, 0.7);
            a.tempering =
                Tempering::Fixed((0..case.layers).map(|l| 0.3 + 0.2 * l as f32).collect());
            a
        };
        let config = BatchConfig {
            shape,
            seed: case.seed,
            sigma: SIGMA.to_vec(),
            bounds: None,
            angular: vec![false, false, false, true, false, false, false],
            ess_threshold: 0.5,
            best: case.particles.div_ceil(10),
            annealing,
            motion: Default::default(),
        };
        let means = vec![0.0; case.targets * D];
        let initial = gaussian_clouds(&shape, case.seed, &means, &[1.0; D]);
        let mut filter = GpuFilter::new(ctx, &config, GpuResampler::Systematic, &initial).unwrap();
        filter.set_prerecording(prerecording);
        let mut first = ToyGaussianLikelihood::new(ctx, case.targets, &SIGMA).unwrap();
        let mut second =
            ToyGaussianLikelihood::new(ctx, case.targets, &SIGMA.map(|s| 2.0 * s)).unwrap();
        first.prepare(ctx, &filter.likelihood_inputs()).unwrap();
        second.prepare(ctx, &filter.likelihood_inputs()).unwrap();
        Side {
            filter,
            first,
            second,
        }
    }

    /// This step's observations, the same on both sides and different from step to step.
    fn observe(&self, ctx: &GpuContext, targets: usize, step: usize) {
        let z: Vec<f32> = (0..targets * D)
            .map(|k| ((k * 7 + step * 13) % 17) as f32 * 0.05 - 0.4)
            .collect();
        self.first.upload_observations(ctx, &z).unwrap();
        self.second.upload_observations(ctx, &z).unwrap();
    }

    /// Runs `action`, returning what it read back: estimates, best estimates, spreads and the
    /// statistics of each step, as bytes.
    fn act(&mut self, ctx: &GpuContext, action: Action) -> Vec<u8> {
        let mut out = Vec::new();
        let mut keep = |r: pf_gpu::GpuStepReport| {
            out.extend(bytemuck::cast_slice(&r.estimates));
            out.extend(bytemuck::cast_slice(&r.best_estimates));
            out.extend(bytemuck::cast_slice(&r.spreads));
            out.extend(bytemuck::cast_slice(&r.stats));
        };
        match action {
            Action::Step => keep(self.filter.step(ctx, &self.first).unwrap()),
            Action::TwoInFlight => {
                let a = self
                    .filter
                    .submit_stages(ctx, &GpuStage::ALL, &self.first)
                    .unwrap();
                let b = self
                    .filter
                    .submit_stages(ctx, &GpuStage::ALL, &self.first)
                    .unwrap();
                keep(self.filter.finish_step(ctx, a).unwrap());
                keep(self.filter.finish_step(ctx, b).unwrap());
            }
            Action::FewStages => {
                let stages = [
                    GpuStage::Resample,
                    GpuStage::Gather,
                    GpuStage::Diffuse,
                    GpuStage::Likelihood,
                ];
                keep(self.filter.run_stages(ctx, &stages, &self.first).unwrap());
            }
            Action::OtherLikelihood => keep(self.filter.step(ctx, &self.second).unwrap()),
            Action::Reprepare => {
                self.first
                    .prepare(ctx, &self.filter.likelihood_inputs())
                    .unwrap();
            }
            Action::SwitchLayout => {
                // Refused where the fused step does not fit: then both sides stay staged.
                let _ = self.filter.set_step_layout(StepLayout::Fused);
            }
            Action::KeepLineage => self.filter.keep_lineage(ctx).unwrap(),
            // Refused where the adapter has no timestamps or the layout is staged: both sides
            // alike.
            Action::Profile(on) => out.push(self.filter.profile_dispatches(ctx, on).is_ok() as u8),
        }
        out
    }
}

fn check(ctx: &GpuContext, case: &Case) -> Result<(), TestCaseError> {
    let mut with = Side::new(ctx, case, true);
    let mut without = Side::new(ctx, case, false);
    let mut staged = false;
    for (k, &action) in case.actions.iter().enumerate() {
        with.observe(ctx, case.targets, k);
        without.observe(ctx, case.targets, k);
        let action = match action {
            // Alternate the layouts, both sides alike.
            Action::SwitchLayout => {
                staged = !staged;
                let layout = if staged {
                    StepLayout::Staged
                } else {
                    StepLayout::Fused
                };
                for side in [&mut with, &mut without] {
                    let _ = side.filter.set_step_layout(layout);
                }
                continue;
            }
            other => other,
        };
        let a = with.act(ctx, action);
        let b = without.act(ctx, action);
        prop_assert!(a == b, "action {k} ({action:?}): the reports differ");
        let states_with = with.filter.download_states(ctx).unwrap();
        let states_without = without.filter.download_states(ctx).unwrap();
        prop_assert!(
            bytemuck::cast_slice::<f32, u8>(&states_with)
                == bytemuck::cast_slice::<f32, u8>(&states_without),
            "action {k} ({action:?}): the particles differ"
        );
    }
    prop_assert_eq!(without.filter.prerecorded_steps(), 0);
    Ok(())
}

#[test]
fn prerecorded_steps_give_the_same_particles_as_steps_recorded_when_submitted() {
    let Some(ctx) = common::gpu_context("prerecorded_step") else {
        return;
    };
    common::property::check_cases("prerecorded_step", 12, case(), |case| check(&ctx, &case));
}

/// Consecutive lone steps of one likelihood are submitted from their prerecording; a step of
/// another likelihood, and the step after the first likelihood is prepared again, are not.
#[test]
fn lone_steps_are_prerecorded_until_what_they_recorded_changes() {
    let Some(ctx) = common::gpu_context("prerecorded_step") else {
        return;
    };
    let case = Case {
        targets: 2,
        particles: 300,
        layers: 2,
        survival: true,
        seed: 5,
        actions: Vec::new(),
    };
    let mut side = Side::new(&ctx, &case, true);
    for step in 0..4 {
        side.observe(&ctx, 2, step);
        side.act(&ctx, Action::Step);
    }
    // The first step had nothing recorded ahead; the three after it did.
    assert_eq!(side.filter.prerecorded_steps(), 3);
    side.act(&ctx, Action::Reprepare);
    side.act(&ctx, Action::Step);
    assert_eq!(
        side.filter.prerecorded_steps(),
        3,
        "a likelihood prepared again"
    );
    side.act(&ctx, Action::Step);
    assert_eq!(side.filter.prerecorded_steps(), 4);
    side.act(&ctx, Action::OtherLikelihood);
    assert_eq!(
        side.filter.prerecorded_steps(),
        4,
        "another likelihood's step"
    );
    side.act(&ctx, Action::Step);
    assert_eq!(
        side.filter.prerecorded_steps(),
        4,
        "after another likelihood's step"
    );
    side.act(&ctx, Action::Step);
    assert_eq!(side.filter.prerecorded_steps(), 5);
    // The fused layout is these shapes' default: the step after a switch to the staged one.
    side.filter.set_step_layout(StepLayout::Staged).unwrap();
    side.act(&ctx, Action::Step);
    assert_eq!(side.filter.prerecorded_steps(), 5, "another layout");
    side.filter.set_prerecording(false);
    side.act(&ctx, Action::Step);
    side.act(&ctx, Action::Step);
    assert_eq!(
        side.filter.prerecorded_steps(),
        5,
        "prerecording switched off"
    );
}
