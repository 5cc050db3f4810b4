//! The scene files a worker keeps on disk (`--cache-dir`), by scene id: `ID/blob` (the
//! package as downloaded, whose sha256 the coordinator gives with every lease), `ID/root/`
//! (the package unpacked) and `ID/ok` (the sha256 and path of every unpacked file).
//!
//! Several worker processes may share one cache directory. A scene is unpacked into a folder
//! of the process's own and moved into place with one rename; when another process got there
//! first, its folder is used and this one's dropped. A folder whose files no longer match
//! what was recorded (bit rot, an edit, an unpack that did not finish) is moved aside, then
//! removed, and the scene fetched again: the files a frame is rendered from are always the
//! package's.

use anyhow::Context;
use raytile_proto::scene as pkg;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// A name no other process or call uses, beside `dir`: `dir` with `what`, the process id and
/// a counter as its extension.
fn own_name(dir: &Path, what: &str) -> PathBuf {
    static NEXT: AtomicU64 = AtomicU64::new(0);
    let n = NEXT.fetch_add(1, Ordering::Relaxed);
    dir.with_extension(format!("{what}-{}-{n}", std::process::id()))
}

/// The manifest of the files under `root`: one line per file, `SHA256 PATH` (the path relative
/// to `root`, with `/`), sorted by path.
fn manifest(root: &Path) -> std::io::Result<String> {
    let mut lines = Vec::new();
    let mut folders = vec![PathBuf::new()];
    while let Some(rel) = folders.pop() {
        for e in std::fs::read_dir(root.join(&rel))? {
            let e = e?;
            let path = rel.join(e.file_name());
            let kind = e.file_type()?;
            if kind.is_dir() {
                folders.push(path);
            } else {
                let shown = path.to_string_lossy().replace('\\', "/");
                lines.push(format!("{} {shown}", pkg::sha256_file(&root.join(&path))?));
            }
        }
    }
    lines.sort_by(|a, b| a[65..].cmp(&b[65..]));
    Ok(lines.iter().map(|l| format!("{l}\n")).collect())
}

/// Whether the scene folder `dir` is complete and its files are what was recorded: the blob's
/// sha256 is `sha256`, and the unpacked files are those of the manifest, to the byte.
pub fn verify(dir: &Path, sha256: &str) -> bool {
    let Ok(recorded) = std::fs::read_to_string(dir.join("ok")) else {
        return false;
    };
    // A folder from a version that recorded no manifest is fetched again once.
    !recorded.is_empty()
        && pkg::sha256_file(&dir.join("blob")).is_ok_and(|s| s == sha256)
        && manifest(&dir.join("root")).is_ok_and(|m| m == recorded)
}

/// Checks at start that the cache folder `cache` can be written (a read-only one would fail
/// every task the worker takes, and with them the jobs), and removes the folders that workers
/// left half unpacked or half removed there (a kill in the middle). Several workers may share
/// the folder, on this host or (a network file system, containers) on others: only a folder
/// of this naming, untouched for a day, whose process is not running here (Linux, where
/// `/proc` tells) goes.
pub fn prepare_cache(cache: &Path) -> anyhow::Result<()> {
    std::fs::create_dir_all(cache).with_context(|| format!("creating {}", cache.display()))?;
    // Unique among workers sharing the folder (in containers every one may be process 1).
    let probe = own_name(&cache.join(".write-check"), &format!("{:x}", nanos()));
    std::fs::write(&probe, b"")
        .and_then(|()| std::fs::remove_file(&probe))
        .with_context(|| {
            format!(
                "the cache folder {} cannot be written (the worker keeps there the scenes it \
                 renders: give it one it may write, --cache-dir)",
                cache.display()
            )
        })?;
    if !(cfg!(target_os = "linux") && Path::new("/proc/self").exists()) {
        return Ok(());
    }
    let day = std::time::Duration::from_secs(24 * 3600);
    for e in std::fs::read_dir(cache).into_iter().flatten().flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        let Some(pid) = left_by(&name) else { continue };
        let old = e
            .metadata()
            .and_then(|m| m.modified())
            .is_ok_and(|t| t.elapsed().is_ok_and(|age| age > day));
        let running =
            pid == std::process::id() || Path::new("/proc").join(pid.to_string()).exists();
        if old && !running {
            tracing::info!(path = %e.path().display(), "removing a folder a stopped worker left");
            let _ = std::fs::remove_dir_all(e.path());
        }
    }
    Ok(())
}

/// The process that named a folder `SCENE.partial-PID-N` or `SCENE.discarded-PID-N`
/// ([`own_name`]), where `SCENE` is a scene id.
fn left_by(name: &str) -> Option<u32> {
    let (scene, rest) = name.split_once('.')?;
    let rest = rest
        .strip_prefix("partial-")
        .or_else(|| rest.strip_prefix("discarded-"))?;
    let (pid, n) = rest.split_once('-')?;
    let digits = |s: &str| !s.is_empty() && s.bytes().all(|b| b.is_ascii_digit());
    (pkg::is_scene_id(scene) && digits(n)).then(|| pid.parse().ok())?
}

/// Nanoseconds of the system clock, to tell names apart.
fn nanos() -> u128 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos())
}

/// Moves `dir` aside (one rename, so no process sees it half removed) and removes it. Nothing
/// happens when it does not exist.
pub fn discard(dir: &Path) {
    let aside = own_name(dir, "discarded");
    if std::fs::rename(dir, &aside).is_ok() {
        let _ = std::fs::remove_dir_all(&aside);
    }
}

