//! `raytile submit`: check a scene as a farm will and upload exactly the files it uses, submit
//! a job, follow it with a progress bar, download the image.

use crate::render::flag_error;
use anyhow::{anyhow, bail, Context};
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use raytile_core::film::ImageFormat;
use raytile_core::scene::files::{self, SceneFiles};
use raytile_core::scene::gltf::{no_light_warning, NO_LIGHT_WARNING};
use raytile_proto::client::{reqwest, Bytes, Client, ClientError};
use raytile_proto::scene::{self as pkg, SceneFormat};
use raytile_proto::{
    EnvironmentChoice, JobRequest, JobState, JobStatus, RenderOverrides, SceneCreated,
};
use std::path::{Path, PathBuf};
use std::time::Duration;
use tokio::io::AsyncReadExt as _;

/// Job settings as flags: the settings that differ from the scene's own, and the priority.
#[derive(Args, Debug, Clone, Default)]
pub struct JobArgs {
    /// Settings that differ from the scene's own.
    #[command(flatten)]
    pub overrides: RenderOverrides,
    /// Job priority (higher first).
    #[arg(long, allow_hyphen_values = true)]
    pub priority: Option<i32>,
    /// How a PNG written with -o is made of the linear image (not part of the job: the
    /// coordinator makes such a PNG when asked).
    #[command(flatten)]
    pub look: crate::render::LookArgs,
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
    /// Scene file (.gltf, .glb, .json), or a folder with one scene file at its top.
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
    if let Some(problem) = raytile_proto::client::cert_store_problem() {
        eprintln!("raytile: warning: {problem}");
    }
    rt.block_on(async {
        let c = Client::new(&args.coordinator, args.token.clone())?;
        let wait = args.wait || args.output.is_some();
        if args.output.is_none() && args.job.look.options() != Default::default() {
            eprintln!(
                "raytile: warning: --exposure and --tonemap shape the PNG written with -o; \
                 without -o they do nothing (ask GET /v1/jobs/ID/image?format=png&exposure=...)"
            );
        }
        let job =
            submit_and_follow(&c, &args.scene, &args.job, wait, args.output.as_deref()).await?;
        // The job's id, to fetch its image later; with --wait, once the job is done.
        if args.output.is_none() {
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

/// What `raytile submit` uploads for a scene: the scene file and every file it uses, checked
/// as a farm checks them (confined to the scene's folder).
#[derive(Debug)]
pub struct ScenePack {
    /// The scene file's format, from its extension.
    pub format: Option<SceneFormat>,
    /// Every file the scene read, the scene file first, named relative to its folder.
    pub files: Vec<pkg::PackFile>,
}

impl ScenePack {
    /// Loads the scene at `path` (a scene file, or a folder with one scene file at its top) as
    /// the farm will, confined to the scene's folder, and lists the files it read. A scene
    /// naming a file the farm would refuse is an error that says which and how to fix it.
    pub fn check(path: &Path) -> anyhow::Result<ScenePack> {
        let scene = if path.is_dir() {
            scene_in_folder(path)?
        } else {
            path.to_path_buf()
        };
        // The farm's own size limits are its business: here only where files are matters,
        // with the caps of a local render.
        let files = SceneFiles::confined_to_scene(&scene, files::TRUSTED_FILE_CAP, u64::MAX)
            .with_context(|| format!("reading the folder of {}", scene.display()))?;
        if let Err(e) = raytile_core::load_scene_with(&scene, &files) {
            return Err(match files.refusal().and_then(|r| r.refusal.hint()) {
                Some(hint) => anyhow!("{e}; a farm reads only files in the scene's folder: {hint}"),
                None => anyhow!("{e}"),
            });
        }
        let files = files
            .used()
            .into_iter()
            .map(|u| {
                let name = u.name.as_deref().unwrap_or(&u.path);
                let name = name
                    .to_str()
                    .ok_or_else(|| anyhow!("{}: the file name is not UTF-8", u.path.display()))?
                    .replace(std::path::MAIN_SEPARATOR, "/");
                Ok(pkg::PackFile {
                    path: u.path,
                    name,
                    size: u.bytes,
                })
            })
            .collect::<anyhow::Result<Vec<_>>>()?;
        let format = scene
            .extension()
            .and_then(|e| e.to_str())
            .and_then(SceneFormat::from_name);
        Ok(ScenePack { format, files })
    }

    /// Adds the environment map `map` (a path as the user gave it) to the files uploaded and
    /// returns its name in the scene's folder, as the job names it: its own path there if it
    /// is inside the folder, otherwise `environment/` and its file name.
    pub fn add_environment(&mut self, map: &Path) -> anyhow::Result<String> {
        let meta =
            std::fs::metadata(map).with_context(|| format!("--environment {}", map.display()))?;
        if !meta.is_file() {
            bail!("--environment {}: not a regular file", map.display());
        }
        let canonical = std::fs::canonicalize(map)
            .with_context(|| format!("--environment {}", map.display()))?;
        let folder = self.files[0]
            .path
            .parent()
            .filter(|p| !p.as_os_str().is_empty())
            .unwrap_or(Path::new("."));
        let folder = std::fs::canonicalize(folder).context("the scene's folder")?;
        let inside = canonical
            .strip_prefix(&folder)
            .ok()
            .and_then(|rel| rel.to_str())
            .map(|rel| rel.replace(std::path::MAIN_SEPARATOR, "/"));
        let name = match inside {
            Some(rel) => rel,
            None => {
                // The name as given (a link keeps its own): the image's metadata names the map
                // by it, as `raytile render`'s does.
                let file = map.file_name().and_then(|n| n.to_str()).ok_or_else(|| {
                    anyhow!(
                        "--environment {}: the file name is not UTF-8",
                        map.display()
                    )
                })?;
                format!("environment/{file}")
            }
        };
        match self.files.iter().find(|f| f.name == name) {
            Some(f)
                if std::fs::canonicalize(&f.path).ok().as_deref() == Some(canonical.as_path()) => {}
            Some(_) => bail!(
                "--environment {}: the scene already uses a file named {name}; rename the map",
                map.display()
            ),
            None => self.files.push(pkg::PackFile {
                path: canonical,
                name: name.clone(),
                size: meta.len(),
            }),
        }
        Ok(name)
    }

    /// Bytes of all the files together.
    pub fn total_bytes(&self) -> u64 {
        self.files.iter().map(|f| f.size).sum()
    }

    /// What is uploaded, for the user: one line per file after the total.
    pub fn summary(&self) -> String {
        let mut out = format!(
            "packing {} files, {} in all:",
            self.files.len(),
            show_bytes(self.total_bytes())
        );
        for f in &self.files {
            out.push_str(&format!("\n  {}  {}", f.name, show_bytes(f.size)));
        }
        out
    }

    /// Uploads the scene: a scene that uses no other file as it is, otherwise a tar archive of
    /// exactly the files it uses, written to the request body as it is sent. Either way the
    /// length goes first, so a coordinator refuses an upload over its limit at once.
    pub async fn upload(&self, c: &Client) -> anyhow::Result<SceneCreated> {
        match self.send(c).await {
            Err(e)
                if e.downcast_ref::<ClientError>()
                    .is_some_and(ClientError::is_unreachable)
                    && c.health().await.is_ok() =>
            {
                // An HTTP client sending a body may not read the answer the coordinator gives
                // before it has it all (a 413): it sees the connection closed under it.
                Err(e.context(format!(
                    "the coordinator closed the connection while {} were sent: an upload over its limit (--max-upload-bytes, 512 MiB by default) is refused that way",
                    show_bytes(self.upload_bytes())
                )))
            }
            r => r,
        }
    }

    /// The bytes the upload sends.
    fn upload_bytes(&self) -> u64 {
        match self.files.as_slice() {
            [only] => only.size,
            files => pkg::packed_size(files),
        }
    }

    async fn send(&self, c: &Client) -> anyhow::Result<SceneCreated> {
        if let [only] = self.files.as_slice() {
            let file = tokio::fs::File::open(&only.path)
                .await
                .with_context(|| format!("reading {}", only.path.display()))?;
            let chunks =
                futures_util::stream::try_unfold(file.take(only.size), |mut f| async move {
                    let mut buf = vec![0u8; CHUNK];
                    let n = f.read(&mut buf).await?;
                    buf.truncate(n);
                    std::io::Result::Ok((n > 0).then(|| (Bytes::from(buf), f)))
                });
            let body = reqwest::Body::wrap_stream(chunks);
            return Ok(c
                .upload_scene_stream(body, only.size, self.format, None)
                .await?);
        }
        eprintln!("{}", self.summary());
        let (tx, mut rx) = tokio::sync::mpsc::channel::<std::io::Result<Bytes>>(4);
        let files = self.files.clone();
        let packer = tokio::task::spawn_blocking(move || {
            let mut w = ChannelWriter {
                tx: tx.clone(),
                buf: Vec::with_capacity(CHUNK),
            };
            let r = pkg::pack_files(&files, &mut w).and_then(|()| std::io::Write::flush(&mut w));
            if let Err(e) = &r {
                // The body must fail rather than end: a cut archive must never be taken for a
                // whole one.
                let _ = tx.blocking_send(Err(std::io::Error::new(e.kind(), e.to_string())));
            }
            r
        });
        let body = futures_util::stream::poll_fn(move |cx| rx.poll_recv(cx));
        let entry = self.files[0].name.clone();
        let created = c
            .upload_scene_stream(
                reqwest::Body::wrap_stream(body),
                pkg::packed_size(&self.files),
                Some(SceneFormat::Tar),
                Some(&entry),
            )
            .await;
        match packer.await? {
            Err(e) if e.kind() != std::io::ErrorKind::BrokenPipe => {
                Err(anyhow!(e).context("packing the scene"))
            }
            _ => Ok(created?),
        }
    }
}

/// The one scene file (`.gltf`, `.glb` or `.json`) at the top of `dir`.
pub(crate) fn scene_in_folder(dir: &Path) -> anyhow::Result<PathBuf> {
    let mut found = Vec::new();
    for e in std::fs::read_dir(dir).with_context(|| format!("reading {}", dir.display()))? {
        let p = e?.path();
        let ext = p
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase);
        if p.is_file() && matches!(ext.as_deref(), Some("gltf" | "glb" | "json")) {
            found.push(p);
        }
    }
    found.sort();
    match found.as_slice() {
        [one] => Ok(one.clone()),
        [] => bail!(
            "{}: no .gltf, .glb or .json scene file in it",
            dir.display()
        ),
        many => bail!(
            "{}: several scene files ({}): name the one to use",
            dir.display(),
            many.iter()
                .filter_map(|p| p.file_name())
                .map(|n| n.to_string_lossy().into_owned())
                .collect::<Vec<_>>()
                .join(", ")
        ),
    }
}

/// Bytes for people: `12.3 MiB`.
fn show_bytes(n: u64) -> String {
    const UNITS: [&str; 4] = ["bytes", "KiB", "MiB", "GiB"];
    let mut v = n as f64;
    let mut unit = 0;
    while v >= 1024.0 && unit + 1 < UNITS.len() {
        v /= 1024.0;
        unit += 1;
    }
    if unit == 0 {
        format!("{n} bytes")
    } else {
        format!("{v:.1} {}", UNITS[unit])
    }
}

/// Size of the chunks the archive is sent in.
const CHUNK: usize = 1 << 16;

/// Hands what is written to the request body in chunks; blocks while the body has not taken
/// the previous chunks, so the archive is never all in memory.
struct ChannelWriter {
    tx: tokio::sync::mpsc::Sender<std::io::Result<Bytes>>,
    buf: Vec<u8>,
}

impl ChannelWriter {
    fn send(&mut self) -> std::io::Result<()> {
        if self.buf.is_empty() {
            return Ok(());
        }
        let chunk = Bytes::from(std::mem::replace(&mut self.buf, Vec::with_capacity(CHUNK)));
        self.tx
            .blocking_send(Ok(chunk))
            .map_err(|_| std::io::Error::new(std::io::ErrorKind::BrokenPipe, "the upload ended"))
    }
}

impl std::io::Write for ChannelWriter {
    fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
        self.buf.extend_from_slice(b);
        if self.buf.len() >= CHUNK {
            self.send()?;
        }
        Ok(b.len())
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.send()
    }
}

/// How long a client that follows a job keeps asking a coordinator that does not answer (a
/// restart, a network cut, a proxy without its upstream) before it gives up.
const OUTAGE: Duration = Duration::from_secs(300);

/// Whether a request may succeed if made again: no answer, or a gateway's or an overloaded
/// server's status.
fn transient(e: &ClientError) -> bool {
    match e {
        // A certificate that is not trusted stays so; anything else may be the network.
        ClientError::Unreachable { message, .. } => !message.contains("certificate"),
        ClientError::Status { status, .. } => matches!(status.as_u16(), 502..=504),
        // An answer cut off midway (a restart while it was sent): every call asked again is
        // a GET.
        ClientError::Body(_) => true,
        _ => false,
    }
}

/// `call`, made again while the coordinator answers it 503 with one of its own error bodies (it
/// cannot write its store at the moment, or is shutting down: nothing was changed), with
/// backoff, for up to [`OUTAGE`]; the user is told once, naming `what` was being done. A 503
/// without the coordinator's error body (a proxy's) is not asked again: the proxy may have
/// passed the request on, and a job would be submitted twice.
async fn while_busy<T, F, Fut>(what: &str, mut call: F) -> anyhow::Result<T>
where
    F: FnMut() -> Fut,
    Fut: std::future::Future<Output = anyhow::Result<T>>,
{
    let start = std::time::Instant::now();
    let mut delay = Duration::from_millis(250);
    let mut told = false;
    loop {
        match call().await {
            Err(e) if start.elapsed() < OUTAGE && unchanged(&e) => {
                if !told {
                    eprintln!(
                        "raytile: {what}: {e}; trying again for up to {} minutes",
                        OUTAGE.as_secs() / 60
                    );
                    told = true;
                }
                tokio::time::sleep(delay).await;
                delay = (delay * 2).min(Duration::from_secs(5));
            }
            r => return r,
        }
    }
}

/// Whether `e` is the coordinator's own 503, which says nothing was changed.
fn unchanged(e: &anyhow::Error) -> bool {
    matches!(
        e.downcast_ref::<ClientError>(),
        Some(ClientError::Status { status, code: Some(code), .. })
            if *status == reqwest::StatusCode::SERVICE_UNAVAILABLE
                && matches!(code.as_str(), "store_unavailable" | "unavailable" | "busy")
    )
}

/// `call` for job `id`, made again while its failure is [`transient`], with backoff, for up
/// to [`OUTAGE`]; `say` tells the user once that the coordinator does not answer, and again
/// when it does.
async fn patiently<T, F, Fut>(id: &str, say: &dyn Fn(String), mut call: F) -> anyhow::Result<T>
where
    F: FnMut() -> Fut,
    Fut: std::future::Future<Output = Result<T, ClientError>>,
{
    let start = std::time::Instant::now();
    let mut delay = Duration::from_millis(250);
    let mut told = false;
    loop {
        match call().await {
            Ok(v) => {
                if told {
                    say(format!("raytile: the coordinator answers again (job {id})"));
                }
                return Ok(v);
            }
            Err(e) if transient(&e) && start.elapsed() < OUTAGE => {
                if !told {
                    say(format!(
                        "raytile: {e}; asking again for up to {} minutes (job {id} goes on)",
                        OUTAGE.as_secs() / 60
                    ));
                    told = true;
                }
                tokio::time::sleep(delay).await;
                delay = (delay * 2).min(Duration::from_secs(5));
            }
            Err(e) => return Err(anyhow::Error::new(e).context(format!("following job {id}"))),
        }
    }
}

/// Uploads the scene, submits the job and, if `wait`, follows it to the end and writes the
/// image to `output`. Bad flags, an unknown output extension and a scene naming a file a farm
/// would refuse are refused before anything is uploaded.
pub async fn submit_and_follow(
    c: &Client,
    scene: &Path,
    job: &JobArgs,
    wait: bool,
    output: Option<&Path>,
) -> anyhow::Result<JobStatus> {
    let format = output.map(ImageFormat::from_path).transpose()?;
    if let (Some(o), Some(f)) = (output, format) {
        raytile_core::film::check_writable(o)?;
        job.look.warn_unless_png(f, o);
    }
    job.overrides.check().map_err(flag_error)?;
    let mut pack = ScenePack::check(scene)?;
    let mut job = job.clone();
    if let Some(EnvironmentChoice::Map(map)) = &job.overrides.environment {
        // The map travels with the scene; the job names it inside the scene's folder.
        let name = pack.add_environment(Path::new(map))?;
        job.overrides.environment = Some(EnvironmentChoice::Map(name));
    }
    let created = while_busy("uploading the scene", || pack.upload(c))
        .await
        .context("uploading the scene")?;
    let request = job.request(created.id);
    let mut status = while_busy("submitting the job", || async {
        c.create_job(&request).await.map_err(anyhow::Error::new)
    })
    .await
    .map_err(|e| match e.downcast::<ClientError>() {
        Ok(e) => job_error(e),
        Err(e) => e,
    })?;
    if let (Some(o), Some(f)) = (output, format) {
        crate::render::LookArgs::warn_if_alpha_lost(status.settings.alpha, f, o);
    }
    // What the farm's loader said about the scene, as `raytile render` says it: the default
    // light's warning names what lights this job in its place.
    for w in &created.warnings {
        if w == NO_LIGHT_WARNING {
            eprintln!("raytile: warning: {}", no_light_warning(&status.settings));
        } else {
            eprintln!("raytile: warning: {w}");
        }
    }
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
    // Frames of a done job made without a tag, in a row.
    let mut untagged = 0;
    // Said above the progress bar when it shows, on stderr when it does not (not a terminal).
    let say = |m: String| {
        if bar.is_hidden() {
            eprintln!("{m}");
        } else {
            bar.println(m);
        }
    };
    // The id first: a user who stops waiting can still find the job, which goes on.
    say(format!(
        "raytile: job {} submitted; it goes on if you stop waiting (the coordinator's \
         DELETE /v1/jobs/{} cancels it)",
        status.id, status.id
    ));
    let id = status.id.clone();
    loop {
        while !status.state.is_final() {
            tokio::time::sleep(Duration::from_millis(100)).await;
            status = patiently(&id, &say, || c.job(&id)).await?;
            bar.set_position(status.tasks_done);
            bar.set_message(format!(
                "{} ({} workers)",
                status.state.name(),
                status.workers.len()
            ));
        }
        if status.state != JobState::Done {
            bar.finish_and_clear();
        }
        match status.state {
            JobState::Done => {}
            JobState::Failed => bail!(
                "job {} failed: {}",
                status.id,
                status.error.as_deref().unwrap_or("unknown error")
            ),
            _ => bail!("job {} was {}", status.id, status.state.name()),
        }
        let (Some(out), Some(format)) = (output, format) else {
            break;
        };
        let look = job.look.query(format);
        let image = patiently(&id, &say, || c.job_image_tagged(&id, format.name(), &look)).await?;
        let (bytes, tag) = (image.bytes, image.etag);
        // Making the frame reads every stored tile: one found lost or damaged is left out (the
        // frame has no tag) and rendered again, and the job runs again (and may be done again
        // already). The frame is written once it has every tile; a frame that stays without a
        // tag while its job stays done (the tile could not be queued again) is written after
        // a few tries, with a warning.
        let after = patiently(&id, &say, || c.job(&id)).await?;
        let same = after.state == JobState::Done && after.finished_ms == status.finished_ms;
        if same && (tag.is_some() || untagged >= UNTAGGED_TRIES) {
            bar.finish_and_clear();
            if tag.is_none() {
                eprintln!(
                    "raytile: warning: job {}'s frame lacks stored tiles that were lost and \
                     could not be rendered again (see the coordinator's log)",
                    status.id
                );
            }
            if let Some(n) = image.dropped.filter(|&n| n > 0) {
                eprintln!("raytile: warning: {n} NaN, infinite or too large samples were dropped");
            }
            std::fs::write(out, &bytes).with_context(|| format!("writing {}", out.display()))?;
            eprintln!("wrote {}", out.display());
            break;
        }
        if same {
            untagged += 1;
            tokio::time::sleep(Duration::from_secs(1)).await;
            continue;
        }
        say(format!(
            "raytile: job {} lost stored tiles; they are rendered again",
            status.id
        ));
        untagged = 0;
        status = after;
    }
    bar.finish_and_clear();
    Ok(status)
}

/// Frames of a done job made without a tag, one second apart, before `submit` writes one.
const UNTAGGED_TRIES: u32 = 5;

#[cfg(test)]
mod tests {
    use super::*;

    /// Following a job rides out a coordinator that does not answer for a while (a restart),
    /// saying so once and again when it answers; an answer that will not change (404) ends it
    /// at once, naming the job.
    #[tokio::test]
    async fn following_a_job_asks_again_while_the_coordinator_is_away() {
        let said = std::sync::Mutex::new(Vec::<String>::new());
        let say = |m: String| said.lock().unwrap().push(m);
        let mut calls = 0;
        let got = patiently("job-1", &say, || {
            calls += 1;
            let n = calls;
            async move {
                match n {
                    1 => Err(ClientError::Unreachable {
                        base: "http://127.0.0.1:9".into(),
                        message: "connection refused".into(),
                    }),
                    2 => Err(ClientError::Status {
                        status: reqwest::StatusCode::BAD_GATEWAY,
                        code: None,
                        field: None,
                        message: "no upstream".into(),
                    }),
                    _ => Ok(7),
                }
            }
        })
        .await
        .unwrap();
        assert_eq!((got, calls), (7, 3));
        let said = said.lock().unwrap().clone();
        assert_eq!(said.len(), 2, "{said:?}");
        assert!(said[0].contains("connection refused") && said[0].contains("job-1"));
        assert!(said[1].contains("answers again"));

        let e = patiently("job-2", &|_| {}, || async {
            Err::<(), _>(ClientError::Status {
                status: reqwest::StatusCode::NOT_FOUND,
                code: Some("not_found".into()),
                field: None,
                message: "no job job-2".into(),
            })
        })
        .await
        .unwrap_err();
        assert!(format!("{e:#}").contains("following job job-2"), "{e:#}");
        // A certificate the client does not trust is not the network: no asking again.
        assert!(!transient(&ClientError::Unreachable {
            base: "https://farm".into(),
            message: "client error (Connect): invalid peer certificate: UnknownIssuer".into(),
        }));
    }

    /// An upload or a submission the coordinator answers 503 (it could not write its store:
    /// nothing changed) is made again until it is taken; any other error ends it at once.
    #[tokio::test]
    async fn uploads_and_submissions_wait_out_a_coordinator_that_cannot_write() {
        let status = |status, code: Option<&str>| ClientError::Status {
            status,
            code: code.map(String::from),
            field: None,
            message: "retry later".into(),
        };
        let busy = reqwest::StatusCode::SERVICE_UNAVAILABLE;
        let mut calls = 0;
        let got = while_busy("uploading the scene", || {
            calls += 1;
            let n = calls;
            async move {
                match n {
                    1 | 2 => Err(status(busy, Some("store_unavailable")).into()),
                    _ => Ok(7),
                }
            }
        })
        .await
        .unwrap();
        assert_eq!((got, calls), (7, 3));
        // A 500, and a 503 that is not the coordinator's (a proxy's, which may have passed
        // the job on): not asked again.
        for (code, body) in [
            (reqwest::StatusCode::INTERNAL_SERVER_ERROR, Some("internal")),
            (busy, None),
        ] {
            let mut calls = 0;
            let e = while_busy("submitting the job", || {
                calls += 1;
                async move { Err::<(), _>(status(code, body).into()) }
            })
            .await
            .unwrap_err();
            assert_eq!(calls, 1, "{e:#}");
        }
    }

    /// A coordinator in this process, with uploads limited to `max_upload` bytes.
    async fn coordinator(
        dir: &Path,
        max_upload: u64,
    ) -> (Client, tokio::sync::watch::Sender<bool>) {
        let mut cfg = raytile_coordinator::Config::new(dir);
        cfg.limits.max_upload_bytes = max_upload;
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
        let base = format!("http://{}", listener.local_addr().unwrap());
        let (stop, mut rx) = tokio::sync::watch::channel(false);
        tokio::spawn(raytile_coordinator::run(listener, cfg, async move {
            let _ = rx.wait_for(|v| *v).await;
        }));
        (Client::new(&base, None).unwrap(), stop)
    }

    /// A glTF triangle whose buffer file (`pad` bytes after the 36 it uses) is beside it.
    fn gltf_folder(dir: &Path, pad: usize) -> PathBuf {
        let mut bin: Vec<u8> = [0.0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        bin.resize(36 + pad, 0);
        std::fs::write(dir.join("tri.bin"), &bin).unwrap();
        std::fs::write(dir.join("unused.bin"), vec![1u8; 4096]).unwrap();
        let gltf = format!(
            r#"{{"asset": {{"version": "2.0"}},
                "buffers": [{{"byteLength": {}, "uri": "tri.bin"}}],
                "bufferViews": [{{"buffer": 0, "byteLength": 36}}],
                "accessors": [{{"bufferView": 0, "componentType": 5126, "type": "VEC3", "count": 3,
                                "min": [0, 0, 0], "max": [1, 1, 0]}}],
                "meshes": [{{"primitives": [{{"attributes": {{"POSITION": 0}}}}]}}],
                "nodes": [{{"mesh": 0}}], "scenes": [{{"nodes": [0]}}]}}"#,
            bin.len()
        );
        std::fs::write(dir.join("tri.gltf"), gltf).unwrap();
        dir.join("tri.gltf")
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn uploads_say_their_length_so_one_over_the_limit_is_refused_at_once() {
        let t = tempfile::tempdir().unwrap();
        let scene_dir = t.path().join("scene");
        std::fs::create_dir(&scene_dir).unwrap();
        let (c, stop) = coordinator(&t.path().join("data"), 64 << 10).await;
        // Within the limit: the scene and its buffer, not the file beside them.
        let scene = gltf_folder(&scene_dir, 1000);
        let pack = ScenePack::check(&scene).unwrap();
        let names: Vec<&str> = pack.files.iter().map(|f| f.name.as_str()).collect();
        assert_eq!(names, ["tri.gltf", "tri.bin"]);
        let created = pack.upload(&c).await.unwrap();
        assert_eq!(created.entry, "tri.gltf");
        assert_eq!(created.format, "tar");
        // The same files again: the same bytes, the same scene.
        assert!(pack.upload(&c).await.unwrap().existed);
        // Over it, archive or single file: refused from its length. The client sees the 413,
        // or only the connection closed under it, and then says what that means.
        let scene = gltf_folder(&scene_dir, 1 << 20);
        let big = scene_dir.join("big.json");
        std::fs::write(&big, format!("{{\"objects\": []{}}}", " ".repeat(1 << 20))).unwrap();
        for scene in [scene, big] {
            let e = ScenePack::check(&scene)
                .unwrap()
                .upload(&c)
                .await
                .unwrap_err();
            let status = e
                .downcast_ref::<ClientError>()
                .and_then(ClientError::status);
            let said = format!("{e:#}");
            assert!(
                status == Some(reqwest::StatusCode::PAYLOAD_TOO_LARGE)
                    || said.contains("MiB were sent: an upload over its limit"),
                "{said}"
            );
        }
        let _ = stop.send(true);
    }

    #[test]
    fn an_environment_map_is_packed_with_the_scene() {
        let t = tempfile::tempdir().unwrap();
        let scene_dir = t.path().join("scene");
        std::fs::create_dir_all(scene_dir.join("maps")).unwrap();
        let scene = gltf_folder(&scene_dir, 0);
        std::fs::write(scene_dir.join("maps/sky.hdr"), b"inside").unwrap();
        std::fs::write(t.path().join("studio.hdr"), b"outside").unwrap();
        let mut pack = ScenePack::check(&scene).unwrap();
        // Inside the scene's folder: its own path there; outside: environment/NAME.
        assert_eq!(
            pack.add_environment(&scene_dir.join("maps/sky.hdr"))
                .unwrap(),
            "maps/sky.hdr"
        );
        assert_eq!(
            pack.add_environment(&t.path().join("studio.hdr")).unwrap(),
            "environment/studio.hdr"
        );
        // The same map twice is packed once.
        pack.add_environment(&t.path().join("studio.hdr")).unwrap();
        let names: Vec<&str> = pack.files.iter().map(|f| f.name.as_str()).collect();
        assert_eq!(
            names,
            [
                "tri.gltf",
                "tri.bin",
                "maps/sky.hdr",
                "environment/studio.hdr"
            ]
        );
        // Another file of the same name, or no file at all: refused, saying which.
        let other = t.path().join("other");
        std::fs::create_dir(&other).unwrap();
        std::fs::write(other.join("studio.hdr"), b"other").unwrap();
        let e = pack.add_environment(&other.join("studio.hdr")).unwrap_err();
        assert!(e.to_string().contains("already uses"), "{e}");
        let e = pack
            .add_environment(&t.path().join("none.hdr"))
            .unwrap_err();
        assert!(format!("{e:#}").contains("none.hdr"), "{e:#}");
    }
}
