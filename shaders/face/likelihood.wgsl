// The sparse-template face likelihood (eq. 10-13 of the face paper) on the GPU. Two layouts:
// weigh_faces is the paper's (one workgroup per particle, one invocation per feature point,
// looping when a template has more points than the workgroup, the sums reduced in workgroup
// memory); weigh_faces_packed puts WG / LANES particles in a workgroup, LANES invocations each,
// and weigh_faces_packed_staged does too with the face's template staged in workgroup memory.
// The grid's y is the face: one dispatch weighs every face of a frame (the batched form), or one
// dispatch per face with `face_offset` (the paper's form). CPU twin:
// face_tracker::likelihood::residual_error_through (residual_error through weak perspective).
// Launcher: face_tracker::likelihood::gpu::FaceLikelihoodGpu.
//
// Per point facing the camera ((R N)_z >= 0): p = S R2x3 P + (Tx, Ty) (weak perspective, the
// paper's), or through a pinhole (inverse_focal = 1/f > 0) that point magnified by
// 1 / (1 - S (R P)_z / f) about the principal point (through_lens; CPU twin
// face_tracker::likelihood::Lens::apply); a point at or behind the camera counts as outside the frame.
// I(p) bilinear, through the texture unit's filter (pf_gpu::image: 8-bit fractional weights; the
// CPU twin rounds its weights the same way), kappa =
// (alpha I(p) - J) / J, rho = kappa^2 / (kappa^2 + 1), computed as d^2 / (d^2 + J^2) with d =
// alpha I(p) - J (the same value, one division); a point outside the frame has rho = 1.
// epsilon = mean rho over those points (1 when fewer than min_visible_share of the points face
// the camera), log pi = -sharpness ln max(epsilon, floor).
//
// Layouts: states (the filter's, common.wgsl); frame: an R8Unorm texture of the 8-bit gray levels
// (pf_gpu::GrayTexture) with a linear, clamp-to-edge sampler; points of
// face t at [(t * max_points + i) * 2] = (P, J) and [.. + 1] = (N, 0), point_counts[t];
// log_likelihood and errors [t * M + m]. weigh_estimates checks each face's pose estimate
// (pose_estimates [t * 7 + d], the filter's estimate) and writes its epsilon to
// estimate_errors[t]: the tracker's failure test, without a readback of the frame to the host.

struct FaceParams {
    width: u32,
    height: u32,
    max_points: u32,
    face_offset: u32,
    sharpness: f32,
    min_error: f32,
    // A pose showing fewer than this share of the points has epsilon = 1.
    min_visible_share: f32,
    inverse_focal: f32,
    principal_x: f32,
    principal_y: f32,
    // 1 / width and 1 / height: pixel (x, y) is the texture's ((x + 0.5) / width, (y + 0.5) / height).
    texel_x: f32,
    texel_y: f32,
}

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> states: array<f32>;
@group(0) @binding(2) var<storage, read_write> log_likelihood: array<f32>;
@group(0) @binding(3) var<uniform> fp: FaceParams;
@group(0) @binding(4) var frame: texture_2d<f32>;
@group(0) @binding(10) var frame_sampler: sampler;
@group(0) @binding(5) var<storage, read> points: array<vec4<f32>>;
@group(0) @binding(6) var<storage, read> point_counts: array<u32>;
@group(0) @binding(7) var<storage, read_write> errors: array<f32>;
@group(0) @binding(8) var<storage, read> pose_estimates: array<f32>;
@group(0) @binding(9) var<storage, read_write> estimate_errors: array<f32>;

const WG: u32 = 256u;
var<workgroup> rho_sums: array<f32, 256>;
var<workgroup> visible_counts: array<f32, 256>;

fn rotation_x(a: f32) -> mat3x3<f32> {
    let c = cos(a);
    let s = sin(a);
    return mat3x3<f32>(vec3<f32>(1.0, 0.0, 0.0), vec3<f32>(0.0, c, s), vec3<f32>(0.0, -s, c));
}

fn rotation_y(a: f32) -> mat3x3<f32> {
    let c = cos(a);
    let s = sin(a);
    return mat3x3<f32>(vec3<f32>(c, 0.0, -s), vec3<f32>(0.0, 1.0, 0.0), vec3<f32>(s, 0.0, c));
}

fn rotation_z(a: f32) -> mat3x3<f32> {
    let c = cos(a);
    let s = sin(a);
    return mat3x3<f32>(vec3<f32>(c, s, 0.0), vec3<f32>(-s, c, 0.0), vec3<f32>(0.0, 0.0, 1.0));
}

