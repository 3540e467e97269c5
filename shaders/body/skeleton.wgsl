// Forward kinematics of an articulated skeleton on the GPU, so that a tracking frame uploads only
// its points: the pose samples already live on the GPU (the filter's state buffer), and this
// kernel turns each into its capsules for body/likelihood.wgsl. A second entry turns the
// likelihood's sums into log-likelihoods. CPU twin: body_tracker::Skeleton::capsules. Launcher:
// body_tracker::skeleton::gpu::BodyLikelihoodGpu.
//
// Conventions (body_tracker::skeleton): the root's frame is origin (t0, t1, t2) and rotation
// Rz(t5) Ry(t4) Rx(t3); a child's origin is o_parent + R_parent offset and its rotation
// R_parent R_joint, with R_joint the product of the rotations about the bone's joint axes in
// order. The capsule runs from o to o + R extent with the bone's radius.
//
// Layouts: states[(t * D + d) * M + m] for sample s = t * M + m (the filter's batch layout);
// capsules[(s * K + k) * 2] = (a, r), [.. + 1] = (b, 0); frames[(s * K + k) * 4 + c] holds the
// bone's rotation columns (c = 0..2) and origin (c = 3).

struct KinematicsParams {
    // Samples to pose (T * M).
    samples: u32,
    // Particles per target M: the stride of the state layout.
    particles: u32,
    // Pose values per sample D.
    dims: u32,
    // Bones (= capsules) K.
    bones: u32,
    // -1 / (2 sigma^2) of eq. 3.
    log_scale: f32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

struct Bone {
    // Where the bone starts in its parent's frame (ignored for the root).
    offset: vec3<f32>,
    radius: f32,
    // direction * length in the bone's own frame.
    extent: vec3<f32>,
    // The parent's index, or 0xffffffff for the root (always bone 0).
    parent: u32,
    // (number of joint axes, index in the pose of the first angle, axes 2 bits each: 0 x, 1 y,
    // 2 z, unused).
    joint: vec4<u32>,
}

@group(0) @binding(0) var<uniform> kp: KinematicsParams;
@group(0) @binding(1) var<storage, read> bones: array<Bone>;
@group(0) @binding(2) var<storage, read> states: array<f32>;
@group(0) @binding(3) var<storage, read_write> frames: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read_write> capsules: array<vec4<f32>>;
@group(0) @binding(5) var<storage, read> sums: array<f32>;
@group(0) @binding(6) var<storage, read_write> log_likelihood: array<f32>;

fn pose_value(s: u32, d: u32) -> f32 {
    let t = s / kp.particles;
    let m = s - t * kp.particles;
    return states[(t * kp.dims + d) * kp.particles + m];
}

fn rotation_about(axis: u32, angle: f32) -> mat3x3<f32> {
    let c = cos(angle);
    let s = sin(angle);
    if (axis == 0u) {
        return mat3x3<f32>(vec3<f32>(1.0, 0.0, 0.0), vec3<f32>(0.0, c, s), vec3<f32>(0.0, -s, c));
    }
    if (axis == 1u) {
        return mat3x3<f32>(vec3<f32>(c, 0.0, -s), vec3<f32>(0.0, 1.0, 0.0), vec3<f32>(s, 0.0, c));
    }
    return mat3x3<f32>(vec3<f32>(c, s, 0.0), vec3<f32>(-s, c, 0.0), vec3<f32>(0.0, 0.0, 1.0));
}

// One invocation per sample walks the bones in order (parents come before children), keeping
// the frames in global scratch: a private array of up to 128 frames would spill anyway.
@compute @workgroup_size(64)
fn forward_kinematics(@builtin(global_invocation_id) gid: vec3<u32>) {
    let s = gid.x;
    if (s >= kp.samples) {
        return;
    }
    for (var k = 0u; k < kp.bones; k = k + 1u) {
        let bone = bones[k];
        var joint = mat3x3<f32>(vec3<f32>(1.0, 0.0, 0.0), vec3<f32>(0.0, 1.0, 0.0), vec3<f32>(0.0, 0.0, 1.0));
        for (var i = 0u; i < bone.joint.x; i = i + 1u) {
            let axis = (bone.joint.z >> (2u * i)) & 3u;
            joint = joint * rotation_about(axis, pose_value(s, bone.joint.y + i));
        }
        var origin: vec3<f32>;
        var rotation: mat3x3<f32>;
        if (bone.parent == 0xffffffffu) {
            origin = vec3<f32>(pose_value(s, 0u), pose_value(s, 1u), pose_value(s, 2u));
            let root = rotation_about(2u, pose_value(s, 5u)) * rotation_about(1u, pose_value(s, 4u))
                * rotation_about(0u, pose_value(s, 3u));
            rotation = root * joint;
        } else {
            let p = (s * kp.bones + bone.parent) * 4u;
            let parent_rotation = mat3x3<f32>(frames[p].xyz, frames[p + 1u].xyz, frames[p + 2u].xyz);
            origin = frames[p + 3u].xyz + parent_rotation * bone.offset;
            rotation = parent_rotation * joint;
        }
        let f = (s * kp.bones + k) * 4u;
        frames[f] = vec4<f32>(rotation[0], 0.0);
        frames[f + 1u] = vec4<f32>(rotation[1], 0.0);
        frames[f + 2u] = vec4<f32>(rotation[2], 0.0);
        frames[f + 3u] = vec4<f32>(origin, 0.0);
        let c = (s * kp.bones + k) * 2u;
        capsules[c] = vec4<f32>(origin, bone.radius);
        capsules[c + 1u] = vec4<f32>(origin + rotation * bone.extent, 0.0);
    }
}

// log p(X | theta_s) = -M_s / (2 sigma^2) (eq. 3), into the filter's log-likelihood buffer.
@compute @workgroup_size(64)
fn log_likelihood_from_sums(@builtin(global_invocation_id) gid: vec3<u32>) {
    let s = gid.x;
    if (s >= kp.samples) {
        return;
    }
    log_likelihood[s] = kp.log_scale * sums[s];
}
