//! Scene uploads: streamed to a temporary file with a size cut-off, hashed on the way, unpacked
//! safely, parsed once (at most [`SceneLimits::max_parallel_parses`] at a time, every file the
//! scene names confined to its folder), and stored content-addressed under
//! `data/scenes/{id}/`: `blob` (the bytes as uploaded, served to workers), `root/` (unpacked)
//! and `meta.json`.

use crate::error::AppError;
use crate::AppState;
use futures_util::StreamExt;
use raytile_core::scene::desc::RenderDefaults;
use raytile_core::scene::files;
use raytile_core::scene::job::SppmFacts;
use raytile_proto::scene::{self as pkg, SceneFormat, UnpackLimits};
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Weak};
use std::time::Duration;
use tokio::io::AsyncWriteExt;

/// What the loader found out about a valid scene.
#[derive(Clone, Debug, Default)]
pub struct LoadedScene {
    /// The scene's own render settings.
    pub defaults: RenderDefaults,
    /// Non-fatal problems.
    pub warnings: Vec<String>,
    /// The names of the scene's cameras, in order (`None`: not known, a job's camera is then
    /// not checked).
    pub cameras: Option<Vec<String>>,
    /// What decides whether `sppm` can render the scene (`None`: not known, not checked).
    pub sppm: Option<SppmFacts>,
}

/// Why the loader refused a scene.
#[derive(Clone, Debug)]
pub enum LoadError {
    /// The scene is invalid (422 with this message).
    Invalid(String),
    /// The loader itself failed (500).
    Internal(String),
}

/// Parses a scene file once to validate it.
pub type SceneLoader = Arc<dyn Fn(&Path) -> Result<LoadedScene, LoadError> + Send + Sync>;

/// Bounds on checking uploaded scenes: what one parse may read and allocate, and how many run
/// at once. A parse reads the scene through the core's confined resolver: only files in the
/// scene file's own folder.
#[derive(Clone, Debug)]
pub struct SceneLimits {
    /// Largest file a scene may name (and the scene file itself), in bytes.
    pub max_file_bytes: u64,
    /// Most bytes one scene may read, all its files together.
    pub max_scene_bytes: u64,
    /// Most memory one parse may allocate for decoded data (texels, vertices, indices).
    pub max_parse_memory: u64,
    /// Most scene parses at once; further uploads wait for one to end.
    pub max_parallel_parses: usize,
    /// How long an upload waits for a parse to end before it is answered 503 (retryable).
    pub parse_wait: Duration,
}

impl Default for SceneLimits {
    fn default() -> Self {
        SceneLimits {
            max_file_bytes: files::DEFAULT_FILE_CAP,
            max_scene_bytes: files::DEFAULT_SCENE_BUDGET,
            max_parse_memory: 2 << 30,
            max_parallel_parses: 2,
            parse_wait: Duration::from_secs(30),
        }
    }
}

/// The core's loader, confined to the scene file's folder with the file and memory bounds of
/// `limits`, with panics turned into internal errors.
pub fn core_scene_loader(limits: SceneLimits) -> SceneLoader {
    Arc::new(move |path: &Path| {
        let p = path.to_path_buf();
        let limits = limits.clone();
        let load = move || -> Result<_, LoadError> {
            let files = files::SceneFiles::confined_to_scene(
                &p,
                limits.max_file_bytes,
                limits.max_scene_bytes,
            )
            .map_err(|e| LoadError::Internal(format!("scene folder: {e}")))?
            .with_memory_limit(limits.max_parse_memory);
            raytile_core::load_scene_with(&p, &files).map_err(|e| LoadError::Invalid(e.to_string()))
        };
        match std::panic::catch_unwind(load) {
            Ok(Ok(desc)) => Ok(LoadedScene {
                cameras: Some(desc.cameras.iter().map(|c| c.name.clone()).collect()),
                sppm: Some(desc.sppm_facts()),
                defaults: desc.render,
                warnings: desc.warnings,
            }),
            Ok(Err(e)) => Err(e),
            Err(_) => Err(LoadError::Internal("scene loader panicked".into())),
        }
    })
}

