//! A program with [`raytile_core::cpu_gate!`]. `scripts/check-cpu-builds.sh --golden` builds it
//! for AVX2 CPUs and runs it on an emulated CPU without AVX2, where the gate must stop it
//! before `main` with its message and exit status 1; on a CPU that fits, it runs this test.

raytile_core::cpu_gate!();

#[test]
fn a_program_with_the_gate_starts_on_a_cpu_that_fits_it() {
    assert!(raytile_core::cpu::missing_features().is_empty());
}
