//! The hostile-scene suite: scenes a user with the token could upload to read the farm's files,
//! hang it or exhaust its memory, sent to a coordinator running in this process. Each is
//! answered 422 (or 413) within a second with a message naming what was refused; the
//! coordinator's resident memory stays bounded (measured on this process, which runs it) and it
//! keeps serving: a normal job renders afterwards. A worker handed such a scene anyway (a
//! coordinator that did not check it) fails the task with a message and reads nothing outside
//! the scene's folder.

use raytile_coordinator::{core_scene_loader, Config, LoadedScene, SceneLimits};
use raytile_proto::{self as proto, JobRequest, JobState, JobStatus, RenderOverrides};
use std::io::Write as _;
use std::path::Path;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio::sync::watch;
use tokio::task::JoinHandle;

/// Tests here measure this process's memory: they run one at a time.
static SERIAL: tokio::sync::Mutex<()> = tokio::sync::Mutex::const_new(());

/// Helpers: a coordinator and a worker in this process, uploads, archives, fixtures.
mod support {
    use super::*;

    /// A coordinator running in this process.
    pub struct Coord {
        /// `http://127.0.0.1:PORT`.
        pub base: String,
        stop: watch::Sender<bool>,
        handle: JoinHandle<anyhow::Result<()>>,
    }

    impl Coord {
        pub async fn start(cfg: Config) -> Coord {
            let listener = tokio::net::TcpListener::bind(("127.0.0.1", 0))
                .await
                .unwrap();
            let base = format!("http://{}", listener.local_addr().unwrap());
            let (stop, rx) = watch::channel(false);
            let mut rx2 = rx.clone();
            let handle = tokio::spawn(raytile_coordinator::run(listener, cfg, async move {
                let _ = rx2.wait_for(|v| *v).await;
            }));
            Coord { base, stop, handle }
        }

        pub async fn stop(self) {
            let _ = self.stop.send(true);
            let _ = self.handle.await;
        }
    }

    /// Coordinator settings for tests: short leases, no grace, the core's loader with `limits`.
    pub fn config(dir: &Path, limits: SceneLimits) -> Config {
        let mut c = Config::new(dir);
        c.lease_timeout = Duration::from_secs(1);
        c.heartbeat_interval = Duration::from_millis(200);
        c.startup_grace = Duration::from_millis(0);
        c.long_poll_max = Duration::from_secs(2);
        c.scene_loader = core_scene_loader(limits.clone());
        c.scene_limits = limits;
        c
    }

    /// A worker running in this process; stopped when the returned sender says so.
    pub fn worker(
        base: &str,
        cache: &Path,
    ) -> (watch::Sender<bool>, JoinHandle<anyhow::Result<()>>) {
        let mut c = raytile_worker::Config::new(base);
        c.threads = 1;
        c.name = "w".into();
        c.cache_dir = cache.to_path_buf();
        c.long_poll = Duration::from_secs(1);
        c.max_backoff = Duration::from_millis(300);
        let (stop, rx) = watch::channel(false);
        let mut rx2 = rx.clone();
        let handle = tokio::spawn(raytile_worker::run(c, async move {
            let _ = rx2.wait_for(|v| *v).await;
        }));
        (stop, handle)
    }

    /// Uploads `body` with `query` (`?format=tar`); the status, the body and how long it took.
    pub async fn upload(base: &str, query: &str, body: Vec<u8>) -> (u16, String, Duration) {
        let t = Instant::now();
        let r = reqwest::Client::new()
            .post(format!("{base}/v1/scenes{query}"))
            .body(body)
            .send()
            .await
            .unwrap();
        let status = r.status().as_u16();
        let text = r.text().await.unwrap();
        (status, text, t.elapsed())
    }