/// Stored facts about a scene.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct SceneMeta {
    /// Scene id.
    pub id: String,
    /// sha256 of `blob`.
    pub sha256: String,
    /// Format name.
    pub format: String,
    /// Scene file relative to `root/` (for archives, inside the archive).
    pub entry: String,
    /// The scene's own render settings.
    pub defaults: RenderDefaults,
    /// Loader warnings.
    pub warnings: Vec<String>,
    /// The names of the scene's cameras, in order; `None` for scenes stored by a coordinator
    /// that did not record them.
    #[serde(default)]
    pub cameras: Option<Vec<String>>,
    /// What decides whether `sppm` can render the scene; `None` for scenes stored by a
    /// coordinator that did not record it (a worker then refuses such a job).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sppm: Option<SppmFacts>,
}

impl SceneMeta {
    /// Checks that the scene has the camera `sel` names (by name, or by index when no camera
    /// has that name, as the renderer picks it), or that it can render without one when
    /// `sel` is `None`. The error is for a 422 naming `camera`.
    pub fn check_camera(&self, sel: Option<&str>) -> Result<(), String> {
        let (Some(cameras), Some(sel)) = (&self.cameras, sel) else {
            // No choice: the scene's first camera, or one framing the scene if it has none.
            return Ok(());
        };
        // The renderer's own choice, so that a job the coordinator takes is one a worker renders.
        raytile_core::scene::job::pick_camera(cameras, Some(sel))
            .map(drop)
            .map_err(|e| e.message)
    }
}

/// Query of `POST /v1/scenes`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct UploadQuery {
    /// Format hint: gltf, glb, json, tar, zip.
    pub format: Option<String>,
    /// Scene file inside an archive.
    pub entry: Option<String>,
}

/// The scenes being checked, by id, each with a lock its check holds (dropped when no upload
/// holds or waits for it any more).
pub type Checks = std::sync::Mutex<HashMap<String, Weak<tokio::sync::Mutex<()>>>>;

/// The lock of scene `id`'s check, shared by every upload of the same scene now.
fn check_lock(state: &AppState, id: &str) -> Arc<tokio::sync::Mutex<()>> {
    let mut checks = state.scene_checks.lock().unwrap_or_else(|p| p.into_inner());
    checks.retain(|_, w| w.strong_count() > 0);
    if let Some(lock) = checks.get(id).and_then(Weak::upgrade) {
        return lock;
    }
    let lock = Arc::new(tokio::sync::Mutex::new(()));
    checks.insert(id.to_string(), Arc::downgrade(&lock));
    lock
}