/// Unpacks the package `bytes` (already checked against its sha256) into the scene folder
/// `dir`: into a folder of this call's own first, then moved into place. When another process
/// put a complete folder there meanwhile, that one stays.
pub fn install(
    dir: &Path,
    bytes: &[u8],
    format: pkg::SceneFormat,
    entry: &str,
) -> anyhow::Result<()> {
    let tmp = own_name(dir, "partial");
    let result = (|| -> anyhow::Result<()> {
        std::fs::create_dir_all(tmp.join("root"))
            .with_context(|| format!("creating {}", tmp.display()))?;
        std::fs::write(tmp.join("blob"), bytes)
            .with_context(|| format!("writing the scene to {}", tmp.display()))?;
        let entry = format.is_archive().then_some(entry);
        pkg::unpack(
            &tmp.join("blob"),
            format,
            entry,
            &tmp.join("root"),
            pkg::UnpackLimits::default(),
        )?;
        std::fs::write(tmp.join("ok"), manifest(&tmp.join("root"))?)?;
        Ok(())
    })();
    if let Err(e) = result {
        let _ = std::fs::remove_dir_all(&tmp);
        return Err(e);
    }
    match std::fs::rename(&tmp, dir) {
        Ok(()) => Ok(()),
        // Another process installed it first (a rename onto a folder that is not empty fails).
        Err(_) if dir.join("ok").exists() => {
            let _ = std::fs::remove_dir_all(&tmp);
            Ok(())
        }
        Err(e) => {
            let _ = std::fs::remove_dir_all(&tmp);
            Err(e).with_context(|| format!("moving the scene into {}", dir.display()))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn json_scene() -> (Vec<u8>, String) {
        let bytes = br#"{"objects": []}"#.to_vec();
        let sha = pkg::sha256_hex(&bytes);
        (bytes, sha)
    }

    #[test]
    fn a_folder_is_used_only_while_its_files_are_what_was_unpacked() {
        let cache = tempfile::tempdir().unwrap();
        let (bytes, sha) = json_scene();
        let dir = cache.path().join(&sha);
        assert!(!verify(&dir, &sha));
        install(&dir, &bytes, pkg::SceneFormat::Json, "scene.json").unwrap();
        assert!(verify(&dir, &sha));
        assert!(!verify(&dir, &"0".repeat(64)), "another scene's id");
        // An unpacked file edited (or rotted): the folder is not used.
        let file = std::fs::read_dir(dir.join("root"))
            .unwrap()
            .next()
            .unwrap()
            .unwrap();
        std::fs::write(file.path(), b"{\"objects\": [], \"x\": 1}").unwrap();
        assert!(!verify(&dir, &sha));
        discard(&dir);
        assert!(!dir.exists());
        // A folder from a version that wrote no manifest.
        install(&dir, &bytes, pkg::SceneFormat::Json, "scene.json").unwrap();
        std::fs::write(dir.join("ok"), b"").unwrap();
        assert!(!verify(&dir, &sha));
    }

    /// The cache is checked writable at start, and what stopped workers left half done there
    /// goes; what a running one (this process) has in hand stays.
    #[test]
    fn a_cache_is_checked_and_tidied_at_start() {
        let cache = tempfile::tempdir().unwrap();
        let (bytes, sha) = json_scene();
        let dir = cache.path().join(&sha);
        install(&dir, &bytes, pkg::SceneFormat::Json, "scene.json").unwrap();
        // A pid no process has (above Linux's largest), a day old: it goes; a day old but of
        // this process, or new, or not named as a worker names them: they stay.
        let stale = cache.path().join(format!("{sha}.partial-4294967295-0"));
        let fresh = cache.path().join(format!("{sha}.discarded-4294967295-1"));
        let mine = own_name(&dir, "partial");
        let other = cache.path().join("notes.partial-4294967295-0");
        let day_ago = std::time::SystemTime::now() - std::time::Duration::from_secs(25 * 3600);
        for d in [&stale, &fresh, &mine, &other] {
            std::fs::create_dir_all(d.join("root")).unwrap();
            if *d != fresh {
                std::fs::File::open(d)
                    .unwrap()
                    .set_modified(day_ago)
                    .unwrap();
            }
        }
        prepare_cache(cache.path()).unwrap();
        assert!(verify(&dir, &sha), "the installed scene stays");
        assert!(mine.exists() && fresh.exists() && other.exists());
        assert_eq!(!stale.exists(), cfg!(target_os = "linux"));
        assert_eq!(left_by(&format!("{sha}.partial-12-3")), Some(12));
        assert_eq!(left_by(&format!("{sha}.partial-12-")), None);
        // A cache folder that is a file cannot be written.
        let file = cache.path().join("a-file");
        std::fs::write(&file, b"").unwrap();
        let e = prepare_cache(&file).unwrap_err();
        assert!(
            format!("{e:#}").contains(&file.display().to_string()),
            "{e:#}"
        );
    }

    #[test]
    fn processes_sharing_a_cache_install_a_scene_once_without_failing() {
        let cache = tempfile::tempdir().unwrap();
        let (bytes, sha) = json_scene();
        let dir = cache.path().join(&sha);
        std::thread::scope(|s| {
            for _ in 0..8 {
                s.spawn(|| install(&dir, &bytes, pkg::SceneFormat::Json, "scene.json").unwrap());
            }
        });
        assert!(verify(&dir, &sha));
        let left: Vec<_> = std::fs::read_dir(cache.path())
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(
            left,
            [std::ffi::OsString::from(&sha)],
            "no partial folder left"
        );
    }
}