    /// Submits a job, waits for its end.
    pub async fn render(base: &str, scene: &str) -> JobStatus {
        let req = JobRequest {
            scene: scene.into(),
            overrides: RenderOverrides {
                width: Some(16),
                height: Some(16),
                spp: Some(1),
                ..Default::default()
            },
            ..Default::default()
        };
        let http = reqwest::Client::new();
        let r = http
            .post(format!("{base}/v1/jobs"))
            .json(&req)
            .send()
            .await
            .unwrap();
        assert_eq!(r.status(), 201, "{:?}", r.text().await);
        let mut s: JobStatus = r.json().await.unwrap();
        let end = Instant::now() + Duration::from_secs(60);
        while !s.state.is_final() {
            assert!(Instant::now() < end, "timed out: {s:?}");
            tokio::time::sleep(Duration::from_millis(50)).await;
            s = http
                .get(format!("{base}/v1/jobs/{}", s.id))
                .send()
                .await
                .unwrap()
                .json()
                .await
                .unwrap();
        }
        s
    }

    /// A tar archive of regular members.
    pub fn tar_of(members: &[(&str, &[u8])]) -> tar::Builder<Vec<u8>> {
        let mut b = tar::Builder::new(Vec::new());
        for (name, data) in members {
            let mut h = tar::Header::new_gnu();
            h.set_size(data.len() as u64);
            h.set_mode(0o644);
            h.set_entry_type(tar::EntryType::Regular);
            b.append_data(&mut h, name, *data).unwrap();
        }
        b
    }

    /// Adds a member of `kind` with no data (a link to `target`, a FIFO...).
    pub fn add_special(
        b: &mut tar::Builder<Vec<u8>>,
        name: &str,
        kind: tar::EntryType,
        target: &str,
    ) {
        let mut h = tar::Header::new_gnu();
        h.set_entry_type(kind);
        h.set_size(0);
        h.set_mode(0o644);
        if kind == tar::EntryType::Symlink {
            b.append_link(&mut h, name, target).unwrap();
        } else {
            b.append_data(&mut h, name, &[][..]).unwrap();
        }
    }

    /// A zip archive whose members have the names given, as an attacker writes them.
    pub fn zip_of(members: &[(&str, &[u8])]) -> Vec<u8> {
        let mut w = zip::ZipWriter::new(std::io::Cursor::new(Vec::new()));
        for (name, data) in members {
            w.start_file(*name, zip::write::SimpleFileOptions::default())
                .unwrap();
            w.write_all(data).unwrap();
        }
        w.finish().unwrap().into_inner()
    }

