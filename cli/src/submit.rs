//! `raytile submit`: upload a scene, submit a job, follow it with a progress bar, download
//! the image.

use crate::render::flag_error;
use anyhow::{bail, Context};
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use raytile_proto::{self as proto, scene as pkg, JobRequest, JobState, RenderOverrides};
use std::path::{Path, PathBuf};
use std::time::Duration;

/// Job settings as flags: the settings that differ from the scene's own, and the priority.
#[derive(Args, Debug, Clone, Default)]
pub struct JobArgs {
    /// Settings that differ from the scene's own.
    #[command(flatten)]
    pub overrides: RenderOverrides,
    /// Job priority (higher first).
    #[arg(long, allow_hyphen_values = true)]
    pub priority: Option<i32>,
}

impl JobArgs {
    /// The job request for `scene`.
    pub fn request(&self, scene: String) -> JobRequest {
        JobRequest {
            scene,
            overrides: self.overrides.clone(),
            priority: self.priority,
        }
    }
}

/// `raytile submit` flags.
#[derive(Args, Debug)]
pub struct SubmitArgs {
    /// Scene file (.gltf, .glb, .json) or folder.
    pub scene: PathBuf,
    /// Coordinator URL.
    #[arg(
        long,
        env = "RAYTILE_COORDINATOR",
        default_value = "http://127.0.0.1:8080"
    )]
    pub coordinator: String,
    /// Bearer token.
    #[arg(long, env = "RAYTILE_TOKEN", hide_env_values = true)]
    pub token: Option<String>,
    /// Job settings.
    #[command(flatten)]
    pub job: JobArgs,
    /// Write the final image here (.png, .exr or .hdr); implies --wait.
    #[arg(short = 'o', long)]
    pub output: Option<PathBuf>,
    /// Wait until the job ends.
    #[arg(long)]
    pub wait: bool,
}

/// Runs `raytile submit`.
pub fn run(args: SubmitArgs) -> anyhow::Result<()> {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    rt.block_on(async {
        let c = Api::new(&args.coordinator, args.token.clone())?;
        let wait = args.wait || args.output.is_some();
        let job =
            submit_and_follow(&c, &args.scene, &args.job, wait, args.output.as_deref()).await?;
        if !wait {
            println!("{}", job.id);
        }
        Ok::<(), anyhow::Error>(())
    })
}

/// A small client of the coordinator's API.
pub struct Api {
    http: reqwest::Client,
    base: String,
    token: Option<String>,
}

impl Api {
    /// A client for `base` (e.g. `http://127.0.0.1:8080`).
    pub fn new(base: &str, token: Option<String>) -> anyhow::Result<Api> {
        Ok(Api {
            http: reqwest::Client::builder().build()?,
            base: base.trim_end_matches('/').to_string(),
            token: token.filter(|t| !t.is_empty()),
        })
    }

    fn req(&self, m: reqwest::Method, path: &str) -> reqwest::RequestBuilder {
        let r = self.http.request(m, format!("{}{path}", self.base));
        match &self.token {
            Some(t) => r.bearer_auth(t),
            None => r,
        }
    }

    async fn send(&self, r: reqwest::RequestBuilder) -> anyhow::Result<reqwest::Response> {
        let resp = r
            .send()
            .await
            .with_context(|| format!("cannot reach the coordinator at {}", self.base))?;
        if resp.status().is_success() {
            return Ok(resp);
        }
        let status = resp.status();
        let text = resp.text().await.unwrap_or_default();
        let msg = serde_json::from_str::<proto::ErrorBody>(&text)
            .map(|b| b.error.message)
            .unwrap_or(text);
        bail!("coordinator answered {status}: {msg}")
    }
}

/// Whether a .gltf file references files beside it (not data URIs).
fn gltf_has_external_files(path: &Path) -> anyhow::Result<bool> {
    let text = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    let v: serde_json::Value =
        serde_json::from_slice(&text).with_context(|| format!("{} is not JSON", path.display()))?;
    let external = |key: &str| {
        v.get(key).and_then(|a| a.as_array()).is_some_and(|a| {
            a.iter().any(|b| {
                b.get("uri")
                    .and_then(|u| u.as_str())
                    .is_some_and(|u| !u.starts_with("data:"))
            })
        })
    };
    Ok(external("buffers") || external("images"))
}

