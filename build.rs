//! Builds the benchmarks' plain C baseline (benches/baseline/): the single-threaded loop the CPU
//! reference kernels are measured against. Only the root package's tests and benchmarks link it.

fn main() {
    println!("cargo:rerun-if-changed=benches/baseline/face_residual.c");
    cc::Build::new()
        .file("benches/baseline/face_residual.c")
        .opt_level(2)
        .compile("streampf_baselines");
}
