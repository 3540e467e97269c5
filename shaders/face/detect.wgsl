// The Viola–Jones (Haar cascade) detector over an image pyramid, as four passes: each level's
// integral and squared-integral images (rows, then columns), every window's verdict (one
// invocation per window), and the scan of each row of windows that applies OpenCV's skip rule
// and collects the faces. CPU twin: face_tracker::detect::Cascade (its scan and run_at);
// launcher: face_tracker::detect::gpu::GpuCascade.
//
// The tables hold u32 sums that may wrap: a rectangle's sum is a difference of four corners, and
// wrapping arithmetic gives it exactly as long as the sum itself fits (a 24×24 window of 255² is
// 3.7e7). The window's variance is computed in exact 64-bit integers (two u32 words) as the CPU
// does in i64; the features and stage sums are f32 where the CPU uses f64, so a window whose sum
// lies within rounding of a threshold may go the other way (the tests bound how often).

struct Level {
    width: u32,
    height: u32,
    // Window step on this level (2 on the finer levels, 1 once the frame is halved).
    step: u32,
    // First u32 word of the level's 8-bit pixels in `pixels` (four to a word).
    pixel_word: u32,
    // First value of the level's (width + 1) × (height + 1) tables.
    table: u32,
    // First of the level's windows in `verdicts`; windows per row and rows of windows.
    window_first: u32,
    columns: u32,
    rows: u32,
    // First of the level's pixel rows, table columns and window rows in the passes' flat grids.
    pixel_row_first: u32,
    table_column_first: u32,
    window_row_first: u32,
    _pad: u32,
}

struct Params {
    levels: u32,
    window_width: u32,
    window_height: u32,
    stages: u32,
    // Totals of the passes' grids.
    pixel_rows: u32,
    table_columns: u32,
    windows: u32,
    window_rows: u32,
    // Invocations per row of a dispatch grid (a flat index is x + y * grid_width).
    grid_width: u32,
    max_hits: u32,
    // Where each section of `cascade` starts (in words).
    stages_at: u32,
    trees_at: u32,
    nodes_at: u32,
    leaves_at: u32,
    rects_at: u32,
    feature_starts_at: u32,
}

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> levels: array<Level>;
@group(0) @binding(2) var<storage, read> pixels: array<u32>;
@group(0) @binding(3) var<storage, read_write> integral: array<u32>;
@group(0) @binding(4) var<storage, read_write> squares: array<u32>;
@group(0) @binding(5) var<storage, read_write> verdicts: array<u32>;
// [0]: how many faces were found (may exceed max_hits: the launcher then falls back to the CPU);
// then (level, x, y, 0) per face.
@group(0) @binding(6) var<storage, read_write> hits: array<atomic<u32>>;
// Stages (threshold bits, first tree, end tree, 0), trees (first node, first leaf), nodes
// (feature, threshold bits, left, right), leaves (f32 bits), rectangles (x | y << 8 | w << 16 |
// h << 24, weight bits) and each feature's first rectangle (features + 1 entries).
@group(0) @binding(7) var<storage, read> cascade: array<u32>;

const FLAT: u32 = 0u;
const LATER_STAGE: u32 = 0u;
const FIRST_STAGE: u32 = 1u;
const FACE: u32 = 2u;

fn flat_index(gid: vec3<u32>) -> u32 {
    return gid.x + gid.y * params.grid_width;
}

// The level whose part of a flat grid holds `index` (`firsts`: 0 pixel rows, 1 table columns,
// 2 windows, 3 window rows).
fn level_of(index: u32, which: u32) -> u32 {
    var found = 0u;
    for (var l = 1u; l < params.levels; l++) {
        var first: u32;
        switch which {
            case 0u: { first = levels[l].pixel_row_first; }
            case 1u: { first = levels[l].table_column_first; }
            case 2u: { first = levels[l].window_first; }
            default: { first = levels[l].window_row_first; }
        }
        if index >= first {
            found = l;
        }
    }
    return found;
}

fn pixel(level: Level, x: u32, y: u32) -> u32 {
    let byte = y * level.width + x;
    return (pixels[level.pixel_word + byte / 4u] >> (8u * (byte % 4u))) & 0xffu;
}

// Each pixel row's running sums, into table row y + 1 (row 0 and column 0 stay zero).
@compute @workgroup_size(64)
fn integral_rows(@builtin(global_invocation_id) gid: vec3<u32>) {
    let index = flat_index(gid);
    if index >= params.pixel_rows {
        return;
    }
    let level = levels[level_of(index, 0u)];
    let y = index - level.pixel_row_first;
    let stride = level.width + 1u;
    let row = level.table + (y + 1u) * stride;
    var sum = 0u;
    var sum_sq = 0u;
    integral[row] = 0u;
    squares[row] = 0u;
    if y == 0u {
        for (var x = 0u; x < stride; x++) {
            integral[level.table + x] = 0u;
            squares[level.table + x] = 0u;
        }
    }
    for (var x = 0u; x < level.width; x++) {
        let v = pixel(level, x, y);
        sum += v;
        sum_sq += v * v;
        integral[row + x + 1u] = sum;
        squares[row + x + 1u] = sum_sq;
    }
}

// Each table column's running sum of the row sums (wrapping).
@compute @workgroup_size(64)
fn integral_columns(@builtin(global_invocation_id) gid: vec3<u32>) {
    let index = flat_index(gid);
    if index >= params.table_columns {
        return;
    }
    let level = levels[level_of(index, 1u)];
    let x = index - level.table_column_first;
    let stride = level.width + 1u;
    var sum = 0u;
    var sum_sq = 0u;
    for (var y = 1u; y <= level.height; y++) {
        let at = level.table + y * stride + x;
        sum += integral[at];
        sum_sq += squares[at];
        integral[at] = sum;
        squares[at] = sum_sq;
    }
}