/// The answer to an upload of a scene already stored as `m`. A format the request gives
/// (`?format=`, or a `Content-Type` naming one) must be the stored one: the same request with
/// bytes not yet stored would have been read as that format, and refused.
fn stored_answer(
    m: &SceneMeta,
    hinted: Option<(SceneFormat, &'static str)>,
) -> Result<(bool, raytile_proto::SceneCreated), AppError> {
    if let Some((format, source)) = hinted.filter(|(f, _)| f.name() != m.format) {
        return Err(AppError::invalid(
            "format",
            format!(
                "these bytes are stored as a {} scene ({}), not {} as {source} says",
                m.format,
                m.id,
                format.name(),
            ),
        ));
    }
    Ok((
        false,
        raytile_proto::SceneCreated {
            id: m.id.clone(),
            format: m.format.clone(),
            entry: m.entry.clone(),
            existed: true,
            warnings: m.warnings.clone(),
        },
    ))
}

/// Folder of a stored scene.
pub fn scene_dir(state: &AppState, id: &str) -> PathBuf {
    state.cfg.data_dir.join("scenes").join(id)
}

/// Reads a stored scene's metadata (cached). `None` if the scene is unknown.
pub fn meta(state: &AppState, id: &str) -> Option<Arc<SceneMeta>> {
    if !pkg::is_scene_id(id) {
        return None;
    }
    if let Some(m) = state
        .scene_meta
        .lock()
        .unwrap_or_else(|p| p.into_inner())
        .get(id)
    {
        return Some(m.clone());
    }
    let text = std::fs::read(scene_dir(state, id).join("meta.json")).ok()?;
    let m: Arc<SceneMeta> = Arc::new(serde_json::from_slice(&text).ok()?);
    state
        .scene_meta
        .lock()
        .unwrap_or_else(|p| p.into_inner())
        .insert(id.to_string(), m.clone());
    Some(m)
}

/// Streams `body` into a temporary file, cutting off at `limit`. Returns the file, its
/// sha256 and its first bytes.
pub async fn stream_to_temp(
    body: axum::body::Body,
    tmp_dir: &Path,
    limit: u64,
) -> Result<(tempfile::NamedTempFile, String, Vec<u8>), AppError> {
    // Made again if it was removed while the coordinator ran.
    std::fs::create_dir_all(tmp_dir).map_err(AppError::disk(tmp_dir.display()))?;
    let tmp = tempfile::NamedTempFile::new_in(tmp_dir).map_err(AppError::disk(format!(
        "an upload in {}",
        tmp_dir.display()
    )))?;
    let path = tmp.path().display().to_string();
    let mut file = tokio::fs::File::from_std(tmp.reopen().map_err(AppError::disk(&path))?);
    let mut hasher = Sha256::new();
    let mut head = Vec::with_capacity(4096);
    let mut total: u64 = 0;
    let mut stream = body.into_data_stream();
    while let Some(chunk) = stream.next().await {
        let chunk = chunk.map_err(|e| AppError::bad("body", format!("reading body: {e}")))?;
        total += chunk.len() as u64;
        if total > limit {
            return Err(AppError::TooLarge(limit));
        }
        if head.len() < 4096 {
            let n = (4096 - head.len()).min(chunk.len());
            head.extend_from_slice(&chunk[..n]);
        }
        hasher.update(&chunk);
        file.write_all(&chunk)
            .await
            .map_err(AppError::disk(&path))?;
    }
    file.flush().await.map_err(AppError::disk(&path))?;
    Ok((tmp, hex::encode(hasher.finalize()), head))
}

/// Handles an upload: returns (created?, answer).
pub async fn upload(
    state: &AppState,
    q: UploadQuery,
    content_type: Option<&str>,
    content_length: Option<u64>,
    body: axum::body::Body,
) -> Result<(bool, raytile_proto::SceneCreated), AppError> {
    let limit = state.cfg.limits.max_upload_bytes;
    if content_length.is_some_and(|n| n > limit) {
        return Err(AppError::TooLarge(limit));
    }
    // The format the request gives, and where: `?format=`, else the Content-Type.
    let hinted = match q.format.as_deref() {
        Some(f) => Some((
            SceneFormat::from_name(f).ok_or_else(|| {
                AppError::invalid(
                    "format",
                    format!("unknown format '{f}' (expected gltf, glb, json, tar or zip)"),
                )
            })?,
            "?format=",
        )),
        None => content_type
            .and_then(SceneFormat::from_content_type)
            .map(|f| (f, "the Content-Type")),
    };
    let tmp_dir = state.cfg.data_dir.join("tmp");
    let (tmp, sha, head) = stream_to_temp(body, &tmp_dir, limit).await?;
    if head.is_empty() {
        return Err(AppError::invalid("body", "empty scene upload"));
    }
    let format = match hinted.map(|(f, _)| f).or_else(|| pkg::sniff(&head)) {
        Some(f) => f,
        None => {
            return Err(AppError::invalid(
                "body",
                pkg::PackageError::UnknownFormat.to_string(),
            ))
        }
    };
    let entry = q.entry.filter(|_| format.is_archive());
    let id = pkg::scene_id(&sha, entry.as_deref());
    if let Some(m) = meta(state, &id) {
        return stored_answer(&m, hinted);
    }
    let limits = &state.cfg.scene_limits;
    // One check of a scene at a time: the same bytes uploaded meanwhile wait for it and are
    // answered as stored (one 201, the others 200), without a parse of their own. Uploads of
    // other scenes do not wait for it.
    let same_scene = check_lock(state, &id);
    let _checking = match tokio::time::timeout(limits.parse_wait, same_scene.lock()).await {
        Ok(guard) => guard,
        Err(_) => {
            return Err(AppError::Busy(format!(
                "the same scene is being checked for another upload and that did not end \
                 within {} s: try again shortly",
                limits.parse_wait.as_secs_f64()
            )))
        }
    };
    if let Some(m) = meta(state, &id) {
        return stored_answer(&m, hinted);
    }
    // Parsing takes memory (decoded texels and geometry): a bounded number run at once, the
    // other uploads wait here with their bytes on disk.
    let permit =
        match tokio::time::timeout(limits.parse_wait, state.parse_slots.clone().acquire_owned())
            .await
        {
            Ok(Ok(permit)) => permit,
            Ok(Err(_)) => return Err(AppError::Unavailable),
            Err(_) => {
                return Err(AppError::Busy(format!(
                    "{} scenes are being checked and none ended within {} s: try again shortly",
                    limits.max_parallel_parses,
                    limits.parse_wait.as_secs_f64()
                )))
            }
        };
    let st = state.clone();
    let (id2, sha2) = (id.clone(), sha.clone());
    let (created, m) = tokio::task::spawn_blocking(move || {
        let _permit = permit;
        store_scene(&st, tmp, format, entry, id2, sha2)
    })
    .await
    .map_err(AppError::internal)??;
    Ok((
        created,
        raytile_proto::SceneCreated {
            id,
            format: m.format.clone(),
            entry: m.entry.clone(),
            existed: !created,
            warnings: m.warnings.clone(),
        },
    ))
}

/// A file error while unpacking an upload into `root`: the data directory's (a retryable 503)
/// unless the archive asked for what no file system gives (a name too long, a name that is
/// not one), which is the upload's fault (422, `body`).
fn unpack_io_error(e: std::io::Error, root: &Path) -> AppError {
    match e.raw_os_error() {
        Some(libc::ENAMETOOLONG | libc::EINVAL | libc::EILSEQ | libc::ELOOP) => {
            AppError::invalid("body", format!("an archive member cannot be unpacked: {e}"))
        }
        _ => AppError::disk(format!("unpacking into {}", root.display()))(e),
    }
}

/// Checks an upload and stores it as scene `id`. Returns whether this upload stored it (the
/// move into place is what decides: an identical upload may have got there first) and the
/// scene's metadata.
fn store_scene(
    state: &AppState,
    tmp: tempfile::NamedTempFile,
    format: SceneFormat,
    entry: Option<String>,
    id: String,
    sha256: String,
) -> Result<(bool, Arc<SceneMeta>), AppError> {
    let tmp_dir = state.cfg.data_dir.join("tmp");
    let stage = tempfile::Builder::new()
        .prefix("stage-")
        .tempdir_in(&tmp_dir)
        .map_err(AppError::disk(format!("a scene in {}", tmp_dir.display())))?;
    let blob = stage.path().join("blob");
    tmp.persist(&blob)
        .map_err(|e| AppError::disk(blob.display())(e.error))?;
    let root = stage.path().join("root");
    std::fs::create_dir(&root).map_err(AppError::disk(root.display()))?;
    let limits = UnpackLimits {
        max_bytes: state.cfg.limits.max_unpacked_bytes,
        ..UnpackLimits::default()
    };
    let scene_file =
        pkg::unpack(&blob, format, entry.as_deref(), &root, limits).map_err(|e| match e {
            pkg::PackageError::Io(e) => unpack_io_error(e, &root),
            // Only a missing or ambiguous scene file is about `?entry=`; the rest is the body's.
            e @ pkg::PackageError::Entry(_) if entry.is_some() => {
                AppError::invalid("entry", e.to_string())
            }
            e => AppError::invalid("body", e.to_string()),
        })?;
    let rel = scene_file
        .strip_prefix(&root)
        .unwrap_or(&scene_file)
        .to_string_lossy()
        .into_owned();
    let loaded = (state.cfg.scene_loader)(&scene_file).map_err(|e| match e {
        // The loader names files by their temporary paths (as given, and canonical for the
        // files a scene includes): show them relative to the scene's root instead.
        LoadError::Invalid(m) => {
            let mut m = m;
            for r in [Some(root.clone()), std::fs::canonicalize(&root).ok()]
                .into_iter()
                .flatten()
            {
                m = m.replace(&format!("{}/", r.to_string_lossy()), "");
            }
            AppError::invalid("scene", m)
        }
        LoadError::Internal(m) => AppError::internal(m),
    })?;
    let m = SceneMeta {
        id: id.clone(),
        sha256,
        format: format.name().into(),
        entry: rel,
        defaults: loaded.defaults,
        warnings: loaded.warnings,
        cameras: loaded.cameras,
        sppm: loaded.sppm,
    };
    let text = serde_json::to_vec_pretty(&m).map_err(AppError::internal)?;
    let meta_file = stage.path().join("meta.json");
    std::fs::write(&meta_file, text).map_err(AppError::disk(meta_file.display()))?;
    let dest = scene_dir(state, &id);
    let staged = stage.keep();
    // scenes/ is made again if it was removed while the coordinator ran.
    let stored = dest
        .parent()
        .map_or(Ok(()), std::fs::create_dir_all)
        .and_then(|()| std::fs::rename(&staged, &dest));
    if let Err(e) = stored {
        // Stored meanwhile by an identical upload: keep theirs, and answer as stored.
        let _ = std::fs::remove_dir_all(&staged);
        if let Some(theirs) = meta(state, &id) {
            return Ok((false, theirs));
        }
        // Not stored at all (scenes/ gone, a read-only disk): no scene to answer with.
        return Err(AppError::disk(dest.display())(e));
    }
    let m = Arc::new(m);
    state
        .scene_meta
        .lock()
        .unwrap_or_else(|p| p.into_inner())
        .insert(id, m.clone());
    Ok((true, m))
}

/// Checks the environment map a job names (`map`, relative to the scene file's folder): read
/// through the scene's confined resolver within `limits`, like any file of the scene, and
/// decoded once, at most [`SceneLimits::max_parallel_parses`] at a time. The error says why
/// (a missing file, a path leaving the folder, an undecodable image), for a 422 naming the
/// `environment` field. Its texels times the job's `strength` must be at most the largest
/// radiance, as a worker checks them.
pub async fn check_environment_map(
    state: &AppState,
    m: &SceneMeta,
    map: &str,
    strength: f32,
) -> Result<(), AppError> {
    let limits = state.cfg.scene_limits.clone();
    let permit =
        match tokio::time::timeout(limits.parse_wait, state.parse_slots.clone().acquire_owned())
            .await
        {
            Ok(Ok(permit)) => permit,
            Ok(Err(_)) => return Err(AppError::Unavailable),
            Err(_) => {
                return Err(AppError::Busy(format!(
                    "{} scenes are being checked and none ended within {} s: try again shortly",
                    limits.max_parallel_parses,
                    limits.parse_wait.as_secs_f64()
                )))
            }
        };
    let file = scene_dir(state, &m.id).join("root").join(&m.entry);
    let map = PathBuf::from(map);
    tokio::task::spawn_blocking(move || {
        let _permit = permit;
        let files = files::SceneFiles::confined_to_scene(
            &file,
            limits.max_file_bytes,
            limits.max_scene_bytes,
        )
        .map_err(|e| AppError::internal(format!("scene folder: {e}")))?
        .with_memory_limit(limits.max_parse_memory);
        let base = file.parent().unwrap_or(Path::new("."));
        let check =
            || raytile_core::scene::build::load_environment_map(&map, base, &files, strength, 0.0);
        match std::panic::catch_unwind(std::panic::AssertUnwindSafe(check)) {
            Ok(Ok(_)) => Ok(()),
            Ok(Err(e)) => Err(AppError::invalid(
                "environment",
                format!(
                    "{e} (a farm reads the map from the scene's folder: submit packs it there)"
                ),
            )),
            Err(_) => Err(AppError::internal("environment map check panicked")),
        }
    })
    .await
    .map_err(AppError::internal)?
}

#[cfg(test)]
mod tests {
    use super::*;
    use axum::response::IntoResponse;

    /// A member name no file system takes is the upload's fault (422); a disk that cannot take
    /// the files is the coordinator's, for a while (503, retryable).
    #[test]
    fn unpacking_errors_are_the_uploads_or_the_disks() {
        let status = |errno| {
            unpack_io_error(std::io::Error::from_raw_os_error(errno), Path::new("/d"))
                .into_response()
                .status()
        };
        assert_eq!(status(libc::ENAMETOOLONG), 422);
        assert_eq!(status(libc::EILSEQ), 422);
        assert_eq!(status(libc::ENOSPC), 503);
        assert_eq!(status(libc::EROFS), 503);
        assert_eq!(status(libc::EIO), 503);
    }
}
