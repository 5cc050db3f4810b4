//! The instruction sets a binary was compiled for, checked against the CPU it runs on.
//!
//! The default build targets baseline x86-64 and picks wider code (the 8-wide BVH nodes, the
//! sampler's SSE4.1 multiply) at run time. A build for AVX2 CPUs (`RAYTILE_CPU=avx2`, see
//! `scripts/cpu-flags.sh`) lets the compiler use AVX2, BMI and LZCNT everywhere and renders
//! the same bits, as FMA stays off; but it stops with SIGILL on a CPU without them. Its
//! binaries call [`require_compiled_features`] first thing, so that they refuse to start
//! with a message instead.

/// Features the binary may have been compiled with (`-C target-feature=+...` or
/// `-C target-cpu=...`), by the name both `cfg(target_feature)` and `is_x86_feature_detected!`
/// use: (name, compiled in, present on this CPU).
#[cfg(target_arch = "x86_64")]
fn features() -> [Feature; 16] {
    macro_rules! feature {
        ($name:tt) => {
            (
                $name,
                cfg!(target_feature = $name),
                std::arch::is_x86_feature_detected!($name),
            )
        };
    }
    [
        feature!("sse3"),
        feature!("ssse3"),
        feature!("sse4.1"),
        feature!("sse4.2"),
        feature!("popcnt"),
        feature!("avx"),
        feature!("avx2"),
        feature!("bmi1"),
        feature!("bmi2"),
        feature!("lzcnt"),
        feature!("f16c"),
        feature!("fma"),
        feature!("avx512f"),
        feature!("avx512bw"),
        feature!("avx512dq"),
        feature!("avx512vl"),
    ]
}

/// A feature: its name, whether the binary was compiled to use it, whether the CPU has it.
type Feature = (&'static str, bool, bool);

#[cfg(not(target_arch = "x86_64"))]
fn features() -> [Feature; 0] {
    []
}

/// The features this binary was compiled to use that the CPU lacks (empty: it can run).
pub fn missing_features() -> Vec<&'static str> {
    missing(&features())
}

/// The features this binary was compiled to use beyond baseline x86-64 (for messages and
/// logs); empty for the default build.
pub fn compiled_features() -> Vec<&'static str> {
    compiled(&features())
}

fn compiled(features: &[Feature]) -> Vec<&'static str> {
    features
        .iter()
        .filter(|&&(_, compiled, _)| compiled)
        .map(|&(name, ..)| name)
        .collect()
}

fn missing(features: &[Feature]) -> Vec<&'static str> {
    features
        .iter()
        .filter(|&&(_, compiled, present)| compiled && !present)
        .map(|&(name, ..)| name)
        .collect()
}

/// Why `program` cannot run on a CPU with these features, or `None` when it can.
fn refusal(program: &str, features: &[Feature]) -> Option<String> {
    let missing = missing(features);
    if missing.is_empty() {
        return None;
    }
    Some(format!(
        "{program}: this binary was built for CPUs with {}, and this CPU lacks {}: use the \
         default build (it renders the same images)",
        compiled(features).join(", "),
        missing.join(", ")
    ))
}

/// Exits with status 1 and a message naming what is missing when this binary was compiled
/// for instructions the CPU does not have. Call it first in `main`, before anything else runs
/// (the runtime of an async `main` included).
pub fn require_compiled_features(program: &str) {
    if let Some(message) = refusal(program, &features()) {
        eprintln!("{message}");
        std::process::exit(1);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_running_binary_fits_its_cpu() {
        // The tests run, so the CPU has what they were compiled for.
        assert!(missing_features().is_empty());
        assert_eq!(refusal("raytile", &features()), None);
        // Baseline x86-64 has SSE2 alone: SSE3 and up are compiled in only on request.
        #[cfg(target_arch = "x86_64")]
        assert_eq!(
            compiled_features().contains(&"avx2"),
            cfg!(target_feature = "avx2")
        );
    }

    #[test]
    fn a_build_for_a_newer_cpu_names_what_is_missing() {
        let cpu = [
            ("sse4.1", true, true),
            ("avx2", true, false),
            ("bmi2", true, false),
            ("fma", false, true),
            ("avx512f", false, false),
        ];
        assert_eq!(missing(&cpu), ["avx2", "bmi2"]);
        let message = refusal("raytile-worker", &cpu).unwrap();
        assert!(message.starts_with("raytile-worker: "), "{message}");
        assert!(
            message
                .contains("built for CPUs with sse4.1, avx2, bmi2, and this CPU lacks avx2, bmi2"),
            "{message}"
        );
        // Compiled without a feature the CPU lacks: nothing is missing.
        assert_eq!(refusal("raytile", &[("avx512f", false, false)]), None);
    }
}