/// Reads a scene for upload: (bytes, format hint, entry).
pub fn scene_upload(
    path: &Path,
) -> anyhow::Result<(Vec<u8>, Option<&'static str>, Option<String>)> {
    if path.is_dir() {
        return Ok((pkg::pack_folder(path)?, Some("tar"), None));
    }
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    if ext.as_deref() == Some("gltf") && gltf_has_external_files(path)? {
        let dir = path.parent().unwrap_or(Path::new("."));
        let dir = if dir.as_os_str().is_empty() {
            Path::new(".")
        } else {
            dir
        };
        let entry = path.file_name().map(|n| n.to_string_lossy().into_owned());
        return Ok((pkg::pack_folder(dir)?, Some("tar"), entry));
    }
    let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    let hint = match ext.as_deref() {
        Some("gltf") => Some("gltf"),
        Some("glb") => Some("glb"),
        Some("json") => Some("json"),
        Some("tar") => Some("tar"),
        Some("zip") => Some("zip"),
        _ => None,
    };
    Ok((bytes, hint, None))
}

/// Uploads the scene, submits the job and, if `wait`, follows it to the end and writes the
/// image to `output`.
pub async fn submit_and_follow(
    c: &Api,
    scene: &Path,
    job_args: &JobArgs,
    wait: bool,
    output: Option<&Path>,
) -> anyhow::Result<proto::JobStatus> {
    job_args.overrides.check().map_err(flag_error)?;
    let (bytes, hint, entry) = scene_upload(scene)?;
    let mut q: Vec<(&str, String)> = Vec::new();
    if let Some(h) = hint {
        q.push(("format", h.into()));
    }
    if let Some(e) = entry {
        q.push(("entry", e));
    }
    let created: proto::SceneCreated = c
        .send(
            c.req(reqwest::Method::POST, "/v1/scenes")
                .query(&q)
                .body(bytes),
        )
        .await
        .context("uploading the scene")?
        .json()
        .await?;
    let req = job_args.request(created.id);
    let mut job: proto::JobStatus = c
        .send(c.req(reqwest::Method::POST, "/v1/jobs").json(&req))
        .await
        .context("submitting the job")?
        .json()
        .await?;
    if !wait {
        return Ok(job);
    }
    let bar = ProgressBar::new(job.tasks_total);
    bar.set_style(
        ProgressStyle::with_template(
            "{spinner} [{elapsed_precise}] {bar:40} {pos}/{len} tile passes {msg}",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    while !job.state.is_final() {
        tokio::time::sleep(Duration::from_millis(100)).await;
        job = c
            .send(c.req(reqwest::Method::GET, &format!("/v1/jobs/{}", job.id)))
            .await?
            .json()
            .await?;
        bar.set_position(job.tasks_done);
        bar.set_message(format!(
            "{} ({} workers)",
            job.state.name(),
            job.workers.len()
        ));
    }
    bar.finish_and_clear();
    match job.state {
        JobState::Done => {}
        JobState::Failed => bail!(
            "job {} failed: {}",
            job.id,
            job.error.as_deref().unwrap_or("unknown error")
        ),
        _ => bail!("job {} was {}", job.id, job.state.name()),
    }
    if let Some(out) = output {
        let fmt = match out
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase)
            .as_deref()
        {
            Some("exr") => "exr",
            Some("hdr") => "hdr",
            _ => "png",
        };
        let bytes = c
            .send(c.req(
                reqwest::Method::GET,
                &format!("/v1/jobs/{}/image?format={fmt}", job.id),
            ))
            .await?
            .bytes()
            .await?;
        std::fs::write(out, &bytes).with_context(|| format!("writing {}", out.display()))?;
        eprintln!("wrote {}", out.display());
    }
    Ok(job)
}