    pub fn crc32(bytes: &[u8]) -> u32 {
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

    /// A PNG claiming `w × h` pixels without their data: enough for a decoder to read its size.
    pub fn png_header(w: u32, h: u32) -> Vec<u8> {
        png_header_of_depth(w, h, 8)
    }

    /// [`png_header`] of an RGBA image of `depth` bits per channel.
    pub fn png_header_of_depth(w: u32, h: u32, depth: u8) -> Vec<u8> {
        let mut out = b"\x89PNG\r\n\x1a\n".to_vec();
        let mut chunk = |kind: &[u8], data: &[u8]| {
            let body = [kind, data].concat();
            out.extend((data.len() as u32).to_be_bytes());
            out.extend(&body);
            out.extend(crc32(&body).to_be_bytes());
        };
        let ihdr = [&w.to_be_bytes()[..], &h.to_be_bytes(), &[depth, 6, 0, 0, 0]].concat();
        chunk(b"IHDR", &ihdr);
        chunk(b"IDAT", &[]);
        chunk(b"IEND", &[]);
        out
    }

    /// A JSON scene with one image texture at `path`.
    pub fn json_texture(path: &str) -> Vec<u8> {
        format!(r#"{{"textures": {{"t": {{"type": "image", "path": {path:?}}}}}}}"#).into_bytes()
    }

    /// A JSON scene including the glTF file at `path`.
    pub fn json_include(path: &str) -> Vec<u8> {
        format!(r#"{{"objects": [{{"shape": {{"type": "gltf", "path": {path:?}}}}}]}}"#)
            .into_bytes()
    }

    /// A glTF triangle whose positions come from `buffer_uri` (36 bytes), textured with the
    /// image at `image_uri` if given.
    pub fn gltf_triangle(buffer_uri: &str, image_uri: Option<&str>) -> Vec<u8> {
        let mut v = serde_json::json!({
            "asset": {"version": "2.0"},
            "buffers": [{"byteLength": 36, "uri": buffer_uri}],
            "bufferViews": [{"buffer": 0, "byteLength": 36}],
            "accessors": [{"bufferView": 0, "componentType": 5126, "type": "VEC3", "count": 3,
                           "min": [0, 0, 0], "max": [1, 1, 0]}],
            "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
            "nodes": [{"mesh": 0}],
            "scenes": [{"nodes": [0]}]
        });
        if let Some(uri) = image_uri {
            v["images"] = serde_json::json!([{"uri": uri}]);
            v["textures"] = serde_json::json!([{"source": 0}]);
            v["materials"] =
                serde_json::json!([{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}]);
            v["meshes"][0]["primitives"][0]["material"] = 0.into();
        }
        serde_json::to_vec(&v).unwrap()
    }

    /// A percent-encoded data URI of a triangle's 36 bytes of positions.
    pub fn positions_uri() -> String {
        let bytes: Vec<u8> = [0.0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        let mut s = String::from("data:application/octet-stream,");
        for b in bytes {
            s.push_str(&format!("%{b:02X}"));
        }
        s
    }

    /// Makes a FIFO at `path`.
    pub fn mkfifo(path: &Path) {
        let c = std::ffi::CString::new(path.to_string_lossy().as_bytes()).unwrap();
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o644) }, 0, "mkfifo");
    }

    /// This process's resident memory, in bytes (`VmRSS` of /proc/self/status).
    pub fn rss() -> u64 {
        let s = std::fs::read_to_string("/proc/self/status").expect("/proc/self/status");
        let kb: u64 = s
            .lines()
            .find_map(|l| l.strip_prefix("VmRSS:"))
            .and_then(|v| v.split_whitespace().next())
            .and_then(|v| v.parse().ok())
            .expect("VmRSS in /proc/self/status");
        kb * 1024
    }

    /// Samples [`rss`] every few milliseconds until stopped; keeps the highest.
    pub struct RssPeak {
        stop: Arc<AtomicBool>,
        peak: Arc<AtomicU64>,
        thread: Option<std::thread::JoinHandle<()>>,
    }

    impl RssPeak {
        pub fn start() -> RssPeak {
            let stop = Arc::new(AtomicBool::new(false));
            let peak = Arc::new(AtomicU64::new(rss()));
            let (s, p) = (stop.clone(), peak.clone());
            let thread = std::thread::spawn(move || {
                while !s.load(Ordering::Relaxed) {
                    p.fetch_max(rss(), Ordering::Relaxed);
                    std::thread::sleep(Duration::from_millis(2));
                }
            });
            RssPeak {
                stop,
                peak,
                thread: Some(thread),
            }
        }

        /// The highest resident memory seen.
        pub fn finish(mut self) -> u64 {
            self.stop.store(true, Ordering::Relaxed);
            if let Some(t) = self.thread.take() {
                t.join().unwrap();
            }
            self.peak.load(Ordering::Relaxed).max(rss())
        }
    }
}

use support::*;

const MIB: u64 = 1 << 20;

/// Uploads `body`; it must be refused (422 or 413) within a second with a message containing
/// every one of `wants`.
async fn check_refused(base: &str, what: &str, query: &str, body: Vec<u8>, wants: &[&str]) {
    let (status, text, took) = upload(base, query, body).await;
    assert!(
        status == 422 || status == 413,
        "{what}: answered {status}: {text}"
    );
    assert!(took < Duration::from_secs(1), "{what}: took {took:?}");
    let body: proto::ErrorBody =
        serde_json::from_str(&text).unwrap_or_else(|e| panic!("{what}: {e}: {text}"));
    eprintln!("{what}: {status} in {took:.1?}: {}", body.error.message);
    for want in wants {
        assert!(
            body.error.message.contains(want),
            "{what}: {:?} does not say {want:?}",
            body.error.message
        );
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn hostile_scenes_are_refused_at_once_and_the_farm_keeps_serving() {
    let _serial = SERIAL.lock().await;
    let dir = tempfile::tempdir().unwrap();
    // Files outside any scene: what a hostile scene would like to read.
    let host = dir.path().join("host");
    std::fs::create_dir_all(&host).unwrap();
    let secret_png = host.join("secret.png");
    std::fs::write(&secret_png, png_header(2, 2)).unwrap();
    let fifo = host.join("fifo.png");
    mkfifo(&fifo);
    let sparse = host.join("sparse.bin");
    std::fs::File::create(&sparse)
        .unwrap()
        .set_len(10 << 30)
        .unwrap();
    let (secret_png, fifo, sparse) = (
        secret_png.to_str().unwrap(),
        fifo.to_str().unwrap(),
        sparse.to_str().unwrap(),
    );
    let limits = SceneLimits {
        max_parse_memory: 256 * MIB,
        ..SceneLimits::default()
    };
    let c = Coord::start(config(&dir.path().join("data"), limits)).await;
    let b = c.base.as_str();
    let rss_before = rss();
    let peak = RssPeak::start();
    let started = Instant::now();

    // Paths out of the scene's folder, in a JSON scene.
    let absolute = ["absolute paths are refused: a scene names its files relative to its folder, so that it renders the same on any machine"];
    for (what, path) in [
        ("a host image", secret_png),
        ("/etc/passwd", "/etc/passwd"),
        ("/dev/zero", "/dev/zero"),
        ("a FIFO", fifo),
        ("a sparse 10 GiB file", sparse),
    ] {
        let want = format!("{path:?} refused");
        let wants = [&["textures.t.path", want.as_str()][..], &absolute[..]].concat();
        check_refused(
            b,
            &format!("texture: {what}"),
            "",
            json_texture(path),
            &wants,
        )
        .await;
        let wants = [&["objects[0].shape.path", want.as_str()][..], &absolute[..]].concat();
        check_refused(
            b,
            &format!("include: {what}"),
            "",
            json_include(path),
            &wants,
        )
        .await;
    }
    let env = format!(r#"{{"environment": {{"type": "map", "path": {secret_png:?}}}}}"#);
    check_refused(
        b,
        "environment map",
        "",
        env.into_bytes(),
        &["environment.path"],
    )
    .await;
    for path in [
        "../secret.png",
        "sub/../../secret.png",
        "../../../../../../etc/passwd",
    ] {
        let t = tar_of(&[("scene.json", &json_texture(path)), ("sub/x", b"x")]);
        check_refused(
            b,
            path,
            "?format=tar",
            t.into_inner().unwrap(),
            &["textures.t.path", "'..' leads out of the scene's folder"],
        )
        .await;
    }

    // The same in glTF files: buffers and images.
    for (uri, wants) in [
        ("/dev/zero", &["buffers[0].uri", "absolute"][..]),
        ("../../../../etc/passwd", &["buffers[0].uri", "'..'"]),
        ("file:///etc/passwd", &["buffers[0].uri", "scheme"]),
        (fifo, &["buffers[0].uri", "absolute"]),
    ] {
        check_refused(b, uri, "?format=gltf", gltf_triangle(uri, None), wants).await;
    }
    let pos = positions_uri();
    for (uri, wants) in [
        (secret_png, &["images[0].uri", "absolute"][..]),
        ("../secret.png", &["images[0].uri", "'..'"]),
    ] {
        let g = gltf_triangle(&pos, Some(uri));
        check_refused(b, uri, "?format=gltf", g, wants).await;
    }

    // Archives: a link leaving the root, FIFOs and devices as a texture, a glTF include and a
    // glTF buffer, a sparse 10 GiB file, a member claiming 10 GiB.
    let special = "links and special files are not allowed";
    let cases: [(&str, Vec<u8>, &str, tar::EntryType, &str); 6] = [
        (
            "link",
            json_texture("t.png"),
            "t.png",
            tar::EntryType::Symlink,
            "/etc/passwd",
        ),
        (
            "FIFO texture",
            json_texture("t.png"),
            "t.png",
            tar::EntryType::Fifo,
            "",
        ),
        (
            "FIFO include",
            json_include("m.gltf"),
            "m.gltf",
            tar::EntryType::Fifo,
            "",
        ),
        (
            "device include",
            json_include("m.gltf"),
            "m.gltf",
            tar::EntryType::Char,
            "",
        ),
        (
            "FIFO buffer",
            json_include("m.gltf"),
            "b.bin",
            tar::EntryType::Fifo,
            "",
        ),
        (
            "link buffer",
            json_include("m.gltf"),
            "b.bin",
            tar::EntryType::Symlink,
            "../../x",
        ),
    ];
    for (what, scene, name, kind, target) in cases {
        let mut t = tar_of(&[
            ("scene.json", &scene),
            ("m.gltf", &gltf_triangle("b.bin", None)),
        ]);
        add_special(&mut t, name, kind, target);
        check_refused(
            b,
            what,
            "?format=tar&entry=scene.json",
            t.into_inner().unwrap(),
            &[special],
        )
        .await;
    }
    // GNU tar's sparse member: a 10 GiB file of holes in a few hundred bytes.
    let mut t = tar_of(&[
        ("scene.json", &json_include("m.gltf")),
        ("m.gltf", &gltf_triangle("big.bin", None)),
    ]);
    let mut h = tar::Header::new_gnu();
    h.set_entry_type(tar::EntryType::GNUSparse);
    h.set_size(0);
    h.set_mode(0o644);
    // As GNU tar writes a file of holes only: one empty chunk at its end.
    let gnu = h.as_gnu_mut().unwrap();
    gnu.set_real_size(10 << 30);
    gnu.sparse[0].set_offset(10 << 30);
    gnu.sparse[0].set_length(0);
    t.append_data(&mut h, "big.bin", &[][..]).unwrap();
    let t = t.into_inner().unwrap();
    let mut check = tar::Archive::new(&t[..]);
    let last = check.entries().unwrap().last().unwrap().unwrap();
    assert_eq!(
        last.size(),
        10 << 30,
        "the fixture is a sparse 10 GiB member"
    );
    assert_eq!(last.header().entry_type(), tar::EntryType::GNUSparse);
    check_refused(b, "sparse member", "?format=tar", t, &[special]).await;
    let mut t = tar_of(&[
        ("scene.json", &json_include("m.gltf")),
        ("m.gltf", &gltf_triangle("big.bin", None)),
    ]);
    let mut h = tar::Header::new_gnu();
    h.set_entry_type(tar::EntryType::Regular);
    h.set_size(10 << 30);
    h.set_mode(0o644);
    h.set_path("big.bin").unwrap();
    h.set_cksum();
    let mut t = {
        t.finish().unwrap();
        let mut v = t.into_inner().unwrap();
        v.truncate(v.len() - 1024);
        v
    };
    t.extend_from_slice(h.as_bytes());
    t.extend_from_slice(&[0u8; 4096]);
    check_refused(
        b,
        "member claiming 10 GiB",
        "?format=tar",
        t,
        &["too large"],
    )
    .await;

    // Zip members with hostile names.
    for name in [
        "../evil.json",
        "/etc/evil.json",
        "a/../../evil.json",
        "a\\..\\..\\evil.json",
        "nul\0.json",
    ] {
        let z = zip_of(&[(name, b"{}")]);
        check_refused(b, name, "?format=zip", z, &["refusing archive member"]).await;
    }

    // A JSON scene that includes itself, directly (a single file is stored as scene.json)
    // and inside an archive.
    check_refused(
        b,
        "self include",
        "",
        json_include("scene.json"),
        &["includes itself"],
    )
    .await;
    let t = tar_of(&[("me.json", &json_include("./me.json"))]);
    check_refused(
        b,
        "self include in a tar",
        "?format=tar",
        t.into_inner().unwrap(),
        &["includes itself (me.json → me.json)"],
    )
    .await;

    // Image headers claiming huge sizes: refused before anything is decoded; one the decoder
    // would take but the parse memory (256 MiB here) would not, refused before decoding (a
    // 16-bit image is held as floats, 1 GiB). The same size in 8 bits is held as its bytes,
    // 256 MiB: it fits a JSON scene, and this header without data then fails to decode, but
    // not a glTF file, which holds its triangle's data already.
    for (w, h, depth, want, gltf_want) in [
        (100_000, 100_000, 8, "on a side", "on a side"),
        (16384, 16384, 8, "allowed", "allowed"),
        (8192, 8192, 16, "more memory", "more memory"),
        (8192, 8192, 8, "cannot decode", "more memory"),
    ] {
        let png = png_header_of_depth(w, h, depth);
        let t = tar_of(&[("scene.json", &json_texture("big.png")), ("big.png", &png)]);
        check_refused(
            b,
            &format!("{w}×{h}, {depth}-bit texture"),
            "?format=tar",
            t.into_inner().unwrap(),
            &["textures.t.path", want],
        )
        .await;
        let t = tar_of(&[
            ("scene.gltf", &gltf_triangle(&pos, Some("big.png"))),
            ("big.png", &png),
        ]);
        check_refused(
            b,
            &format!("{w}×{h}, {depth}-bit glTF image"),
            "?format=tar",
            t.into_inner().unwrap(),
            &["image 0", gltf_want],
        )
        .await;
    }

    let took = started.elapsed();
    let peak = peak.finish();
    eprintln!(
        "hostile suite: {took:.2?}; resident memory {} MiB before, {} MiB at most (+{} MiB)",
        rss_before / MIB,
        peak / MIB,
        peak.saturating_sub(rss_before) / MIB
    );
    assert!(
        peak.saturating_sub(rss_before) < 128 * MIB,
        "resident memory grew from {} to {} MiB",
        rss_before / MIB,
        peak / MIB
    );

    // Still serving: a normal scene renders.
    let scene = std::fs::read(raytile_tests::cornell_box()).unwrap();
    let (status, text, _) = upload(b, "", scene).await;
    assert_eq!(status, 201, "{text}");
    let id = serde_json::from_str::<proto::SceneCreated>(&text)
        .unwrap()
        .id;
    let (stop, w) = worker(b, &dir.path().join("cache"));
    let s = render(b, &id).await;
    assert_eq!(s.state, JobState::Done, "{s:?}");
    let _ = stop.send(true);
    let _ = w.await;
    c.stop().await;
}

/// Many uploads at once are checked a few at a time: memory stays near one check's, and an
/// upload that waits too long is answered 503 with Retry-After.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn parallel_uploads_are_checked_a_few_at_a_time() {
    let _serial = SERIAL.lock().await;
    let dir = tempfile::tempdir().unwrap();
    // Each scene: a JSON scene and a 2048² PNG of one colour (a few KiB) that decodes to
    // 64 MiB of texels.
    let img = raytile_core::film::encode(
        &raytile_core::Film::new(2048, 2048),
        raytile_core::film::ImageFormat::Png,
        &Default::default(),
    )
    .unwrap();
    assert!(img.len() < 1 << 20, "{} bytes", img.len());
    let limits = SceneLimits {
        max_parallel_parses: 1,
        ..SceneLimits::default()
    };
    let c = Coord::start(config(&dir.path().join("data"), limits)).await;
    let rss_before = rss();
    let peak = RssPeak::start();
    let uploads: Vec<_> = (0..8)
        .map(|i| {
            let scene = format!(
                r#"{{"render": {{"seed": {i}}}, "textures": {{"t": {{"type": "image", "path": "t.png"}}}}}}"#
            );
            let t = tar_of(&[("scene.json", scene.as_bytes()), ("t.png", &img)]);
            let base = c.base.clone();
            tokio::spawn(async move { upload(&base, "?format=tar", t.into_inner().unwrap()).await })
        })
        .collect();
    for u in uploads {
        let (status, text, _) = u.await.unwrap();
        assert_eq!(status, 201, "{text}");
    }
    let peak = peak.finish();
    eprintln!(
        "8 parallel uploads of a 2048² texture, 1 check at a time: resident memory {} MiB before, {} MiB at most (+{} MiB)",
        rss_before / MIB,
        peak / MIB,
        peak.saturating_sub(rss_before) / MIB
    );
    assert!(
        peak.saturating_sub(rss_before) < 400 * MIB,
        "resident memory grew from {} to {} MiB",
        rss_before / MIB,
        peak / MIB
    );
    c.stop().await;

    // A check that takes long: the next upload waits, then is told to come back.
    let mut cfg = config(
        &dir.path().join("slow"),
        SceneLimits {
            max_parallel_parses: 1,
            parse_wait: Duration::from_millis(200),
            ..SceneLimits::default()
        },
    );
    cfg.scene_loader = Arc::new(|_p: &Path| {
        std::thread::sleep(Duration::from_millis(1500));
        Ok(LoadedScene::default())
    });
    let c = Coord::start(cfg).await;
    let first = {
        let base = c.base.clone();
        tokio::spawn(async move { upload(&base, "", br#"{"objects": []}"#.to_vec()).await })
    };
    tokio::time::sleep(Duration::from_millis(300)).await;
    let r = reqwest::Client::new()
        .post(format!("{}/v1/scenes", c.base))
        .body(r#"{"lights": []}"#)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 503);
    assert_eq!(r.headers()["retry-after"], "2");
    let body: proto::ErrorBody = r.json().await.unwrap();
    assert_eq!(body.error.code, "busy");
    assert_eq!(first.await.unwrap().0, 201);
    c.stop().await;
}

/// A worker handed a scene naming files outside its folder (by a coordinator that accepted it
/// unchecked) fails the task with the loader's message, and the job fails with it.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_worker_handed_a_hostile_scene_fails_the_task() {
    let _serial = SERIAL.lock().await;
    let dir = tempfile::tempdir().unwrap();
    let mut cfg = config(&dir.path().join("data"), SceneLimits::default());
    cfg.scene_loader = Arc::new(|_p: &Path| Ok(LoadedScene::default()));
    let c = Coord::start(cfg).await;
    let (stop, w) = worker(&c.base, &dir.path().join("cache"));
    let outside = dir.path().join("outside.png");
    std::fs::write(&outside, png_header(2, 2)).unwrap();
    for (path, want) in [
        (outside.to_str().unwrap(), "absolute paths are refused"),
        (
            "../../../outside.png",
            "'..' leads out of the scene's folder",
        ),
    ] {
        let t = tar_of(&[("scene.json", &json_texture(path))]);
        let (status, text, _) = upload(&c.base, "?format=tar", t.into_inner().unwrap()).await;
        assert_eq!(status, 201, "{text}");
        let id = serde_json::from_str::<proto::SceneCreated>(&text)
            .unwrap()
            .id;
        let s = render(&c.base, &id).await;
        assert_eq!(s.state, JobState::Failed, "{s:?}");
        let err = s.error.unwrap_or_default();
        assert!(
            err.contains("textures.t.path") && err.contains(want),
            "{path}: {err}"
        );
    }
    let _ = stop.send(true);
    let _ = w.await;
    c.stop().await;
}
