// The lag window's parameters, shared by lag_ring.wgsl and lag_summary.wgsl (a library prepended
// to both; mirror: the LagParams of pf_gpu::filter::lag_window, written before each whole step).

struct LagParams {
    // Frames the ring holds.
    slots: u32,
    // The ring slot this step writes (and the summary's newest frame).
    newest: u32,
    // How many frames back the summarised frame lies (1 or more).
    lag: u32,
    // 1: also summarise the lagged frame under its own weights.
    filtered: u32,
}
