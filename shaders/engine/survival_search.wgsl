// The survival rule's bisection spread over the GPU. survival_beta (normalise_target.wgsl) tests
// max_beta, then bisects (0, max_beta] in BISECTION_LEVELS levels, one ESS reduction after another
// in one workgroup: 21 serial passes a layer. Here the levels are taken SEARCH_LEVELS at a time,
// one dispatch a round (survival_round.wgsl): a round's workgroups each test one node of the
// round's subtree of midpoints (2^levels - 1 nodes, heap order: node i's children are 2i + 1, the
// ESS fell short and hi = mid, and 2i + 2, it did not and lo = mid), round 0 also the test at
// max_beta (its last slot). Each node's midpoint is computed by the bisection's own float
// operations along its path, and each ESS by the same reduction (tempered_ess.wgsl), so walking
// the rounds' decisions gives survival_beta's result bit for bit.
// A library: the including kernel declares `survival_decisions` (array<u32>; 1 where the node's
// ESS reached the wanted one), laid out [(t * SEARCH_ROUNDS + round) * SEARCH_SLOTS + node].
// pf_gpu::filter::survival sets SEARCH_LEVELS from the target count.
// CPU twin: pf_core::anneal::survival_beta (the serial bisection).

const BISECTION_LEVELS: u32 = 20u;
const SEARCH_LEVELS: u32 = 7u;
const SEARCH_SLOTS: u32 = 1u << SEARCH_LEVELS;
const SEARCH_ROUNDS: u32 = (BISECTION_LEVELS + SEARCH_LEVELS - 1u) / SEARCH_LEVELS;
// Round 0's slot for the test at max_beta.
const MAX_BETA_SLOT: u32 = SEARCH_SLOTS - 1u;

fn decision_index(t: u32, round: u32, node: u32) -> u32 {
    return (t * SEARCH_ROUNDS + round) * SEARCH_SLOTS + node;
}

fn levels_in_round(round: u32) -> u32 {
    return min(SEARCH_LEVELS, BISECTION_LEVELS - round * SEARCH_LEVELS);
}

// The bisection's interval (lo, hi) after round `round`'s decisions, walked from `interval`.
fn walk_round(t: u32, round: u32, interval: vec2<f32>) -> vec2<f32> {
    var lo = interval.x;
    var hi = interval.y;
    var node = 0u;
    for (var level = 0u; level < levels_in_round(round); level = level + 1u) {
        let mid = 0.5 * (lo + hi);
        if (survival_decisions[decision_index(t, round, node)] == 1u) {
            lo = mid;
            node = 2u * node + 2u;
        } else {
            hi = mid;
            node = 2u * node + 1u;
        }
    }
    return vec2<f32>(lo, hi);
}

// The interval at the start of round `round`: the rounds before it walked from (0, max_beta).
fn round_start(t: u32, round: u32, max_beta: f32) -> vec2<f32> {
    var interval = vec2<f32>(0.0, max_beta);
    for (var r = 0u; r < round; r = r + 1u) {
        interval = walk_round(t, r, interval);
    }
    return interval;
}

// The midpoint node `node` tests, from its round's start: the bisection's steps along the node's
// path (the bits of node + 1 below its leading one, first step first).
fn node_midpoint(interval: vec2<f32>, node: u32) -> f32 {
    let path = node + 1u;
    var lo = interval.x;
    var hi = interval.y;
    for (var k = firstLeadingBit(path); k > 0u; k = k - 1u) {
        let mid = 0.5 * (lo + hi);
        if (((path >> (k - 1u)) & 1u) == 1u) {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    return 0.5 * (lo + hi);
}

// Target t's survival beta from every round's decisions: survival_beta's result.
fn searched_beta(t: u32, max_beta: f32) -> f32 {
    if (survival_decisions[decision_index(t, 0u, MAX_BETA_SLOT)] == 1u) {
        return max_beta;
    }
    let interval = round_start(t, SEARCH_ROUNDS, max_beta);
    return 0.5 * (interval.x + interval.y);
}