// Whether (x, y) lies in [0, w-1] x [0, h-1], where the frame is sampled (false for NaN).
fn inside_frame(x: f32, y: f32) -> bool {
    return x >= 0.0 && y >= 0.0 && x <= f32(fp.width - 1u) && y <= f32(fp.height - 1u);
}

// The texture unit's bilinear sample at pixel (x, y): pixel (x, y) is the texture's
// ((x + 0.5) / width, (y + 0.5) / height). Inside the frame, clamp-to-edge makes the last row and
// column interpolate within their cell, as the CPU's does; outside (NaN included) it is harmless.
fn level_at(x: f32, y: f32) -> f32 {
    let at = vec2<f32>((x + 0.5) * fp.texel_x, (y + 0.5) * fp.texel_y);
    return 255.0 * textureSampleLevel(frame, frame_sampler, at, 0.0).r;
}

// Bilinear sample at (x, y) through the texture unit, or -1 outside the frame (as
// GrayImage::bilinear; the CPU twin is face_tracker::likelihood's Pixels::bilinear).
fn bilinear(x: f32, y: f32) -> f32 {
    if (!inside_frame(x, y)) {
        return -1.0;
    }
    return level_at(x, y);
}

// bilinear without its branch: the texture is read either way, so that the caller's fetches
// need not wait behind a branch.
fn bilinear_or_outside(x: f32, y: f32) -> f32 {
    return select(-1.0, level_at(x, y), inside_frame(x, y));
}

// Lens::MIN_DISTANCE_SHARE.
const MIN_DISTANCE_SHARE: f32 = 0.05;

// Where a point is seen whose weak-perspective image is `weak` and which lies `depth` pixels
// nearer the camera than the face's centre; (-1, -1), outside every frame, when it is at or
// behind the camera.
fn through_lens(weak: vec2<f32>, depth: f32) -> vec2<f32> {
    if (fp.inverse_focal == 0.0) {
        return weak;
    }
    let distance = 1.0 - depth * fp.inverse_focal;
    if (!(distance > MIN_DISTANCE_SHARE)) {
        return vec2<f32>(-1.0, -1.0);
    }
    let principal = vec2<f32>(fp.principal_x, fp.principal_y);
    return principal + (weak - principal) / distance;
}

struct FacePose {
    tx: f32,
    ty: f32,
    scale: f32,
    r: mat3x3<f32>,
    alpha: f32,
}

fn face_pose(tx: f32, ty: f32, scale: f32, rx: f32, ry: f32, rz: f32, alpha: f32) -> FacePose {
    return FacePose(tx, ty, scale, rotation_x(rx) * rotation_y(ry) * rotation_z(rz), alpha);
}

fn particle_pose(t: u32, m: u32) -> FacePose {
    return face_pose(
        states[state_index(t, 0u, m)],
        states[state_index(t, 1u, m)],
        states[state_index(t, 2u, m)],
        states[state_index(t, 3u, m)],
        states[state_index(t, 4u, m)],
        states[state_index(t, 5u, m)],
        states[state_index(t, 6u, m)],
    );
}

fn estimate_pose(t: u32) -> FacePose {
    let b = t * 7u;
    return face_pose(
        pose_estimates[b],
        pose_estimates[b + 1u],
        pose_estimates[b + 2u],
        pose_estimates[b + 3u],
        pose_estimates[b + 4u],
        pose_estimates[b + 5u],
        pose_estimates[b + 6u],
    );
}

// (sum of rho, number of points facing the camera) over points first, first + step, ... of face
// t's template in pose x.
fn accumulate(t: u32, x: FacePose, first: u32, step: u32) -> vec2<f32> {
    let count = min(point_counts[t], fp.max_points);
    var rho_sum = 0.0;
    var visible = 0.0;
    for (var i = first; i < count; i = i + step) {
        let base = (t * fp.max_points + i) * 2u;
        let pj = points[base];
        let n = points[base + 1u].xyz;
        if ((x.r * n).z >= 0.0) {
            visible = visible + 1.0;
            let q = x.r * pj.xyz;
            let p = through_lens(vec2<f32>(x.scale * q.x + x.tx, x.scale * q.y + x.ty), x.scale * q.z);
            let intensity = bilinear(p.x, p.y);
            if (intensity < 0.0) {
                rho_sum = rho_sum + 1.0;
            } else {
                let d = x.alpha * intensity - pj.w;
                let d2 = d * d;
                rho_sum = rho_sum + d2 / (d2 + pj.w * pj.w);
            }
        }
    }
    return vec2<f32>(rho_sum, visible);
}

