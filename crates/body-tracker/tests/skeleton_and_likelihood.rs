//! Forward kinematics, the skeleton file, and the capsule likelihood on the CPU.

use body_tracker::capsule::ray_capsule;
use body_tracker::human::{BASE_CAPSULES, human_skeleton, standing_pose};
use body_tracker::likelihood::{
    CapsuleLikelihoodParams, Rays, culled_sum_of_squared_distances,
    culled_sum_of_squared_distances_parallel, listing_1_2, parallel_over_samples,
    sum_of_squared_distances,
};
use body_tracker::{BodyError, Skeleton, SkeletonSpec};
use nalgebra::{Vector3, vector};
use proptest::prelude::*;

#[test]
fn capsule_count_is_configurable_up_to_48_and_beyond() {
    for k in [BASE_CAPSULES, 40, 48, 96] {
        let s = human_skeleton(k).unwrap();
        assert_eq!(s.capsule_count(), k);
        assert_eq!(s.capsules(&standing_pose(&s, 3.0)).unwrap().len(), k);
    }
    assert!(human_skeleton(18).is_err());
    assert!(human_skeleton(97).is_err());
}

#[test]
fn splitting_bones_keeps_the_body_the_same_shape() {
    // The rest pose of the 48-capsule body covers the same points as the 19-capsule one: every
    // joint of the base body is still a capsule end point.
    let base = human_skeleton(BASE_CAPSULES).unwrap();
    let fine = human_skeleton(48).unwrap();
    let base_caps = base.capsules(&standing_pose(&base, 3.0)).unwrap();
    let fine_caps = fine.capsules(&standing_pose(&fine, 3.0)).unwrap();
    for c in &base_caps {
        for end in [c.a, c.b] {
            let near = fine_caps
                .iter()
                .any(|f| (f.a - end).norm() < 1e-5 || (f.b - end).norm() < 1e-5);
            assert!(
                near,
                "end point {end:?} of the base body is missing from the split body"
            );
        }
    }
    let total =
        |caps: &[body_tracker::Capsule]| caps.iter().map(|c| (c.b - c.a).norm()).sum::<f32>();
    assert!((total(&base_caps) - total(&fine_caps)).abs() < 1e-4);
}

#[test]
fn rest_pose_matches_hand_computed_joints() {
    let s = human_skeleton(BASE_CAPSULES).unwrap();
    let theta = standing_pose(&s, 3.0);
    let joints = s.joint_positions(&theta).unwrap();
    let at = |name: &str| joints[s.bone_index(name).unwrap()];
    // Head: pelvis 0.10 + spine 0.22 + chest 0.22 + neck 0.08 above the root at y = −0.05.
    assert!((at("head") - vector![0.0, -0.05 + 0.62, 3.0]).norm() < 1e-5);
    // Left shoulder: chest origin (y = 0.27) + 0.18 up, then the clavicle's 0.16 to +x.
    assert!((at("left_upper_arm") - vector![0.16, 0.27 + 0.18, 3.0]).norm() < 1e-5);
    // Right knee: hip at x = −0.10, 0.42 below.
    assert!((at("right_shin") - vector![-0.10, -0.05 - 0.42, 3.0]).norm() < 1e-5);
}

proptest! {
    #[test]
    fn forward_kinematics_keeps_bone_lengths_and_attaches_children(seed in any::<u64>()) {
        let s = human_skeleton(48).unwrap();
        let (lo, hi) = s.limits();
        let mut rng = pf_core::RandomStreams::new(seed).stream(0, pf_core::Stage::Model(0));
        let theta: Vec<f32> = (0..s.dofs()).map(|i| {
            if lo[i].is_finite() { lo[i] + (hi[i] - lo[i]) * rng.uniform() as f32 } else { rng.gaussian_f32() }
        }).collect();
        let caps = s.capsules(&theta).unwrap();
        for (bone, c) in s.bones().iter().zip(&caps) {
            prop_assert!(((c.b - c.a).norm() - bone.length).abs() < 1e-4);
        }
        // A chained child (offset = parent's length along its direction) starts where its parent ends.
        let fore = s.bone_index("left_forearm").unwrap();
        let upper_end = caps.iter().zip(s.bones()).filter(|(_, b)| b.name.starts_with("left_upper_arm")).map(|(c, _)| c.b);
        prop_assert!(upper_end.clone().any(|e| (e - caps[fore].a).norm() < 1e-4));
    }
}

