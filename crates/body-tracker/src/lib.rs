//! # body-tracker (not yet built)
//!
//! This crate will hold the stereo articulated body tracker of Friborg, Hauberg & Erleben ("GPU
//! accelerated likelihoods for stereo-based articulated tracking"), rebuilt on `pf-core` and
//! `pf-gpu`:
//!
//! - the kinematic skeleton (a tree of rigid bones with joint limits) and forward kinematics to
//!   capsules (a, b, r);
//! - the ray–capsule intersection of the paper's Appendix A, the truncated metric and the
//!   log-likelihood over a stereo point cloud;
//! - the CPU reference likelihood (the paper's Listing 1.2 loop) that the GPU kernel is tested
//!   against, point-cloud inputs and the tracker itself.
//!
//! It deliberately exposes no API yet: nothing here is usable until that work lands.