// (rho, 1) for a template point (P, J) with normal N that faces the camera in pose x, (0, 0) for
// one that faces away. Without branches (a point outside the frame is sampled at a clamped place
// and its rho replaced by 1), so that a loop's texture fetches of several points can be in
// flight together; the same values as accumulate's.
fn point_terms(x: FacePose, pj: vec4<f32>, n: vec3<f32>) -> vec2<f32> {
    let facing = (x.r * n).z >= 0.0;
    let q = x.r * pj.xyz;
    let p = through_lens(vec2<f32>(x.scale * q.x + x.tx, x.scale * q.y + x.ty), x.scale * q.z);
    let intensity = bilinear_or_outside(p.x, p.y);
    let d = x.alpha * intensity - pj.w;
    let d2 = d * d;
    let rho = select(d2 / (d2 + pj.w * pj.w), 1.0, intensity < 0.0);
    return select(vec2<f32>(0.0, 0.0), vec2<f32>(rho, 1.0), facing);
}

// Sums each group of `lanes` consecutive invocations' (rho, shown) in workgroup memory (lanes a
// power of two dividing WG; called by the whole workgroup); the group's first invocation gets
// the total.
fn reduce_groups(lid: u32, lanes: u32, sums: vec2<f32>) -> vec2<f32> {
    rho_sums[lid] = sums.x;
    visible_counts[lid] = sums.y;
    workgroupBarrier();
    let lane = lid % lanes;
    for (var stride = lanes / 2u; stride > 0u; stride = stride / 2u) {
        if (lane < stride) {
            rho_sums[lid] = rho_sums[lid] + rho_sums[lid + stride];
            visible_counts[lid] = visible_counts[lid] + visible_counts[lid + stride];
        }
        workgroupBarrier();
    }
    return vec2<f32>(rho_sums[lid], visible_counts[lid]);
}

// epsilon of face t from its sums: the mean rho over the points shown, or 1 when too few show.
fn epsilon_of(t: u32, rho_sum: f32, shown: f32) -> f32 {
    let count = min(point_counts[t], fp.max_points);
    if (shown > 0.0 && shown >= fp.min_visible_share * f32(count)) {
        return rho_sum / shown;
    }
    return 1.0;
}

// Writes epsilon and the log-likelihood of particle m of face t from its sums.
fn finish(t: u32, m: u32, sums: vec2<f32>) {
    let epsilon = epsilon_of(t, sums.x, sums.y);
    errors[t * params.particles + m] = epsilon;
    log_likelihood[t * params.particles + m] = -fp.sharpness * log(max(epsilon, fp.min_error));
}

// The paper's layout: one workgroup per particle, one invocation per point.
@compute @workgroup_size(256)
fn weigh_faces(@builtin(local_invocation_id) lid3: vec3<u32>, @builtin(workgroup_id) wid: vec3<u32>) {
    let lid = lid3.x;
    let m = wid.x;
    let t = fp.face_offset + wid.y;
    // Workgroup-uniform: the whole workgroup leaves together.
    if (m >= params.particles || t >= params.targets) {
        return;
    }
    let sums = reduce_groups(lid, WG, accumulate(t, particle_pose(t, m), lid, WG));
    if (lid == 0u) {
        finish(t, m, sums);
    }
}

// The packed layout: each workgroup weighs WG / LANES particles, LANES invocations each looping
// over the points (LANES a power of two up to WG, set by the launcher,
// face_tracker::likelihood::gpu::FaceDispatch). Fewer lanes a particle: fewer
// workgroups, less of the per-invocation pose set-up and a shorter reduction, against a longer
// loop.
override LANES: u32 = 64u;

// A packed invocation's place: its lane among its particle's LANES, particle m of face t, and
// whether that particle exists.
struct PackedLane {
    lane: u32,
    m: u32,
    t: u32,
    live: bool,
}

fn packed_lane(lid: u32, wid: vec3<u32>) -> PackedLane {
    let m = wid.x * (WG / LANES) + lid / LANES;
    let t = fp.face_offset + wid.y;
    return PackedLane(lid % LANES, m, t, m < params.particles && t < params.targets);
}

