//! `raytile submit`: upload a scene, submit a job, follow it with a progress bar, download
//! the image.

use crate::render::flag_error;
use anyhow::{anyhow, bail, Context};
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use raytile_core::film::ImageFormat;
use raytile_proto::client::{Client, ClientError};
use raytile_proto::scene::{self as pkg, SceneFormat};
use raytile_proto::{JobRequest, JobState, JobStatus, RenderOverrides};
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
        let c = Client::new(&args.coordinator, args.token.clone())?;
        let wait = args.wait || args.output.is_some();
        let job =
            submit_and_follow(&c, &args.scene, &args.job, wait, args.output.as_deref()).await?;
        if !wait {
            println!("{}", job.id);
        }
        Ok::<(), anyhow::Error>(())
    })
}

/// A coordinator's refusal of a job as the command line says it: a settings field named by the
/// coordinator (`max_depth`) is named as its flag (`--max-depth`).
fn job_error(e: ClientError) -> anyhow::Error {
    if let ClientError::Status {
        field: Some(field),
        message,
        ..
    } = &e
    {
        if let Some(f) = RenderOverrides::FIELDS.iter().find(|f| *f == field) {
            let message = message.strip_prefix(&format!("{f}: ")).unwrap_or(message);
            return anyhow!("--{}: {message}", f.replace('_', "-"));
        }
    }
    anyhow::Error::new(e).context("submitting the job")
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

/// Reads a scene for upload: (bytes, format, entry). A folder, or a `.gltf` with files beside
/// it, travels as a tar archive of the folder.
pub fn scene_upload(path: &Path) -> anyhow::Result<(Vec<u8>, Option<SceneFormat>, Option<String>)> {
    if path.is_dir() {
        return Ok((pkg::pack_folder(path)?, Some(SceneFormat::Tar), None));
    }
    let format = path
        .extension()
        .and_then(|e| e.to_str())
        .and_then(SceneFormat::from_name);
    if format == Some(SceneFormat::Gltf) && gltf_has_external_files(path)? {
        let dir = path.parent().unwrap_or(Path::new("."));
        let dir = if dir.as_os_str().is_empty() {
            Path::new(".")
        } else {
            dir
        };
        let entry = path.file_name().map(|n| n.to_string_lossy().into_owned());
        return Ok((pkg::pack_folder(dir)?, Some(SceneFormat::Tar), entry));
    }
    let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    Ok((bytes, format, None))
}

/// Uploads the scene, submits the job and, if `wait`, follows it to the end and writes the
/// image to `output`. Bad flags and an unknown output extension are refused before anything is
/// uploaded.
pub async fn submit_and_follow(
    c: &Client,
    scene: &Path,
    job: &JobArgs,
    wait: bool,
    output: Option<&Path>,
) -> anyhow::Result<JobStatus> {
    let format = output.map(ImageFormat::from_path).transpose()?;
    job.overrides.check().map_err(flag_error)?;
    let (bytes, scene_format, entry) = scene_upload(scene)?;
    let created = c
        .upload_scene(bytes, scene_format, entry.as_deref())
        .await
        .context("uploading the scene")?;
    let mut status = c
        .create_job(&job.request(created.id))
        .await
        .map_err(job_error)?;
    if !wait {
        return Ok(status);
    }
    let bar = ProgressBar::new(status.tasks_total);
    bar.set_style(
        ProgressStyle::with_template(
            "{spinner} [{elapsed_precise}] {bar:40} {pos}/{len} tile passes {msg}",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    while !status.state.is_final() {
        tokio::time::sleep(Duration::from_millis(100)).await;
        status = c.job(&status.id).await?;
        bar.set_position(status.tasks_done);
        bar.set_message(format!(
            "{} ({} workers)",
            status.state.name(),
            status.workers.len()
        ));
    }
    bar.finish_and_clear();
    match status.state {
        JobState::Done => {}
        JobState::Failed => bail!(
            "job {} failed: {}",
            status.id,
            status.error.as_deref().unwrap_or("unknown error")
        ),
        _ => bail!("job {} was {}", status.id, status.state.name()),
    }
    if let (Some(out), Some(format)) = (output, format) {
        let bytes = c.job_image(&status.id, format.name()).await?;
        std::fs::write(out, &bytes).with_context(|| format!("writing {}", out.display()))?;
        eprintln!("wrote {}", out.display());
    }
    Ok(status)
}