#[test]
fn skeleton_files_round_trip_and_bad_files_are_clear_errors() {
    let dir = std::env::temp_dir().join(format!("streampf-skeleton-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("human.json");
    let s = human_skeleton(40).unwrap();
    s.save(&path).unwrap();
    assert_eq!(Skeleton::load(&path).unwrap(), s);

    let write = |name: &str, text: &str| {
        let p = dir.join(name);
        std::fs::write(&p, text).unwrap();
        p
    };
    let corrupt = write("corrupt.json", "{ \"bones\": [ {\"name\": ");
    assert!(matches!(
        Skeleton::load(&corrupt),
        Err(BodyError::SkeletonFile { .. })
    ));
    assert!(matches!(
        Skeleton::load(&dir.join("missing.json")),
        Err(BodyError::SkeletonFile { .. })
    ));
    let mut spec = s.spec();
    spec.bones[3].parent = Some("no_such_bone".into());
    let err = Skeleton::new(spec).unwrap_err().to_string();
    assert!(err.contains("no_such_bone"), "{err}");
    let mut spec = s.spec();
    spec.bones[2].radius = -1.0;
    assert!(Skeleton::new(spec).is_err());
    let mut spec = s.spec();
    spec.bones[5].name = spec.bones[4].name.clone();
    assert!(
        Skeleton::new(spec)
            .unwrap_err()
            .to_string()
            .contains("used twice")
    );
    assert!(Skeleton::new(SkeletonSpec { bones: vec![] }).is_err());
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn unknown_joints_and_bad_poses_are_clear_errors() {
    let s = human_skeleton(BASE_CAPSULES).unwrap();
    match s.angles_of("left_tentacle") {
        Err(BodyError::UnknownJoint { name, known }) => {
            assert_eq!(name, "left_tentacle");
            assert!(known.contains("left_forearm"));
        }
        other => panic!("{other:?}"),
    }
    assert!(matches!(
        s.capsules(&[0.0; 3]),
        Err(BodyError::InvalidPose(_))
    ));
    let mut theta = standing_pose(&s, 3.0);
    theta[7] = f32::NAN;
    assert!(matches!(s.capsules(&theta), Err(BodyError::InvalidPose(_))));
}

/// Points from ray-casting `caps` from the origin over a grid of directions (the synthetic
/// stereo cloud of a pose, without noise).
fn cast(caps: &[body_tracker::Capsule], n: usize) -> Vec<Vector3<f32>> {
    let mut points = Vec::new();
    for i in 0..n {
        for j in 0..n {
            let dir = vector![
                -0.35 + 0.7 * i as f32 / n as f32,
                -0.45 + 0.9 * j as f32 / n as f32,
                1.0
            ]
            .normalize();
            let hit = caps
                .iter()
                .filter_map(|c| ray_capsule(&Vector3::zeros(), &dir, c))
                .fold(f32::INFINITY, f32::min);
            if hit.is_finite() {
                points.push(dir * hit);
            }
        }
    }
    points
}

#[test]
fn the_true_pose_explains_its_own_points_and_a_moved_pose_does_not() {
    let s = human_skeleton(48).unwrap();
    let theta = standing_pose(&s, 3.0);
    let caps = s.capsules(&theta).unwrap();
    let points = cast(&caps, 40);
    assert!(points.len() > 100, "{} points", points.len());
    let rays = Rays::through(Vector3::zeros(), &points).unwrap();
    let params = CapsuleLikelihoodParams::new(0.1, 0.02).unwrap();
    let own = sum_of_squared_distances(&caps, &rays, params.tau);
    assert!(own < 1e-8 * points.len() as f64, "M = {own}");
    let mut moved = theta.clone();
    moved[0] += 0.05;
    let other = sum_of_squared_distances(&s.capsules(&moved).unwrap(), &rays, params.tau);
    assert!(other > 100.0 * (own + 1e-9));
    assert!(params.log_likelihood(own) > params.log_likelihood(other));
    // No capsule at all: every point is τ away.
    let none = sum_of_squared_distances(&[], &rays, params.tau);
    assert!((none - points.len() as f64 * 0.01).abs() < 1e-6);
}

#[test]
fn the_rayon_version_matches_listing_1_2_bit_for_bit() {
    let s = human_skeleton(48).unwrap();
    let base = standing_pose(&s, 3.0);
    let points = cast(&s.capsules(&base).unwrap(), 30);
    let rays = Rays::through(Vector3::zeros(), &points).unwrap();
    let mut rng = pf_core::RandomStreams::new(4).stream(0, pf_core::Stage::Model(0));
    let samples: Vec<_> = (0..37)
        .map(|_| {
            let theta: Vec<f32> = base.iter().map(|x| x + 0.05 * rng.gaussian_f32()).collect();
            s.capsules(&theta).unwrap()
        })
        .collect();
    let a = listing_1_2(&samples, &rays, 0.1);
    let b = parallel_over_samples(&samples, &rays, 0.1);
    assert_eq!(
        a.iter().map(|x| x.to_bits()).collect::<Vec<_>>(),
        b.iter().map(|x| x.to_bits()).collect::<Vec<_>>()
    );
}

#[test]
fn bad_points_and_parameters_are_clear_errors() {
    let origin = Vector3::zeros();
    let err = Rays::through(
        origin,
        &[vector![0.0, 0.0, 1.0], vector![f32::NAN, 0.0, 1.0]],
    )
    .unwrap_err();
    assert!(err.to_string().contains("point 1"), "{err}");
    assert!(Rays::through(origin, &[origin]).is_err());
    assert!(CapsuleLikelihoodParams::new(0.0, 1.0).is_err());
    assert!(CapsuleLikelihoodParams::new(0.1, f32::NAN).is_err());
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 200, failure_persistence: None, ..ProptestConfig::default() })]

    /// Bounding-sphere culling only skips capsules that are τ away: the culled sum is Listing
    /// 1.2's, for poses far from the points' own, points behind the camera and any τ.
    #[test]
    fn culled_sum_matches_listing_1_2(seed in any::<u64>(), tau in 0.005f32..0.5, spread in 0.0f32..0.5) {
        let s = human_skeleton(48).unwrap();
        let base = standing_pose(&s, 3.0);
        let mut rng = pf_core::RandomStreams::new(seed).stream(0, pf_core::Stage::Model(0));
        let mut points = cast(&s.capsules(&base).unwrap(), 16);
        for _ in 0..40 {
            points.push(vector![rng.gaussian_f32(), rng.gaussian_f32(), 3.0 * rng.gaussian_f32()]);
        }
        let rays = Rays::through(Vector3::zeros(), &points).unwrap();
        let theta: Vec<f32> = base.iter().map(|x| x + spread * rng.gaussian_f32()).collect();
        let caps = s.capsules(&theta).unwrap();
        let want = sum_of_squared_distances(&caps, &rays, tau);
        let got = culled_sum_of_squared_distances(&caps, &rays, tau);
        prop_assert!((got - want).abs() <= 1e-6 * (1.0 + want), "culled {} vs {}", got, want);
    }

    /// The all-cores form sums the same terms in chunks: the same M to f64 rounding, on frames
    /// of several chunks (and of none).
    #[test]
    fn parallel_culled_sum_is_the_culled_sum(seed in any::<u64>(), copies in 0usize..40, tau in 0.005f32..0.5) {
        let s = human_skeleton(48).unwrap();
        let base = standing_pose(&s, 3.0);
        let mut rng = pf_core::RandomStreams::new(seed).stream(0, pf_core::Stage::Model(0));
        let surface = cast(&s.capsules(&base).unwrap(), 16);
        let points: Vec<Vector3<f32>> = (0..copies)
            .flat_map(|_| surface.clone())
            .map(|p| p + 0.01 * vector![rng.gaussian_f32(), rng.gaussian_f32(), rng.gaussian_f32()])
            .collect();
        let rays = Rays::through(Vector3::zeros(), &points).unwrap();
        let caps = s.capsules(&base).unwrap();
        let want = culled_sum_of_squared_distances(&caps, &rays, tau);
        let got = culled_sum_of_squared_distances_parallel(&caps, &rays, tau);
        prop_assert!((got - want).abs() <= 1e-9 * (1.0 + want), "parallel {} vs {}", got, want);
    }
}