@compute @workgroup_size(256)
fn weigh_faces_packed(@builtin(local_invocation_id) lid3: vec3<u32>, @builtin(workgroup_id) wid: vec3<u32>) {
    let lid = lid3.x;
    let p = packed_lane(lid, wid);
    var sums = vec2<f32>(0.0, 0.0);
    if (p.live) {
        sums = accumulate(p.t, particle_pose(p.t, p.m), p.lane, LANES);
    }
    let total = reduce_groups(lid, LANES, sums);
    if (p.live && p.lane == 0u) {
        finish(p.t, p.m, total);
    }
}

// Face t's template points staged WG at a time in workgroup memory (every particle of a packed
// workgroup weighs the same face), and the count of its points, made workgroup-uniform.
var<workgroup> staged_points: array<vec4<f32>, 512>;
var<workgroup> staged_count: u32;

// `so_far` plus accumulate's sums over the staged chunk's points first, first + step, ... below
// `count`, four a pass.
fn accumulate_staged(so_far: vec2<f32>, x: FacePose, first: u32, step: u32, count: u32) -> vec2<f32> {
    var sums = so_far;
    var i = first;
    for (; i + 3u * step < count; i = i + 4u * step) {
        let a = point_terms(x, staged_points[2u * i], staged_points[2u * i + 1u].xyz);
        let b = point_terms(x, staged_points[2u * (i + step)], staged_points[2u * (i + step) + 1u].xyz);
        let c = point_terms(x, staged_points[2u * (i + 2u * step)], staged_points[2u * (i + 2u * step) + 1u].xyz);
        let d = point_terms(x, staged_points[2u * (i + 3u * step)], staged_points[2u * (i + 3u * step) + 1u].xyz);
        sums = sums + a;
        sums = sums + b;
        sums = sums + c;
        sums = sums + d;
    }
    for (; i < count; i = i + step) {
        sums = sums + point_terms(x, staged_points[2u * i], staged_points[2u * i + 1u].xyz);
    }
    return sums;
}

// The packed layout for many particles a workgroup (few lanes each: the launcher takes it up to
// face_tracker::likelihood::gpu::STAGED_MAX_LANES): the face's template is read from global
// memory once a workgroup, not once a particle, and each lane's points are weighed four at a
// time without branches. With 64 lanes (four particles a workgroup) the staging cost more than
// it saved (docs/BENCHMARKS.md, "Template points in workgroup memory").
@compute @workgroup_size(256)
fn weigh_faces_packed_staged(@builtin(local_invocation_id) lid3: vec3<u32>, @builtin(workgroup_id) wid: vec3<u32>) {
    let lid = lid3.x;
    let p = packed_lane(lid, wid);
    let t = p.t;
    if (lid == 0u) {
        staged_count = 0u;
        if (t < params.targets) {
            staged_count = min(point_counts[t], fp.max_points);
        }
    }
    let count = workgroupUniformLoad(&staged_count);
    var pose = face_pose(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    if (p.live) {
        pose = particle_pose(t, p.m);
    }
    var sums = vec2<f32>(0.0, 0.0);
    // Chunks of WG points, a multiple of LANES: each lane meets its points in the order
    // accumulate would.
    for (var chunk = 0u; chunk < count; chunk = chunk + WG) {
        let i = chunk + lid;
        if (i < count) {
            let base = (t * fp.max_points + i) * 2u;
            staged_points[2u * lid] = points[base];
            staged_points[2u * lid + 1u] = points[base + 1u];
        }
        workgroupBarrier();
        if (p.live) {
            sums = accumulate_staged(sums, pose, p.lane, LANES, min(WG, count - chunk));
        }
        workgroupBarrier();
    }
    let total = reduce_groups(lid, LANES, sums);
    if (p.live && p.lane == 0u) {
        finish(t, p.m, total);
    }
}

// epsilon of each face's pose estimate: one workgroup per face (grid y), 256 invocations over
// its points.
@compute @workgroup_size(256)
fn weigh_estimates(@builtin(local_invocation_id) lid3: vec3<u32>, @builtin(workgroup_id) wid: vec3<u32>) {
    let lid = lid3.x;
    let t = wid.y;
    // Workgroup-uniform: the whole workgroup leaves together.
    if (t >= params.targets) {
        return;
    }
    let sums = reduce_groups(lid, WG, accumulate(t, estimate_pose(t), lid, WG));
    if (lid == 0u) {
        estimate_errors[t] = epsilon_of(t, sums.x, sums.y);
    }
}
