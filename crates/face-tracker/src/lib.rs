//! # face-tracker (not yet built)
//!
//! This crate will hold the sparse-template 3D face tracker of Lozano & Otsuka ("Real-time visual
//! tracker by stream processing"), rebuilt on `pf-core` and `pf-gpu`:
//!
//! - the 7-D state (Tx, Ty, S, Rx, Ry, Rz, α) and its Gaussian diffusion;
//! - the weak-perspective projection and the robust relative-residual likelihood with
//!   self-occlusion by rotated normals (see `shared/DESIGN.md` and `ARCHITECTURE.md`);
//! - the generic face model (heightmap + normalmap) and sparse template extraction
//!   (grey-level extrema and Laplacian-of-Gaussian boundary dipoles);
//! - the CPU reference likelihood that the GPU kernel is tested against, and the tracker itself.
//!
//! It deliberately exposes no API yet: nothing here is usable until that work lands.
