//! Container tests: the images from `scripts/build-images.sh`, the top-level
//! `docker-compose.yml` on one host (Compose) and on a single-node Swarm (`docker stack
//! deploy`), with a worker killed and a worker cut off from the network mid-job.
//!
//! They run whenever `docker info` works and skip with a message otherwise. Each starts its
//! own Compose project (or stack) on a free port and tears it down, volumes and networks
//! included, when it ends, also when it fails. They run one at a time (they share two cores
//! and, for the Swarm test, the daemon's swarm membership).
//!
//! Every test renders the repository's `scenes/cornell-box.json` over HTTP and compares the
//! EXR with a render of the same job on this machine, byte for byte.

use raytile_core::film::ImageFormat;
use raytile_core::RenderSettings;
use raytile_proto::{self as proto, JobRequest, JobState, JobStatus, RenderOverrides};
use raytile_tests::{cornell_box, free_port};
use std::path::Path;
use std::process::{Command, Output, Stdio};
use std::sync::{Mutex, OnceLock};
use std::time::{Duration, Instant};

const ROOT: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/..");
const TOKEN: &str = "docker-test-token";
/// The workers' token: the compose file gives workers this one only.
const WORKER_TOKEN: &str = "docker-test-worker-token";

/// One test at a time: they load both cores and the Swarm test changes daemon state.
/// (An async mutex: its guard is held across awaits; each test has its own runtime.)
static SERIAL: tokio::sync::Mutex<()> = tokio::sync::Mutex::const_new(());

/// Whether the tests can run: docker works and the images were built (once per run).
fn ready() -> bool {
    static READY: OnceLock<bool> = OnceLock::new();
    *READY.get_or_init(|| {
        if !run_ok(Command::new("docker").arg("info")) {
            eprintln!("skipping the container tests: `docker info` fails (no Docker daemon)");
            return false;
        }
        if compose_program().is_none() {
            eprintln!("skipping the container tests: neither docker-compose nor `docker compose`");
            return false;
        }
        let out = Command::new("bash")
            .arg(format!("{ROOT}/scripts/build-images.sh"))
            .stdout(Stdio::inherit())
            .stderr(Stdio::inherit())
            .status()
            .expect("running scripts/build-images.sh");
        assert!(out.success(), "scripts/build-images.sh failed");
        true
    })
}

fn run_ok(c: &mut Command) -> bool {
    c.stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}

/// Runs a command; panics with its output when it fails.
fn run(c: &mut Command) -> String {
    let out: Output = c.output().unwrap_or_else(|e| panic!("{c:?}: {e}"));
    assert!(
        out.status.success(),
        "{c:?} failed: {}\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// `docker-compose` (standalone) or `docker compose` (plugin), whichever exists.
fn compose_program() -> Option<Vec<&'static str>> {
    if run_ok(Command::new("docker-compose").arg("version")) {
        Some(vec!["docker-compose"])
    } else if run_ok(Command::new("docker").args(["compose", "version"])) {
        Some(vec!["docker", "compose"])
    } else {
        None
    }
}

/// A Compose project of the top-level `docker-compose.yml`, taken down (with its volumes)
/// when dropped.
struct Compose {
    project: String,
    port: u16,
}

impl Compose {
    fn cmd(&self) -> Command {
        let prog = compose_program().unwrap();
        let mut c = Command::new(prog[0]);
        c.args(&prog[1..])
            .args(["-f", &format!("{ROOT}/docker-compose.yml")])
            .args(["-p", &self.project])
            .current_dir(ROOT)
            .env("RAYTILE_TOKEN", TOKEN)
            .env("RAYTILE_WORKER_TOKEN", WORKER_TOKEN)
            .env("RAYTILE_PORT", self.port.to_string())
            .env("RAYTILE_LEASE_TIMEOUT", "3")
            .env("RAYTILE_STARTUP_GRACE", "0")
            .env("RAYTILE_WORKER_THREADS", "1");
        c
    }

    /// `up -d` with `workers` workers (2, the file's `deploy.replicas`, without `--scale`).
    fn up(name: &str, workers: usize) -> Compose {
        let c = Compose {
            project: format!("raytiletest{name}{}", std::process::id()),
            port: free_port(),
        };
        let mut cmd = c.cmd();
        cmd.args(["up", "-d"]);
        if workers != 2 {
            cmd.args(["--scale", &format!("worker={workers}")]);
        }
        run(&mut cmd);
        assert_eq!(
            c.containers("worker").len(),
            workers,
            "compose started the wrong number of workers"
        );
        c
    }

    fn base(&self) -> String {
        format!("http://127.0.0.1:{}", self.port)
    }

    /// Container ids of a service.
    fn containers(&self, service: &str) -> Vec<String> {
        run(self.cmd().args(["ps", "-q", service]))
            .lines()
            .map(str::trim)
            .filter(|l| !l.is_empty())
            .map(String::from)
            .collect()
    }

    /// The project's default network.
    fn network(&self) -> String {
        format!("{}_default", self.project)
    }
}

impl Drop for Compose {
    fn drop(&mut self) {
        let out = self
            .cmd()
            .args(["down", "-v", "--remove-orphans", "-t", "5"])
            .output();
        if !out.as_ref().is_ok_and(|o| o.status.success()) {
            eprintln!("compose down of {} failed: {out:?}", self.project);
        }
    }
}

/// The host name (= worker name) of a container.
fn hostname(container: &str) -> String {
    run(Command::new("docker").args(["inspect", "-f", "{{.Config.Hostname}}", container]))
        .trim()
        .to_string()
}

fn now_ms() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_millis() as u64
}

