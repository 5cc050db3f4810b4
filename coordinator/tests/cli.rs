//! The `raytile-coordinator` binary: its flags, its refusal to listen exposed without a token,
//! and `--healthcheck` against a live and a missing coordinator. (Building this test also
//! builds the binary that the slow cluster test SIGKILLs.)

use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

const BIN: &str = env!("CARGO_BIN_EXE_raytile-coordinator");

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

fn clean() -> Command {
    let mut c = Command::new(BIN);
    for v in [
        "RAYTILE_TOKEN",
        "RAYTILE_LISTEN",
        "RAYTILE_DATA_DIR",
        "RAYTILE_LEASE_TIMEOUT",
        "RAYTILE_STARTUP_GRACE",
    ] {
        c.env_remove(v);
    }
    c
}

#[test]
fn help_lists_the_flags() {
    let out = clean().arg("--help").output().unwrap();
    assert!(out.status.success());
    let text = String::from_utf8_lossy(&out.stdout);
    for flag in [
        "--listen",
        "--data-dir",
        "--token",
        "--insecure",
        "--lease-timeout",
        "--max-upload-bytes",
        "--max-queued-jobs",
        "--max-queued-tasks",
        "--max-pixels",
        "--max-spp",
        "--max-passes",
        "--min-tile-size",
        "--max-tasks-per-job",
        "--long-poll-max",
        "--healthcheck",
    ] {
        assert!(text.contains(flag), "{flag} missing from:\n{text}");
    }
}

#[test]
fn refuses_a_public_address_without_a_token() {
    let dir = tempfile::tempdir().unwrap();
    let out = clean()
        .args(["--listen", "0.0.0.0:0", "--data-dir"])
        .arg(dir.path())
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("token"), "{err}");
}

#[test]
fn healthcheck_fails_without_a_coordinator_and_passes_with_one() {
    let port = free_port();
    let listen = format!("127.0.0.1:{port}");
    let out = clean()
        .args(["--healthcheck", "--listen", &listen])
        .output()
        .unwrap();
    assert!(!out.status.success(), "healthy with nothing listening");

    let dir = tempfile::tempdir().unwrap();
    let mut server = clean()
        .args(["--listen", &listen, "--data-dir"])
        .arg(dir.path())
        // A token: /healthz must still answer without one.
        .env("RAYTILE_TOKEN", "secret")
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let end = Instant::now() + Duration::from_secs(30);
    let healthy = loop {
        let ok = clean()
            .args(["--healthcheck", "--listen", &listen])
            .status()
            .unwrap()
            .success();
        if ok || Instant::now() > end {
            break ok;
        }
        std::thread::sleep(Duration::from_millis(100));
    };
    let _ = server.kill();
    let _ = server.wait();
    assert!(
        healthy,
        "--healthcheck never passed against a running coordinator"
    );
}
