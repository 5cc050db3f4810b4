//! The `raytile-worker` binary: its flags parse, and a missing coordinator URL is an error.
//! (Building this test also builds the binary that the slow cluster tests SIGKILL.)

use std::process::Command;

#[test]
fn help_lists_the_flags() {
    let out = Command::new(env!("CARGO_BIN_EXE_raytile-worker"))
        .arg("--help")
        .output()
        .unwrap();
    assert!(out.status.success());
    let text = String::from_utf8_lossy(&out.stdout);
    for flag in [
        "--coordinator",
        "--token",
        "--threads",
        "--name",
        "--cache-dir",
        "--scene-cache-mb",
    ] {
        assert!(text.contains(flag), "{flag} missing from:\n{text}");
    }
}

#[test]
fn coordinator_is_required() {
    let out = Command::new(env!("CARGO_BIN_EXE_raytile-worker"))
        .env_remove("RAYTILE_COORDINATOR")
        .output()
        .unwrap();
    assert!(!out.status.success());
}

#[test]
fn a_coordinator_that_is_no_url_is_refused_at_once() {
    let out = Command::new(env!("CARGO_BIN_EXE_raytile-worker"))
        .args(["--coordinator", "farm-host:8080"])
        .env_remove("RAYTILE_TOKEN")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(
        err.contains("bad coordinator URL 'farm-host:8080'"),
        "{err}"
    );
}

/// A thread count no machine has is refused by the flag parser, before any thread starts.
#[test]
fn an_absurd_thread_count_is_refused_at_once() {
    for threads in ["1025", "4294967296", "-1"] {
        let out = Command::new(env!("CARGO_BIN_EXE_raytile-worker"))
            .args(["--coordinator", "http://127.0.0.1:9"])
            .arg(format!("--threads={threads}"))
            .env_remove("RAYTILE_TOKEN")
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{threads}: {err}");
        assert!(err.contains("--threads"), "{threads}: {err}");
    }
}
