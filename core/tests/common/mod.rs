//! Helpers shared by the core's integration tests.

use std::path::{Path, PathBuf};

/// The shared test assets (Khronos glTF samples, the glTF Cornell box): the `shared` folder
/// beside the repository's.
pub const SHARED: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../shared");

/// Whether the tests run in CI (`CI=true`, as CI services set it).
pub fn in_ci() -> bool {
    std::env::var("CI").is_ok_and(|v| v == "true" || v == "1")
}

/// `rel` under the shared assets, or `None` when it is missing: the test then passes, saying
/// it skipped. In CI a missing asset fails the test instead, since CI must run every test.
pub fn shared(rel: &str) -> Option<PathBuf> {
    shared_in(Path::new(SHARED), rel, in_ci())
}

/// [`shared`] under `root`, in CI or not.
pub fn shared_in(root: &Path, rel: &str, ci: bool) -> Option<PathBuf> {
    let p = root.join(rel);
    if p.exists() {
        return Some(p);
    }
    assert!(
        !ci,
        "{} missing: CI runs every test, so the shared test assets must be there",
        p.display()
    );
    println!("skipped: {} missing", p.display());
    None
}

#[test]
fn a_missing_shared_asset_skips_outside_ci_and_fails_in_ci() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    assert_eq!(
        shared_in(root, "Cargo.toml", true),
        Some(root.join("Cargo.toml"))
    );
    assert_eq!(shared_in(root, "no-such-asset.gltf", false), None);
    let in_ci = std::panic::catch_unwind(|| shared_in(root, "no-such-asset.gltf", true));
    assert!(in_ci.is_err(), "a missing asset must fail the test in CI");
}