/// An HTTP client for the coordinator at `base` with the test token.
struct Api {
    base: String,
    http: reqwest::Client,
}

impl Api {
    fn new(base: String) -> Api {
        Api {
            base,
            http: reqwest::Client::builder()
                .timeout(Duration::from_secs(30))
                .build()
                .unwrap(),
        }
    }

    fn get(&self, path: &str) -> reqwest::RequestBuilder {
        self.http
            .get(format!("{}{path}", self.base))
            .bearer_auth(TOKEN)
    }

    /// Waits until `/healthz` answers and `workers` workers have registered.
    async fn wait_ready(&self, workers: usize, secs: u64) {
        let end = Instant::now() + Duration::from_secs(secs);
        loop {
            let ok = match self.get("/healthz").send().await {
                Ok(r) if r.status().is_success() => self.online(30_000).await.len() >= workers,
                _ => false,
            };
            if ok {
                return;
            }
            assert!(
                Instant::now() < end,
                "the cluster at {} did not come up with {workers} workers in {secs} s",
                self.base
            );
            tokio::time::sleep(Duration::from_millis(250)).await;
        }
    }

    /// Workers seen in the last `within_ms`.
    async fn online(&self, within_ms: u64) -> Vec<proto::WorkerInfo> {
        let now = now_ms();
        self.workers()
            .await
            .into_iter()
            .filter(|w| now.saturating_sub(w.last_seen_ms) <= within_ms)
            .collect()
    }

    /// Every worker the coordinator knows (empty while it is unreachable).
    async fn workers(&self) -> Vec<proto::WorkerInfo> {
        let Ok(r) = self.get("/v1/workers").send().await else {
            return vec![];
        };
        r.json::<proto::WorkerList>()
            .await
            .map(|l| l.workers)
            .unwrap_or_default()
    }