fn rect_sum(corner: u32, stride: u32, w: u32, h: u32) -> u32 {
    return integral[corner + h * stride + w] - integral[corner + w] - integral[corner + h * stride]
        + integral[corner];
}

fn rect_sum_of_squares(corner: u32, stride: u32, w: u32, h: u32) -> u32 {
    return squares[corner + h * stride + w] - squares[corner + w] - squares[corner + h * stride]
        + squares[corner];
}

// a · b as 64 bits (low word, high word).
fn multiply_wide(a: u32, b: u32) -> vec2<u32> {
    let a_lo = a & 0xffffu;
    let a_hi = a >> 16u;
    let b_lo = b & 0xffffu;
    let b_hi = b >> 16u;
    let lo_lo = a_lo * b_lo;
    let mid = a_hi * b_lo + (lo_lo >> 16u);
    let mid2 = a_lo * b_hi + (mid & 0xffffu);
    return vec2<u32>((mid2 << 16u) | (lo_lo & 0xffffu), a_hi * b_hi + (mid >> 16u) + (mid2 >> 16u));
}

// Feature f's weighted sum at the window whose corner is `origin`.
fn feature_value(f: u32, origin: u32, stride: u32) -> f32 {
    let first = cascade[params.feature_starts_at + f];
    let end = cascade[params.feature_starts_at + f + 1u];
    var value = 0.0;
    for (var r = first; r < end; r++) {
        let packed = cascade[params.rects_at + 2u * r];
        let weight = bitcast<f32>(cascade[params.rects_at + 2u * r + 1u]);
        let x = packed & 0xffu;
        let y = (packed >> 8u) & 0xffu;
        let w = (packed >> 16u) & 0xffu;
        let h = packed >> 24u;
        value += weight * f32(rect_sum(origin + y * stride + x, stride, w, h));
    }
    return value;
}

fn classify(level: Level, x: u32, y: u32) -> u32 {
    let stride = level.width + 1u;
    let origin = level.table + y * stride + x;
    // The variance over the window less a one-pixel border, in exact integers.
    let w = params.window_width;
    let h = params.window_height;
    let area = (w - 2u) * (h - 2u);
    let inner = origin + stride + 1u;
    let sum = rect_sum(inner, stride, w - 2u, h - 2u);
    let sum_sq = rect_sum_of_squares(inner, stride, w - 2u, h - 2u);
    let a = multiply_wide(area, sum_sq);
    let b = multiply_wide(sum, sum);
    if a.y < b.y || (a.y == b.y && a.x <= b.x) {
        return FLAT;
    }
    let borrow = select(0u, 1u, a.x < b.x);
    let spread = f32(a.y - b.y - borrow) * 4294967296.0 + f32(a.x - b.x);
    let norm = 1.0 / sqrt(spread);
    if f32(area) * norm >= 0.1 {
        return FLAT;
    }
    for (var s = 0u; s < params.stages; s++) {
        let stage = params.stages_at + 4u * s;
        let threshold = bitcast<f32>(cascade[stage]);
        var total = 0.0;
        for (var t = cascade[stage + 1u]; t < cascade[stage + 2u]; t++) {
            let first_node = cascade[params.trees_at + 2u * t];
            let first_leaf = cascade[params.trees_at + 2u * t + 1u];
            var index = 0i;
            loop {
                let node = params.nodes_at + 4u * (first_node + u32(index));
                let value = feature_value(cascade[node], origin, stride) * norm;
                if value < bitcast<f32>(cascade[node + 1u]) {
                    index = bitcast<i32>(cascade[node + 2u]);
                } else {
                    index = bitcast<i32>(cascade[node + 3u]);
                }
                if index <= 0i {
                    break;
                }
            }
            total += bitcast<f32>(cascade[params.leaves_at + first_leaf + u32(-index)]);
        }
        if total < threshold {
            return select(LATER_STAGE, FIRST_STAGE, s == 0u);
        }
    }
    return FACE;
}

// One window each: FLAT or LATER_STAGE (0), FIRST_STAGE or FACE.
@compute @workgroup_size(64)
fn classify_windows(@builtin(global_invocation_id) gid: vec3<u32>) {
    let index = flat_index(gid);
    if index >= params.windows {
        return;
    }
    let level = levels[level_of(index, 2u)];
    let local = index - level.window_first;
    let x = (local % level.columns) * level.step;
    let y = (local / level.columns) * level.step;
    verdicts[index] = classify(level, x, y);
}

// One row of windows each, left to right as the CPU scans: a window the first stage rejects
// skips the next one (OpenCV's rule), and a face is appended to `hits`.
@compute @workgroup_size(64)
fn collect_faces(@builtin(global_invocation_id) gid: vec3<u32>) {
    let index = flat_index(gid);
    if index >= params.window_rows {
        return;
    }
    let l = level_of(index, 3u);
    let level = levels[l];
    let row = index - level.window_row_first;
    let first = level.window_first + row * level.columns;
    var column = 0u;
    while column < level.columns {
        let verdict = verdicts[first + column];
        if verdict == FACE {
            let slot = atomicAdd(&hits[0], 1u);
            if slot < params.max_hits {
                atomicStore(&hits[1u + 4u * slot], l);
                atomicStore(&hits[2u + 4u * slot], column * level.step);
                atomicStore(&hits[3u + 4u * slot], row * level.step);
            }
        } else if verdict == FIRST_STAGE {
            column += 1u;
        }
        column += 1u;
    }
}
