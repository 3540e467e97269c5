//! What the two papers report, quoted as the papers' and kept apart from anything we measure.
//!
//! Only values that can be quoted are here: a point read off a paper's figure is marked as read
//! off ("about"), a claim from the text is quoted as a claim. The papers ran on their own
//! CUDA hardware of 2008 and 2010, described in their experiments sections; the report says so
//! beside every paper value rather than restating it.

/// A value the paper reports on one of our panels' axes, drawn as a black cross and put beside
/// our measurement of `our_series` at the same `x` in the report.
#[derive(Debug, Clone, PartialEq)]
pub struct PaperPoint {
    /// Where it comes from, e.g. "face paper, Fig. 6".
    pub source: &'static str,
    /// The paper's curve, e.g. "CPU, one thread".
    pub label: &'static str,
    pub x: f64,
    /// In the panel's unit.
    pub y: f64,
    /// Our series it compares with.
    pub our_series: &'static str,
}

/// A claim from a paper's text, set beside our corresponding number in the report.
#[derive(Debug, Clone, PartialEq)]
pub struct PaperClaim {
    pub source: &'static str,
    /// The claim, quoted.
    pub quote: &'static str,
}

pub const FACE_PAPER: &str = "Lozano & Otsuka, \"Real-time visual tracker by stream processing\" (J. Signal Processing Systems 57, 2009)";
pub const BODY_PAPER: &str = "Friborg, Hauberg & Erleben, \"GPU accelerated likelihoods for stereo-based articulated tracking\" (ECCV 2010 workshops, LNCS 6554)";

/// Face paper, Fig. 6: weighting 1 000 particles on one CPU thread took about 1.4 ms (read off
/// the figure).
pub fn face_fig6_points(one_thread_series: &'static str) -> Vec<PaperPoint> {
    vec![PaperPoint {
        source: "face paper, Fig. 6 (read off the figure)",
        label: "paper: CPU, one thread",
        x: 1000.0,
        y: 1.4,
        our_series: one_thread_series,
    }]
}

pub fn face_speedup_claim() -> PaperClaim {
    PaperClaim {
        source: "face paper, abstract",
        quote: "performance improvements as large as ten times compared to a similar CPU-only tracker",
    }
}

pub fn body_speedup_claim() -> PaperClaim {
    PaperClaim {
        source: "body paper, abstract",
        quote: "computations which previously required several minutes, are now performed in few seconds",
    }
}
