//! The `raytile` command as a user runs it: real process, real files, exit codes.

use std::path::Path;
use std::process::Command;

/// The smallest render worth the name: 8 × 8 pixels, one sample.
const TINY: [&str; 6] = ["--width", "8", "--height", "8", "--spp", "1"];

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
    // The Cornell box rendered to `out` with `flags`: the exit status and stderr.
    let render = |out: &Path, flags: &[&str]| {
        let o = raytile()
            .args(["render", &scene("cornell-box.json"), "-o"])
            .arg(out)
            .args(flags)
            .output()
            .unwrap();
        (
            o.status.success(),
            String::from_utf8_lossy(&o.stderr).into_owned(),
        )
    };
    for ext in ["png", "exr", "hdr"] {
        let out = dir.join(format!("cb.{ext}"));
        let (ok, err) = render(
            &out,
            &[
                "--width",
                "24",
                "--height",
                "16",
                "--spp",
                "2",
                "--threads",
                "2",
            ],
        );
        assert!(ok, "{err}");
        assert!(
            err.contains("24x16, 2 spp") && err.contains("Msamples/s"),
            "{err}"
        );
        assert!(std::fs::metadata(&out).unwrap().len() > 0);
        assert!(!err.contains("warning"), "{err}");
        // Exposure and tone map shape the PNG alone: said, not silently ignored, for the others.
        let (ok, err) = render(&out, &[&TINY[..], &["--exposure", "1"]].concat());
        assert!(ok, "{err}");
        assert_eq!(
            err.contains("--exposure and --tonemap shape PNG output only"),
            ext != "png",
            "{ext}: {err}"
        );
        // An alpha channel is kept by EXR and PNG; a Radiance file cannot, and says so.
        let (ok, err) = render(&out, &[&TINY[..], &["--alpha"]].concat());
        assert!(ok, "{err}");
        assert_eq!(
            err.contains(".hdr files have no alpha channel"),
            ext == "hdr",
            "{ext}: {err}"
        );
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

/// A camera the scene does not have is the `--camera` flag's error, listing the scene's
/// cameras, as `submit` and `cluster` say it.
#[test]
fn render_reports_a_camera_the_scene_does_not_have_as_the_flag() {
    for camera in ["nope", "1"] {
        let o = raytile()
            .args(["render", &scene("cornell-box.json"), "-o", "x.png"])
            .args(["--camera", camera])
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{err}");
        assert_eq!(
            err,
            format!(
                "raytile: --camera: the scene has no camera named or numbered '{camera}' \
                 (its cameras: 0: 'camera 0')\n"
            )
        );
    }
}

/// What a job cannot render is the flag's error: `sppm` under the sun over an unbounded
/// plane (`classic.json`), and a constant environment too bright for its strength.
/// (`cluster_reports_the_coordinators_refusal_as_the_flag` checks that `cluster` hears the
/// first from its coordinator.)
#[test]
fn render_reports_a_job_it_cannot_render_as_the_flag() {
    let dir = std::env::temp_dir().join(format!("raytile-cli-flags-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let out = dir.join("x.png");
    let cases: [(&[&str], &str); 2] = [
        (
            &["--integrator", "sppm"],
            "raytile: --integrator: sppm cannot render an unbounded plane",
        ),
        (
            &["--environment", "1,1,1", "--environment-strength", "1e31"],
            "raytile: --environment: 1,1,1 times environment_strength 1e31 must be at most 1e30",
        ),
    ];
    for (flags, says) in cases {
        let o = raytile()
            .args(["render", &scene("classic.json"), "-o"])
            .arg(&out)
            .args(TINY)
            .args(flags)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{err}");
        assert!(err.starts_with(says) && err.lines().count() == 1, "{err}");
    }
    assert!(!out.exists());
    std::fs::remove_dir_all(&dir).ok();
}

/// Thread and worker counts no machine has are refused by the flag parser, at once, before a
/// thread is started (rather than spawning four billion of them).
#[test]
fn absurd_thread_and_worker_counts_are_refused() {
    let s = scene("cornell-box.json");
    let cases: [(&[&str], &str); 5] = [
        (
            &["render", &s, "-o", "x.png", "--threads", "4294967296"],
            "--threads",
        ),
        (
            &["render", &s, "-o", "x.png", "--threads", "1025"],
            "--threads",
        ),
        (
            &["render", &s, "-o", "x.png", "--threads", "0"],
            "--threads",
        ),
        (
            &["cluster", "--threads", "100000", "--render", &s],
            "--threads",
        ),
        (
            &["cluster", "--workers", "1000000", "--render", &s],
            "--workers",
        ),
    ];
    for (args, flag) in cases {
        refused_at_once(args, 2, &[flag, "not in"]);
    }
    // A BVH build that is no name says the names.
    refused_at_once(
        &["bench", "--build", "nonsense"],
        1,
        &["--build nonsense: no such build", "binned_sah, "],
    );
}

/// Runs `raytile ARGS` (no token in the environment): it must exit with `code` within ten
/// seconds, its error output holding every one of `wants`.
fn refused_at_once(args: &[&str], code: i32, wants: &[&str]) {
    let t = std::time::Instant::now();
    let o = raytile()
        .args(args)
        .env_remove("RAYTILE_TOKEN")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(code), "{args:?}: {err}");
    for want in wants {
        assert!(err.contains(want), "{args:?}: {err}");
    }
    assert!(
        t.elapsed().as_secs() < 10,
        "{args:?} took {:?}",
        t.elapsed()
    );
}

/// A coordinator that cannot start ends `raytile cluster` at once with its error (it used to
/// print its banner, or report the upload it could not make, while nothing listened).
#[test]
fn cluster_stops_with_the_coordinators_start_error() {
    let dir = std::env::temp_dir().join(format!("raytile-cli-baddb-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join("raytile.sqlite3"), "not a database").unwrap();
    let d = dir.to_str().unwrap();
    let s = scene("cornell-box.json");
    let cases: [(&[&str], &str); 3] = [
        (
            &["cluster", "--data-dir", d, "--listen", "127.0.0.1:0"],
            "opening the database",
        ),
        (
            &["cluster", "--data-dir", d, "--render", &s, "-o", "x.png"],
            "opening the database",
        ),
        (&["cluster", "--listen", "0.0.0.0:0"], "without a token"),
    ];
    for (args, want) in cases {
        refused_at_once(args, 1, &["the coordinator stopped", want]);
    }
    std::fs::remove_dir_all(&dir).ok();
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

/// A setting only the coordinator can refuse (it needs the scene's own spp), or a job only it
/// knows the workers would refuse, is still reported as the flag.
#[test]
fn cluster_reports_the_coordinators_refusal_as_the_flag() {
    let dir = std::env::temp_dir().join(format!("raytile-cli-cluster-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    // The second: sppm under the sun over an unbounded plane, which the workers would refuse.
    let cases: [(&str, &[&str], &str); 2] = [
        (
            "cornell-box.json",
            &["--spp", "4", "--passes", "5"],
            "raytile: --passes: must be between 1 and spp (4), got 5",
        ),
        (
            "classic.json",
            &[
                "--width",
                "8",
                "--height",
                "8",
                "--spp",
                "1",
                "--integrator",
                "sppm",
            ],
            "raytile: --integrator: sppm cannot render an unbounded plane",
        ),
    ];
    for (name, flags, says) in cases {
        let out = dir.join("x.png");
        let o = raytile()
            .args(["cluster", "--workers", "1", "--threads", "1", "--render"])
            .arg(scene(name))
            .arg("-o")
            .arg(&out)
            .args(flags)
            .env_remove("RAYTILE_TOKEN")
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{err}");
        assert!(err.contains(says), "{err}");
        assert!(!out.exists());
    }
    std::fs::remove_dir_all(&dir).ok();
}

/// A camera the scene does not have is refused by the coordinator when the job is submitted,
/// not by the workers later, and reported as the flag.
#[test]
fn submit_reports_a_camera_the_scene_does_not_have() {
    let dir = std::env::temp_dir().join(format!("raytile-cli-camera-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let (s, out) = (scene("cornell-box.json"), dir.join("x.png"));
    let out = out.to_str().unwrap();
    for camera in ["zzz", "7"] {
        let flags = ["--width", "16", "--height", "16", "--spp", "1"];
        let args = [
            &["cluster", "--workers", "1", "--threads", "1"][..],
            &flags,
            &["--render", &s, "-o", out, "--camera", camera],
        ]
        .concat();
        let want =
            format!("raytile: --camera: the scene has no camera named or numbered '{camera}'");
        refused_at_once(&args, 1, &[&want]);
        assert!(!dir.join("x.png").exists());
    }
    std::fs::remove_dir_all(&dir).ok();
}

/// `submit` prints the job's id when it writes no image: at once, or with `--wait` once the
/// job is done (it used to print nothing then, leaving no way to fetch the frame).
#[test]
fn submit_prints_the_job_id_with_or_without_wait() {
    use std::io::BufRead;
    let dir = std::env::temp_dir().join(format!("raytile-cli-wait-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    /// Stops the cluster however the test ends (it holds the test's output open).
    struct Stop(std::process::Child);
    impl Drop for Stop {
        fn drop(&mut self) {
            let _ = Command::new("kill")
                .args(["-INT", &self.0.id().to_string()])
                .status();
            let _ = self.0.wait();
        }
    }
    let mut cluster = raytile()
        .args([
            "cluster",
            "--workers",
            "1",
            "--threads",
            "1",
            "--listen",
            "127.0.0.1:0",
        ])
        .arg("--data-dir")
        .arg(dir.join("data"))
        .env_remove("RAYTILE_TOKEN")
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let stderr = cluster.stderr.take().unwrap();
    let cluster = Stop(cluster);
    let mut lines = std::io::BufReader::new(stderr).lines();
    let base = loop {
        let line = lines.next().expect("the cluster's banner").unwrap();
        if let Some(rest) = line.split("coordinator on ").nth(1) {
            break rest.split_whitespace().next().unwrap().to_string();
        }
    };
    for wait in [false, true] {
        let o = raytile()
            .args(["submit", &scene("cornell-box.json"), "--coordinator", &base])
            .args(["--width", "16", "--height", "16", "--spp", "1"])
            .args(if wait { &["--wait"][..] } else { &[] })
            .env_remove("RAYTILE_TOKEN")
            .output()
            .unwrap();
        let (out, err) = (
            String::from_utf8_lossy(&o.stdout),
            String::from_utf8_lossy(&o.stderr),
        );
        assert!(o.status.success(), "--wait {wait}: {err}");
        assert!(
            out.lines().count() == 1 && out.starts_with("job-"),
            "--wait {wait}: {out:?} {err}"
        );
    }
    drop(cluster);
    std::fs::remove_dir_all(&dir).ok();
}

/// A scene folder: `scene.json` with a texture (through a link inside the folder) and a glTF
/// include whose buffer sits beside it, plus files the scene does not use.
fn scene_folder(dir: &Path) -> std::path::PathBuf {
    let d = dir.join("scene");
    std::fs::create_dir_all(d.join("models")).unwrap();
    std::fs::create_dir_all(d.join("real")).unwrap();
    std::fs::create_dir_all(d.join("tex")).unwrap();
    // A 2×2 PNG, written by hand (no image crate here): 8-bit grey, no filter.
    std::fs::write(d.join("real/wood.png"), tiny_png()).unwrap();
    #[cfg(unix)]
    std::os::unix::fs::symlink("../real/wood.png", d.join("tex/wood.png")).unwrap();
    #[cfg(not(unix))]
    std::fs::write(d.join("tex/wood.png"), tiny_png()).unwrap();
    let positions: Vec<u8> = [-1.0f32, -1.0, 0.0, 1.0, -1.0, 0.0, 0.0, 1.0, 0.0]
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    std::fs::write(d.join("models/tri.bin"), &positions).unwrap();
    std::fs::write(
        d.join("models/tri.gltf"),
        r#"{"asset": {"version": "2.0"},
            "buffers": [{"byteLength": 36, "uri": "tri.bin"}],
            "bufferViews": [{"buffer": 0, "byteLength": 36}],
            "accessors": [{"bufferView": 0, "componentType": 5126, "type": "VEC3", "count": 3,
                           "min": [-1, -1, 0], "max": [1, 1, 0]}],
            "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
            "nodes": [{"mesh": 0}], "scenes": [{"nodes": [0]}]}"#,
    )
    .unwrap();
    std::fs::write(
        d.join("scene.json"),
        r#"{"render": {"width": 8, "height": 8, "spp": 1},
            "camera": {"position": [0, 0, 4], "look_at": [0, 0, 0]},
            "textures": {"wood": {"type": "image", "path": "tex/wood.png"}},
            "materials": {"floor": {"type": "diffuse", "texture": "wood"}},
            "objects": [{"shape": {"type": "plane", "point": [0, -1, 0]}, "material": "floor"},
                        {"shape": {"type": "gltf", "path": "models/tri.gltf"}}],
            "lights": [{"type": "point", "position": [0, 2, 2], "intensity": [5, 5, 5]}]}"#,
    )
    .unwrap();
    std::fs::write(d.join("notes.txt"), b"not part of the scene").unwrap();
    std::fs::write(d.join("models/unused.bin"), vec![0u8; 1000]).unwrap();
    d
}

/// A valid 2×2 8-bit greyscale PNG.
fn tiny_png() -> Vec<u8> {
    fn crc32(bytes: &[u8]) -> u32 {
        let mut c = !0u32;
        for &b in bytes {
            c ^= b as u32;
            for _ in 0..8 {
                c = if c & 1 != 0 {
                    0xEDB8_8320 ^ (c >> 1)
                } else {
                    c >> 1
                };
            }
        }
        !c
    }
    fn adler32(bytes: &[u8]) -> u32 {
        let (mut a, mut b) = (1u32, 0u32);
        for &x in bytes {
            a = (a + x as u32) % 65521;
            b = (b + a) % 65521;
        }
        (b << 16) | a
    }
    let mut out = b"\x89PNG\r\n\x1a\n".to_vec();
    let mut chunk = |kind: &[u8], data: &[u8]| {
        let body = [kind, data].concat();
        out.extend((data.len() as u32).to_be_bytes());
        out.extend(&body);
        out.extend(crc32(&body).to_be_bytes());
    };
    chunk(b"IHDR", &[0, 0, 0, 2, 0, 0, 0, 2, 8, 0, 0, 0, 0]);
    // Rows: filter byte 0, then two grey pixels; stored in one uncompressed deflate block.
    let raw = [0u8, 200, 100, 0, 100, 200];
    let mut z = vec![0x78, 0x01, 1, raw.len() as u8, 0, !(raw.len() as u8), 0xff];
    z.extend(raw);
    z.extend(adler32(&raw).to_be_bytes());
    chunk(b"IDAT", &z);
    chunk(b"IEND", &[]);
    out
}

/// `raytile submit` checks the scene as a farm will before it uploads anything: a scene naming
/// a file outside its folder is refused with the JSON path, the file and how to fix it.
#[test]
fn submit_refuses_a_scene_naming_files_outside_its_folder() {
    let dir = std::env::temp_dir().join(format!("raytile-cli-confine-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let d = scene_folder(&dir);
    std::fs::write(dir.join("outside.png"), tiny_png()).unwrap();
    let nobody = {
        let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        format!("http://{}", l.local_addr().unwrap())
    };
    let outside = dir.join("outside.png").display().to_string();
    for (path, want) in [
        (outside.as_str(), "copy the file next to the scene"),
        ("../outside.png", "remove the '..'"),
    ] {
        let scene = d.join("bad.json");
        std::fs::write(
            &scene,
            format!(r#"{{"textures": {{"t": {{"type": "image", "path": {path:?}}}}}}}"#),
        )
        .unwrap();
        let o = raytile()
            .args(["submit"])
            .arg(&scene)
            .args(["--coordinator", &nobody])
            .env_remove("RAYTILE_TOKEN")
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{path}: {err}");
        assert!(
            err.contains("at textures.t.path")
                && err.contains(&format!("{path:?} refused"))
                && err.contains(want)
                && !err.contains("cannot reach"),
            "{path}: {err}"
        );
        assert_eq!(err.lines().count(), 1, "{err}");
        // The user's own render still reads it.
        let o = raytile()
            .arg("render")
            .arg(&scene)
            .arg("-o")
            .arg(dir.join("local.png"))
            .args(["--width", "4", "--height", "4", "--spp", "1"])
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    }
    std::fs::remove_dir_all(&dir).ok();
}

/// `render` takes a scene folder as `submit` does: the one scene file at its top, the same
/// image as the file gives; a folder without one, or with several, is refused by name.
#[test]
fn render_takes_a_scene_folder() {
    let dir = std::env::temp_dir().join(format!("raytile-cli-folder-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let d = scene_folder(&dir);
    let exr = |scene: &Path, name: &str| {
        let out = dir.join(name);
        let o = raytile()
            .arg("render")
            .arg(scene)
            .arg("-o")
            .arg(&out)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        std::fs::read(out).unwrap()
    };
    assert_eq!(
        exr(&d, "folder.exr"),
        exr(&d.join("scene.json"), "file.exr")
    );
    let empty = dir.join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    let empty = empty.display().to_string();
    let png = dir.join("x.png").display().to_string();
    refused_at_once(
        &["render", &empty, "-o", &png],
        1,
        &["no .gltf, .glb or .json"],
    );
    std::fs::write(d.join("other.json"), "{}").unwrap();
    let two = d.display().to_string();
    refused_at_once(
        &["render", &two, "-o", &png],
        1,
        &["other.json, scene.json"],
    );
    std::fs::remove_dir_all(&dir).ok();
}

/// Samples dropped as too large (a lamp of 10³⁰ a tenth of a millimetre above the floor) are
/// said by a farm's download as by a local render, with the same count, and the images agree.
#[test]
fn dropped_samples_are_said_by_the_farm_as_by_render() {
    let dir = std::env::temp_dir().join(format!("raytile-cli-dropped-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let scene = dir.join("lamp.json");
    std::fs::write(
        &scene,
        r#"{"render": {"width": 8, "height": 8, "spp": 4, "max_depth": 2},
            "camera": {"type": "orthographic", "position": [0, 1, 0], "look_at": [0, 0, 0],
                       "up": [0, 0, -1], "half_height": 0.02},
            "materials": {"white": {"type": "diffuse"}},
            "objects": [{"shape": {"type": "rectangle", "corner": [-2, 0, 2], "edge_u": [4, 0, 0],
                                   "edge_v": [0, 0, -4]}, "material": "white"}],
            "lights": [{"type": "point", "position": [0, 0.0001, 0],
                        "intensity": [1e30, 1e30, 1e30]}]}"#,
    )
    .unwrap();
    let said = |err: &str| -> u64 {
        let line = err
            .lines()
            .find(|l| l.contains("samples were dropped"))
            .unwrap_or_else(|| panic!("no warning: {err}"));
        line.split_whitespace().nth(2).unwrap().parse().unwrap()
    };
    let o = raytile()
        .arg("render")
        .arg(&scene)
        .arg("-o")
        .arg(dir.join("local.exr"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    let local = said(&err);
    assert!(local > 0, "{err}");
    let o = raytile()
        .args(["cluster", "--workers", "1", "--threads", "1", "--render"])
        .arg(&scene)
        .arg("-o")
        .arg(dir.join("farm.exr"))
        .arg("--data-dir")
        .arg(dir.join("data"))
        .env_remove("RAYTILE_TOKEN")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert_eq!(said(&err), local, "{err}");
    assert_eq!(
        std::fs::read(dir.join("farm.exr")).unwrap(),
        std::fs::read(dir.join("local.exr")).unwrap()
    );
    std::fs::remove_dir_all(&dir).ok();
}

/// `raytile submit` packs exactly the files the scene uses (a link inside the folder under the
/// name the scene gives it), says what it packed, and the farm renders it.
#[test]
fn submit_packs_exactly_the_files_the_scene_uses() {
    let dir = std::env::temp_dir().join(format!("raytile-cli-pack-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let d = scene_folder(&dir);
    let data = dir.join("data");
    let o = raytile()
        .args(["cluster", "--workers", "1", "--threads", "1", "--render"])
        .arg(d.join("scene.json"))
        .arg("-o")
        .arg(dir.join("out.png"))
        .arg("--data-dir")
        .arg(&data)
        .env_remove("RAYTILE_TOKEN")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(dir.join("out.png").is_file());
    assert!(err.contains("packing 4 files"), "{err}");
    // What the coordinator unpacked is the scene's files, nothing beside them.
    let scenes: Vec<_> = std::fs::read_dir(data.join("scenes"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    assert_eq!(scenes.len(), 1, "{scenes:?}");
    let root = scenes[0].join("root");
    let mut found = Vec::new();
    let mut stack = vec![root.clone()];
    while let Some(p) = stack.pop() {
        for e in std::fs::read_dir(&p).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                found.push(p.strip_prefix(&root).unwrap().display().to_string());
            }
        }
    }
    found.sort();
    assert_eq!(
        found,
        [
            "models/tri.bin",
            "models/tri.gltf",
            "scene.json",
            "tex/wood.png"
        ]
    );
    for name in ["scene.json", "tex/wood.png", "models/tri.bin"] {
        assert!(err.contains(&format!("  {name}  ")), "{name}: {err}");
    }
    std::fs::remove_dir_all(&dir).ok();
}

/// `--environment MAP` on `raytile cluster` (two workers, the map outside the scene's folder:
/// packed with the scene as `environment/NAME`) gives the EXR of `raytile render`, byte for
/// byte; so does a colour. Tiles of 8 pixels: the cluster takes any tile size `render` does.
#[test]
fn cluster_with_an_environment_matches_render() {
    let dir = std::env::temp_dir().join(format!("raytile-cli-env-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(dir.join("scene")).unwrap();
    let ball = dir.join("scene/ball.json");
    std::fs::write(
        &ball,
        r#"{"camera": {"position": [0, 1, 4], "look_at": [0, 0.5, 0], "fov": 50},
            "materials": {"grey": {"type": "diffuse", "albedo": [0.6, 0.6, 0.6]}},
            "objects": [{"shape": {"type": "sphere", "center": [0, 0.5, 0], "radius": 0.5},
                         "material": "grey"}]}"#,
    )
    .unwrap();
    let map = scene("studio.hdr");
    let job = [
        "--width",
        "32",
        "--height",
        "24",
        "--spp",
        "4",
        "--max-depth",
        "4",
        "--tile-size",
        "8",
    ];
    for env in [
        &[
            "--environment",
            map.as_str(),
            "--environment-rotation",
            "45",
        ][..],
        &["--environment", "0.2,0.4,0.6"],
        // An alpha channel: the farm's tiles carry coverage, the EXR gets RGBA.
        &["--environment", "0.2,0.4,0.6", "--alpha"],
    ] {
        let local = dir.join("local.exr");
        let o = raytile()
            .arg("render")
            .arg(&ball)
            .arg("-o")
            .arg(&local)
            .args(job)
            .args(env)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let farm = dir.join("farm.exr");
        let o = raytile()
            .args(["cluster", "--workers", "2", "--threads", "1", "--render"])
            .arg(&ball)
            .arg("-o")
            .arg(&farm)
            .arg("--data-dir")
            .arg(dir.join("data"))
            .args(job)
            .args(env)
            .env_remove("RAYTILE_TOKEN")
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(o.status.success(), "{err}");
        if env[1].ends_with(".hdr") {
            assert!(err.contains("environment/studio.hdr"), "{err}");
        }
        assert!(
            std::fs::read(&local).unwrap() == std::fs::read(&farm).unwrap(),
            "{env:?}: the cluster's EXR differs from raytile render's"
        );
    }
    std::fs::remove_dir_all(&dir).ok();
}

/// `raytile bench` on small sizes: every figure printed, the BVH rows with closest-hit and
/// shadow-ray throughput both ways (the command fails if leaf pairs hit or block other rays
/// than single leaves).
#[test]
fn bench_prints_its_figures_at_small_sizes() {
    let o = raytile()
        .args(["bench", "--scene", &scene("cornell-box.json")])
        .args(["--caustic-scene", &scene("caustic.json")])
        .args(["--size", "16", "--spp", "2", "--caustic-spp", "1"])
        .args(["--triangles", "20000", "--rays", "20000"])
        .args(["--build", "binned_sah", "--width", "16", "--width", "4"])
        .env("RAYON_NUM_THREADS", "2")
        .output()
        .unwrap();
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "{out}\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let rows: Vec<&str> = out
        .lines()
        .filter(|l| l.contains("BVH binned_sah"))
        .collect();
    assert_eq!(rows.len(), 2, "{out}");
    for row in rows {
        assert!(
            row.contains("Mrays/s coherent (")
                && row.contains("Mrays/s incoherent (")
                && row.contains("Mrays/s shadow (")
                && row.contains("with leaf pairs)"),
            "{row}"
        );
    }
}

/// A model with no light gets the default white environment, with a warning; with a light of
/// the render's own (or none), the warning says so instead.
#[test]
fn the_default_light_warning_says_what_the_render_does() {
    let dir = std::env::temp_dir().join(format!("raytile-cli-unlit-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let model = dir.join("unlit.gltf");
    std::fs::write(
        &model,
        r#"{"asset": {"version": "2.0"},
  "buffers": [{"byteLength": 36, "uri": "data:application/octet-stream;base64,AAAAAAAAAAAAAAAAAACAPwAAAAAAAAAAAAAAAAAAgD8AAAAA"}],
  "bufferViews": [{"buffer": 0, "byteLength": 36}],
  "accessors": [{"bufferView": 0, "componentType": 5126, "type": "VEC3", "count": 3,
    "min": [0, 0, 0], "max": [1, 1, 0]}],
  "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
  "nodes": [{"mesh": 0}], "scenes": [{"nodes": [0]}]}"#,
    )
    .unwrap();
    let out = dir.join("out.exr");
    // `raytile render`, and a farm's job through `raytile cluster --render` (as `submit`).
    let render = |command: &str, extra: &[&str]| {
        let o = raytile()
            .arg(command)
            .args(if command == "cluster" {
                &["--workers", "1", "--render"][..]
            } else {
                &[]
            })
            .arg(&model)
            .arg("-o")
            .arg(&out)
            .args(TINY)
            .args(["--threads", "1"])
            .args(extra)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr).to_string();
        assert!(o.status.success(), "{err}");
        err
    };
    let added = "a constant white environment was added";
    for c in ["render", "cluster"] {
        let err = render(c, &[]);
        assert!(
            err.contains("has no light") && err.contains(added),
            "{c}: {err}"
        );
        for (flags, says) in [
            (
                &["--environment", "none"][..],
                "environment is none: no light was added",
            ),
            (
                &["--environment", "0.5,0.5,0.5"][..],
                "environment (0.5,0.5,0.5) lights it",
            ),
            (
                &["--no-default-light"][..],
                "default light is off: no light was added",
            ),
        ] {
            let err = render(c, flags);
            assert!(
                err.contains("has no light") && err.contains(says) && !err.contains(added),
                "{c} {flags:?}: {err}"
            );
        }
    }
    std::fs::remove_dir_all(&dir).ok();
}

/// What would fail only after a long render, or be ignored, is refused before anything runs:
/// an output in a folder that does not exist, a non-finite exposure, a BVH mesh of no
/// triangles or a node width the BVH does not have, and job flags given to a cluster that has
/// no job of its own.
#[test]
fn what_would_fail_after_the_render_is_refused_before_it() {
    let s = scene("cornell-box.json");
    let missing = "/nonexistent-raytile-folder/x.png";
    refused_at_once(
        &["render", &s, "-o", missing, "--spp", "100000"],
        1,
        &["writing /nonexistent-raytile-folder/x.png: No such file"],
    );
    refused_at_once(
        &["cluster", "--render", &s, "-o", missing, "--spp", "100000"],
        1,
        &["writing /nonexistent-raytile-folder/x.png"],
    );
    for bad in ["nan", "inf", "-1000"] {
        refused_at_once(
            &["render", &s, "-o", "x.png", "--exposure", bad],
            2,
            &["--exposure", "finite number of stops"],
        );
    }
    refused_at_once(&["bench", "--triangles", "0"], 2, &["--triangles"]);
    refused_at_once(&["bench", "--width", "5"], 1, &["--width 5"]);
    refused_at_once(&["bench", "--size", "0"], 2, &["--size"]);
    for flags in [&["-o", "x.png"][..], &["--spp", "4"], &["--priority", "3"]] {
        let mut args = vec!["cluster", "--listen", "127.0.0.1:1"];
        args.extend_from_slice(flags);
        refused_at_once(&args, 1, &["are for --render"]);
    }
}

/// `docker stop` and service managers send SIGTERM: the cluster stops as on Ctrl-C and removes
/// its temporary data folder.
#[cfg(unix)]
#[test]
fn cluster_removes_its_temporary_folder_on_sigterm() {
    let tmp = std::env::temp_dir().join(format!("raytile-cli-term-{}", std::process::id()));
    std::fs::create_dir_all(&tmp).unwrap();
    // Any free port: a fixed one may be another program's.
    let mut child = raytile()
        .args(["cluster", "--workers", "1", "--threads", "1", "--listen"])
        .arg("127.0.0.1:0")
        .env("TMPDIR", &tmp)
        .env_remove("RAYTILE_TOKEN")
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    // Up once its temporary folder holds the coordinator's database.
    let up = || {
        std::fs::read_dir(&tmp)
            .unwrap()
            .flatten()
            .any(|d| d.path().join("data/raytile.sqlite3").exists())
    };
    let t = std::time::Instant::now();
    while !up() {
        assert!(t.elapsed().as_secs() < 30, "the cluster did not start");
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
    std::thread::sleep(std::time::Duration::from_millis(300));
    let killed = Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(killed.success());
    let status = child.wait().unwrap();
    assert!(status.success(), "{status:?}");
    let left: Vec<_> = std::fs::read_dir(&tmp)
        .unwrap()
        .flatten()
        .map(|d| d.path())
        .collect();
    assert!(left.is_empty(), "left behind: {left:?}");
    std::fs::remove_dir_all(&tmp).unwrap();
}

/// `--exposure` and `--tonemap` shape the farm's PNG as they shape `raytile render`'s: the same
/// bytes; and they change it.
#[test]
fn the_farm_makes_the_png_of_an_exposure_and_tone_map_as_render_does() {
    let dir = std::env::temp_dir().join(format!("raytile-cli-look-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let job = [
        "--width",
        "24",
        "--height",
        "16",
        "--spp",
        "4",
        "--exposure",
        "1.5",
        "--tonemap",
        "aces",
    ];
    let render = |out: &str, look: &[&str]| {
        let o = raytile()
            .arg("render")
            .arg(scene("cornell-box.json"))
            .arg("-o")
            .arg(dir.join(out))
            .args(&job[..6])
            .args(look)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        std::fs::read(dir.join(out)).unwrap()
    };
    let plain = render("plain.png", &[]);
    let local = render("local.png", &job[6..]);
    assert_ne!(plain, local, "the exposure changes the PNG");
    let o = raytile()
        .args(["cluster", "--workers", "1", "--threads", "1", "--render"])
        .arg(scene("cornell-box.json"))
        .arg("-o")
        .arg(dir.join("farm.png"))
        .arg("--data-dir")
        .arg(dir.join("data"))
        .args(job)
        .env_remove("RAYTILE_TOKEN")
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(
        std::fs::read(dir.join("farm.png")).unwrap() == local,
        "the farm's PNG differs from raytile render's"
    );
    std::fs::remove_dir_all(&dir).ok();
}
