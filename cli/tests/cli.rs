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
