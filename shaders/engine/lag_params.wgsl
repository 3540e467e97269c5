// The lag window's parameters (a library prepended to lag_summary.wgsl; mirror: the LagParams of
// pf_gpu::filter::lag_window, written before each whole step).

struct LagParams {
    // Frames the ring holds.
    slots: u32,
    // The ring slot this step's frame is kept in (the summary reads that frame from the step's
    // own buffers, the frames before it from the ring).
    newest: u32,
    // How many frames back the summarised frame lies (1 or more).
    lag: u32,
    // 1: also summarise the lagged frame under its own weights.
    filtered: u32,
    // 1: the window is full, summarise the lagged frame; 0: only keep the step in the ring.
    summarise: u32,
    pad0: u32,
    pad1: u32,
    pad2: u32,
}
