//! The one error type of pf-core.

use thiserror::Error;

/// Everything that can go wrong inside the Condensation engine.
///
/// Each variant names its cause so that a caller (or a recovery policy) can tell a degenerate
/// likelihood from a configuration mistake.
#[derive(Debug, Clone, PartialEq, Error)]
#[non_exhaustive]
pub enum PfError {
    /// A filter or a resampler was asked to work on zero particles.
    #[error("the particle set is empty: a filter needs at least one particle")]
    EmptyParticleSet,

    /// Every log-weight is −∞ (every weight is zero): there is nothing to normalise.
    #[error(
        "all {particles} log-weights are -inf (every weight is zero): the likelihood rejected every particle"
    )]
    AllWeightsZero {
        /// The particles weighed.
        particles: usize,
    },

    /// A log-weight is NaN, usually a likelihood that divided 0 by 0 or a state that went NaN.
    #[error("log-weight of particle {particle} is NaN: the likelihood or the state produced a NaN")]
    NanLogWeight {
        /// The first particle with a NaN log-weight.
        particle: usize,
    },

    /// A log-weight is +∞: the likelihood claimed infinite density, so no weight can be normalised.
    #[error(
        "log-weight of particle {particle} is +inf: the likelihood returned an infinite density"
    )]
    InfiniteLogWeight {
        /// The first particle with a +∞ log-weight.
        particle: usize,
    },

    /// A normalised weight handed to a resampler is negative, NaN, or the weights do not sum to 1.
    #[error("invalid normalised weights: {reason}")]
    InvalidWeights {
        /// What is wrong with them.
        reason: String,
    },

    /// Two buffers that must have the same length do not.
    #[error("length mismatch: {what} has length {got}, expected {expected}")]
    LengthMismatch {
        /// The buffer.
        what: &'static str,
        /// The length it must have.
        expected: usize,
        /// The length it has.
        got: usize,
    },

    /// Reading particles back from the device that holds them failed (a lost GPU, say); the
    /// message says why.
    #[error("{0}")]
    Device(String),

    /// A configuration value is out of its domain.
    #[error("invalid configuration: {0}")]
    InvalidConfig(String),

    /// The rejection resampler used up its try budget for one particle.
    #[error(
        "rejection resampling gave up after {tries} tries for particle {particle}: the weights are too degenerate (raise max_tries or use another resampler)"
    )]
    RejectionGaveUp {
        /// The offspring that found no ancestor.
        particle: usize,
        /// The tries it was allowed.
        tries: u32,
    },
}