    /// A worker container of `c` that holds a lease right now, and its worker name.
    async fn busy_worker(&self, c: &Compose, job: &str) -> (String, String) {
        let end = Instant::now() + Duration::from_secs(120);
        let containers: Vec<(String, String)> = c
            .containers("worker")
            .into_iter()
            .map(|id| {
                let n = hostname(&id);
                (id, n)
            })
            .collect();
        loop {
            for w in self.workers().await.iter().filter(|w| w.leased > 0) {
                if let Some(found) = containers.iter().find(|(_, n)| *n == w.name) {
                    return found.clone();
                }
            }
            let s = self.status(job).await;
            assert!(
                !s.state.is_final(),
                "the job ended before a busy worker was found: make the test job longer"
            );
            assert!(Instant::now() < end, "no worker container took a lease");
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    }

    async fn upload(&self, file: &Path) -> String {
        let r = self
            .http
            .post(format!("{}/v1/scenes", self.base))
            .bearer_auth(TOKEN)
            .body(std::fs::read(file).unwrap())
            .send()
            .await
            .unwrap();
        assert!(r.status().is_success(), "{:?}", r.text().await);
        r.json::<proto::SceneCreated>().await.unwrap().id
    }

    async fn submit(&self, req: &JobRequest) -> JobStatus {
        let r = self
            .http
            .post(format!("{}/v1/jobs", self.base))
            .bearer_auth(TOKEN)
            .json(req)
            .send()
            .await
            .unwrap();
        assert_eq!(r.status(), 201, "{:?}", r.text().await);
        r.json().await.unwrap()
    }

    async fn status(&self, id: &str) -> JobStatus {
        self.get(&format!("/v1/jobs/{id}"))
            .send()
            .await
            .unwrap()
            .json()
            .await
            .unwrap()
    }

    /// Polls until `pred` holds; panics after `secs`.
    async fn wait_for(&self, id: &str, secs: u64, pred: impl Fn(&JobStatus) -> bool) -> JobStatus {
        let end = Instant::now() + Duration::from_secs(secs);
        loop {
            let s = self.status(id).await;
            if pred(&s) {
                return s;
            }
            assert!(
                Instant::now() < end,
                "timed out after {secs} s; job is {s:?}"
            );
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
    }

    async fn exr(&self, id: &str) -> Vec<u8> {
        let r = self
            .get(&format!("/v1/jobs/{id}/image?format=exr"))
            .send()
            .await
            .unwrap();
        assert_eq!(r.status(), 200);
        r.bytes().await.unwrap().to_vec()
    }
}

/// The job every test renders: long enough (400 tasks of 16×16 pixels × 64 samples, about
/// 10 s on two one-thread workers) that a worker can be killed or cut off while it runs. All
/// tests render this same job, so the local render is done once.
fn job(scene: &str) -> JobRequest {
    JobRequest {
        scene: scene.into(),
        overrides: RenderOverrides {
            width: Some(160),
            height: Some(160),
            spp: Some(256),
            max_depth: Some(16),
            tile_size: Some(16),
            passes: Some(4),
            ..Default::default()
        },
        ..Default::default()
    }
}

/// The EXR of the job rendered in this process (computed once: every test renders the same
/// job).
fn local_exr(scene: &Path, s: &RenderSettings) -> Vec<u8> {
    static CACHE: Mutex<Vec<(String, Vec<u8>)>> = Mutex::new(Vec::new());
    let key = serde_json::to_string(s).unwrap();
    let mut cache = CACHE.lock().unwrap();
    if let Some((_, v)) = cache.iter().find(|(k, _)| *k == key) {
        return v.clone();
    }
    let desc = raytile_core::load_scene(scene).unwrap();
    let built = raytile_core::Scene::build(&desc).unwrap();
    let job = raytile_core::RenderJob::new(&built, s).unwrap();
    let film = raytile_core::render(&built, &job, &());
    let exr = raytile_coordinator::compose::encode(&film, ImageFormat::Exr, &Default::default(), s)
        .unwrap();
    cache.push((key, exr.clone()));
    exr
}

/// Waits for `id` to finish, checks it is done and that its EXR equals the local render.
async fn check_done_identical(api: &Api, scene: &Path, id: &str) -> JobStatus {
    let done = api.wait_for(id, 600, |s| s.state.is_final()).await;
    assert_eq!(done.state, JobState::Done, "{done:?}");
    let got = api.exr(id).await;
    let want = local_exr(scene, &done.settings);
    assert!(
        got == want,
        "the cluster's EXR differs from the local render of the same job"
    );
    done
}

macro_rules! setup {
    () => {{
        let guard = SERIAL.lock().await;
        if !ready() {
            return;
        }
        let scene = cornell_box();
        (guard, scene)
    }};
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn compose_cluster_renders_the_local_image_and_survives_a_killed_worker() {
    let (_guard, scene) = setup!();
    let c = Compose::up("kill", 2);
    let api = Api::new(c.base());
    api.wait_ready(2, 60).await;
    let id = api.upload(&scene).await;

    // Undisturbed: the same bytes as a local render.
    let j = api.submit(&job(&id)).await;
    check_done_identical(&api, &scene, &j.id).await;

    // Kill one worker once the job is under way: the job still completes, identically.
    let j = api.submit(&job(&id)).await;
    api.wait_for(&j.id, 120, |s| s.tasks_done > 0).await;
    let (victim, _) = api.busy_worker(&c, &j.id).await;
    run(Command::new("docker").args(["kill", &victim]));
    let done = check_done_identical(&api, &scene, &j.id).await;
    assert!(
        done.tiles_done == done.tiles_total,
        "not every tile was delivered: {done:?}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn compose_worker_cut_off_mid_job_loses_only_its_lease_and_comes_back() {
    let (_guard, scene) = setup!();
    let c = Compose::up("partition", 2);
    let api = Api::new(c.base());
    api.wait_ready(2, 60).await;
    let id = api.upload(&scene).await;
    let j = api.submit(&job(&id)).await;
    api.wait_for(&j.id, 120, |s| s.tasks_done > 0).await;

    // Cut a worker that holds a lease off its network: its lease expires (3 s here), the
    // other worker finishes the job, identically.
    let (victim, name) = api.busy_worker(&c, &j.id).await;
    run(Command::new("docker").args(["network", "disconnect", &c.network(), &victim]));
    let done = check_done_identical(&api, &scene, &j.id).await;
    assert_eq!(done.tiles_done, done.tiles_total);

    // Reconnected, it talks to the coordinator again and takes part in the next job.
    run(Command::new("docker").args(["network", "connect", &c.network(), &victim]));
    let reconnected = now_ms();
    let end = Instant::now() + Duration::from_secs(90);
    let back = loop {
        if let Some(w) = api
            .workers()
            .await
            .into_iter()
            .find(|w| w.name == name && w.last_seen_ms > reconnected)
        {
            break w;
        }
        assert!(
            Instant::now() < end,
            "worker {name} did not come back after reconnection"
        );
        tokio::time::sleep(Duration::from_millis(250)).await;
    };
    let j2 = api.submit(&job(&id)).await;
    let done = check_done_identical(&api, &scene, &j2.id).await;
    assert!(
        done.workers.get(&back.id).is_some_and(|s| s.tasks > 0),
        "the reconnected worker {name} rendered nothing of the next job: {:?}",
        done.workers
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn compose_scale_to_three_workers_each_renders_part() {
    let (_guard, scene) = setup!();
    let c = Compose::up("scale", 3);
    let api = Api::new(c.base());
    api.wait_ready(3, 60).await;
    let names: Vec<String> = c.containers("worker").iter().map(|c| hostname(c)).collect();
    assert_eq!(names.len(), 3, "{names:?}");
    let workers = api.online(30_000).await;
    for n in &names {
        assert!(
            workers.iter().any(|w| &w.name == n),
            "worker {n} did not register: {workers:?}"
        );
    }
    let id = api.upload(&scene).await;
    let j = api.submit(&job(&id)).await;
    let done = check_done_identical(&api, &scene, &j.id).await;
    for w in workers.iter().filter(|w| names.contains(&w.name)) {
        assert!(
            done.workers.get(&w.id).is_some_and(|s| s.tasks > 0),
            "worker {} rendered nothing: {:?}",
            w.name,
            done.workers
        );
    }
}

/// A single-node Swarm: `docker stack deploy` of the same file, torn down (stack, volume,
/// and the swarm itself when this test created it) when dropped.
struct Stack {
    name: String,
    port: u16,
    left_swarm: bool,
}

impl Stack {
    fn deploy() -> Stack {
        let state = run(Command::new("docker").args(["info", "-f", "{{.Swarm.LocalNodeState}}"]));
        let mut s = Stack {
            name: format!("raytiletest{}", std::process::id()),
            port: free_port(),
            left_swarm: false,
        };
        if state.trim() != "active" {
            run(Command::new("docker").args(["swarm", "init", "--advertise-addr", "127.0.0.1"]));
            s.left_swarm = true;
        }
        run(Command::new("docker")
            .args(["stack", "deploy", "-c", "docker-compose.yml", &s.name])
            .current_dir(ROOT)
            .env("RAYTILE_TOKEN", TOKEN)
            .env("RAYTILE_WORKER_TOKEN", WORKER_TOKEN)
            .env("RAYTILE_PORT", s.port.to_string())
            .env("RAYTILE_LEASE_TIMEOUT", "3")
            .env("RAYTILE_STARTUP_GRACE", "0")
            .env("RAYTILE_WORKER_THREADS", "1"));
        s
    }
}

impl Drop for Stack {
    fn drop(&mut self) {
        let _ = Command::new("docker")
            .args(["stack", "rm", &self.name])
            .output();
        // The stack's containers go away asynchronously; its volume can only be removed
        // after them.
        let volume = format!("{}_coordinator-data", self.name);
        let end = Instant::now() + Duration::from_secs(60);
        while Instant::now() < end {
            let left = Command::new("docker")
                .args(["ps", "-aq", "--filter"])
                .arg(format!("label=com.docker.stack.namespace={}", self.name))
                .output()
                .map(|o| !o.stdout.is_empty())
                .unwrap_or(false);
            if !left && run_ok(Command::new("docker").args(["volume", "rm", "-f", &volume])) {
                break;
            }
            std::thread::sleep(Duration::from_millis(500));
        }
        if self.left_swarm {
            let _ = Command::new("docker")
                .args(["swarm", "leave", "--force"])
                .output();
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn swarm_stack_deploy_renders_the_local_image() {
    let (_guard, scene) = setup!();
    let s = Stack::deploy();
    let api = Api::new(format!("http://127.0.0.1:{}", s.port));
    // A fresh swarm's service names resolve only after a few seconds: workers retry.
    api.wait_ready(2, 180).await;
    let id = api.upload(&scene).await;
    let j = api.submit(&job(&id)).await;
    let done = check_done_identical(&api, &scene, &j.id).await;
    assert!(!done.workers.is_empty(), "{done:?}");
}