/// Partitioned sampling's parts of the default human, at every capsule count: the trunk is the
/// root and the bones above a branch (pelvis, spine, chest), the limbs the rest (neck and head,
/// arms, legs); together they are every pose value once. The schedule gives the first half of
/// the layers to the trunk; one layer stays the plain step.
#[test]
fn the_human_partitions_into_trunk_and_limbs() {
    use body_tracker::partitioned_schedule;
    use pf_core::anneal::Annealing;
    for capsules in [19, 30, 48] {
        let skeleton = body_tracker::human_skeleton(capsules).unwrap();
        let (trunk, limbs) = skeleton.trunk_and_limbs();
        let mut all: Vec<usize> = trunk.iter().chain(&limbs).copied().collect();
        all.sort_unstable();
        assert_eq!(all, (0..skeleton.dofs()).collect::<Vec<_>>(), "{capsules}");
        assert!(trunk.starts_with(&[0, 1, 2, 3, 4, 5]));
        for bone in ["spine", "chest"] {
            let angles = skeleton.angles_of(bone).unwrap();
            assert!(angles.clone().all(|d| trunk.contains(&d)), "{bone}");
        }
        for bone in [
            "neck",
            "head",
            "left_forearm",
            "right_upper_arm",
            "left_thigh",
            "right_shin",
        ] {
            let angles = skeleton.angles_of(bone).unwrap();
            assert!(!angles.is_empty() || bone == "head");
            assert!(angles.clone().all(|d| limbs.contains(&d)), "{bone}");
        }
        let schedule = partitioned_schedule(&skeleton, &Annealing::survival(5, 0.5, 0.7)).unwrap();
        assert!(schedule.validate_for(skeleton.dofs()).is_ok());
        assert_eq!(
            schedule.diffused[..3],
            [trunk.clone(), trunk.clone(), trunk.clone()]
        );
        assert_eq!(schedule.diffused[3..], [limbs.clone(), limbs.clone()]);
        assert_eq!(schedule.sigma_scale(3), 1.0);
        assert_eq!(
            partitioned_schedule(&skeleton, &Annealing::none()).unwrap(),
            Annealing::none()
        );
    }
}
