//! The `raytile` command as a user runs it: real process, real files, exit codes.

use std::path::Path;
use std::process::Command;

fn raytile() -> Command {
    Command::new(env!("CARGO_BIN_EXE_raytile"))
}

fn scene(name: &str) -> String {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../scenes")
        .join(name)
        .display()
        .to_string()
}

#[test]
fn render_writes_every_format_and_prints_a_summary() {
    let dir = std::env::temp_dir().join(format!("raytile-cli-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    for ext in ["png", "exr", "hdr"] {
        let out = dir.join(format!("cb.{ext}"));
        let o = raytile()
            .args(["render", &scene("cornell-box.json"), "-o"])
            .arg(&out)
            .args([
                "--width",
                "24",
                "--height",
                "16",
                "--spp",
                "2",
                "--threads",
                "2",
            ])
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(o.status.success(), "{err}");
        assert!(
            err.contains("24x16, 2 spp") && err.contains("Msamples/s"),
            "{err}"
        );
        assert!(std::fs::metadata(&out).unwrap().len() > 0);
    }
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn errors_are_one_line_and_a_nonzero_exit() {
    let cases: [&[&str]; 4] = [
        &["render", "/nonexistent/scene.json", "-o", "x.png"],
        &["render", &scene("cornell-box.json"), "-o", "x.jpg"],
        &[
            "render",
            &scene("cornell-box.json"),
            "-o",
            "x.png",
            "--spp",
            "0",
        ],
        &[
            "render",
            &scene("cornell-box.json"),
            "-o",
            "x.png",
            "--camera",
            "nope",
        ],
    ];
    for args in cases {
        let o = raytile().args(args).output().unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{args:?}: {err}");
        assert!(
            err.starts_with("raytile: ") && err.trim_end().lines().count() == 1,
            "{args:?}: {err}"
        );
    }
}

/// `raytile submit` refuses what it can tell is wrong before it uploads anything: nothing listens
/// at the coordinator address, so reaching it would be a different error.
#[test]
fn submit_refuses_bad_flags_and_outputs_before_uploading() {
    let nobody = {
        let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        format!("http://{}", l.local_addr().unwrap())
    };
    let cases: [(&[&str], &str); 3] = [
        (&["-o", "x.jpg"], "unknown image format"),
        (&["--spp", "0"], "--spp: must be between 1 and"),
        (
            &["--max-depth", "99999", "--wait"],
            "--max-depth: must be at most",
        ),
    ];
    for (args, want) in cases {
        let o = raytile()
            .args([
                "submit",
                &scene("cornell-box.json"),
                "--coordinator",
                &nobody,
            ])
            .args(args)
            .env_remove("RAYTILE_TOKEN")
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{args:?}: {err}");
        assert!(err.contains(want), "{args:?}: {err}");
    }
    // Good flags do try to upload, and say where they could not.
    let o = raytile()
        .args([
            "submit",
            &scene("cornell-box.json"),
            "--coordinator",
            &nobody,
        ])
        .env_remove("RAYTILE_TOKEN")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("cannot reach the coordinator"), "{err}");
}

/// A setting only the coordinator can refuse (it needs the scene's own spp) is still reported
/// as the flag.
#[test]
fn cluster_reports_the_coordinators_refusal_as_the_flag() {
    let dir = std::env::temp_dir().join(format!("raytile-cli-cluster-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let o = raytile()
        .args(["cluster", "--workers", "1", "--threads", "1", "--render"])
        .arg(scene("cornell-box.json"))
        .arg("-o")
        .arg(dir.join("x.png"))
        .args(["--spp", "4", "--passes", "5"])
        .env_remove("RAYTILE_TOKEN")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("raytile: --passes: must be between 1 and spp (4), got 5"),
        "{err}"
    );
    std::fs::remove_dir_all(&dir).ok();
}
