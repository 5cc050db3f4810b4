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
//!
//! A scene not yet cached is fetched and unpacked by one process sharing the folder at a time:
//! each takes the scene's install lock (an exclusive `flock` on `ID.installing`, [`Installing`])
//! first, and a process that waited for it finds the scene installed and uses it, rather than
//! downloading and unpacking a copy of its own beside the others (a small shared disk filled
//! up so). A process that waited [`INSTALL_WAIT`] goes on without the lock.
//!
//! The cache is bounded (`--cache-max-mb`): after a scene is installed, the scenes used least
//! recently go until the folder holds no more than the bound ([`trim`]). A scene's last use is
//! the modification time of its `ok` file, set whenever a build reads it ([`mark_used`]), so
//! processes sharing the folder see each other's uses. A process reading a scene's files holds
//! a shared lock on its `ok` file ([`InUse`]); a scene is removed only under an exclusive one,
//! so never while any process sharing the folder reads it. The scene just installed stays
//! however large, and so does a scene used in the last [`IN_USE`] (on a file system that
//! cannot lock, where that age is the only sign of a use).

use anyhow::Context;
use raytile_proto::scene as pkg;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, SystemTime};

/// The disk cache's default bound (`--cache-max-mb`): 20 GiB.
pub const DEFAULT_CACHE_MAX_BYTES: u64 = 20 << 30;

/// A scene used this recently is not removed to make room where locks tell nothing (off
/// Unix, or a file system that cannot lock): there the age of the last use is the only sign
/// of one, and a build may read the files for minutes.
pub const IN_USE: Duration = Duration::from_secs(15 * 60);

/// A scene used this recently is not removed where locks work: the gap between a process's
/// install of a scene and its lock on it (and a network file system's attribute cache).
pub const LOCKED_GRACE: Duration = Duration::from_secs(2 * 60);

/// Longest wait for another process's install of a scene (its download may be large and
/// slow); after it a process fetches the scene itself, as without the lock.
pub const INSTALL_WAIT: Duration = Duration::from_secs(15 * 60);

/// Set once a lock was refused as unsupported (the file system cannot lock): the age rule
/// ([`IN_USE`]) alone then spares scenes.
static NO_LOCKS: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(!cfg!(unix));

/// How recently used a scene must be not to be removed: see [`IN_USE`] and [`LOCKED_GRACE`].
fn grace() -> Duration {
    if NO_LOCKS.load(Ordering::Relaxed) {
        IN_USE
    } else {
        LOCKED_GRACE
    }
}

/// A lock on a scene folder's `ok` file, `flock` shared (a reader) or exclusive (a remover),
/// released when dropped. Where the file system cannot lock, the lock is taken as had.
pub struct InUse(#[allow(dead_code)] std::fs::File);

/// What a `flock` without waiting did.
#[cfg(unix)]
enum Flock {
    /// The lock is held.
    Held,
    /// Another open file holds a lock that excludes it.
    Busy,
    /// The file system cannot lock ([`NO_LOCKS`] is set from now on).
    Unsupported,
    /// Another error.
    Failed,
}

/// `flock(how | LOCK_NB)` on `f` (`how` is `LOCK_SH` or `LOCK_EX`).
#[cfg(unix)]
fn flock_nb(f: &std::fs::File, how: i32) -> Flock {
    use std::os::fd::AsRawFd;
    // SAFETY: a valid open descriptor.
    if unsafe { libc::flock(f.as_raw_fd(), how | libc::LOCK_NB) } == 0 {
        return Flock::Held;
    }
    let e = std::io::Error::last_os_error();
    if matches!(
        e.raw_os_error(),
        Some(libc::ENOLCK | libc::EOPNOTSUPP | libc::ENOSYS)
    ) {
        NO_LOCKS.store(true, Ordering::Relaxed);
        Flock::Unsupported
    } else if e.kind() == std::io::ErrorKind::WouldBlock {
        Flock::Busy
    } else {
        Flock::Failed
    }
}

/// Whether the open file `f` is still the file at `path` (same device and inode).
#[cfg(unix)]
fn still_at(f: &std::fs::File, path: &Path) -> bool {
    use std::os::unix::fs::MetadataExt;
    match (f.metadata(), std::fs::metadata(path)) {
        (Ok(a), Ok(b)) => a.dev() == b.dev() && a.ino() == b.ino(),
        _ => false,
    }
}

/// Takes a lock on `dir`'s `ok` file without waiting: `None` when the file is missing, was
/// replaced meanwhile, or another process holds a lock that excludes this one (or, for the
/// exclusive lock a removal takes, when locking failed for any other reason).
fn lock(dir: &Path, exclusive: bool) -> Option<InUse> {
    let path = dir.join("ok");
    // Written for the exclusive lock: over NFS, flock is a byte-range lock, and an exclusive
    // one needs a file open for writing.
    let f = std::fs::File::options()
        .read(true)
        .write(exclusive)
        .open(&path)
        .ok()?;
    #[cfg(unix)]
    {
        let how = if exclusive {
            libc::LOCK_EX
        } else {
            libc::LOCK_SH
        };
        match flock_nb(&f, how) {
            // The age rule alone spares scenes from now on.
            Flock::Held | Flock::Unsupported => {}
            Flock::Busy => return None,
            Flock::Failed if exclusive => return None,
            Flock::Failed => {}
        }
        // The file locked must still be the folder's: a removal may have moved the folder
        // aside, and an install put a new one in its place, between the open and the lock.
        if !still_at(&f, &path) {
            return None;
        }
    }
    Some(InUse(f))
}

/// The install lock of scene folder `dir` (see the module's documentation), released when
/// dropped or when its process ends. Holds no file where locks do not work.
pub struct Installing(#[allow(dead_code)] Option<std::fs::File>);

/// The lock file of scene folder `dir`'s install, beside it.
fn install_lock_path(dir: &Path) -> PathBuf {
    dir.with_extension("installing")
}

/// Takes the install lock of scene folder `dir` without waiting: `None` while another process
/// holds it. Where the lock cannot be had at all (no locks on this file system, or its file
/// cannot be made), a guard of nothing: the install goes ahead as without the lock.
pub fn try_install_lock(dir: &Path) -> Option<Installing> {
    #[cfg(unix)]
    {
        if NO_LOCKS.load(Ordering::Relaxed) {
            return Some(Installing(None));
        }
        let path = install_lock_path(dir);
        let f = match std::fs::File::options()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .open(&path)
        {
            Ok(f) => f,
            Err(e) => {
                static SAID: std::sync::atomic::AtomicBool =
                    std::sync::atomic::AtomicBool::new(false);
                if !SAID.swap(true, Ordering::Relaxed) {
                    tracing::warn!(path = %path.display(), "cannot make a scene's install lock ({e}): workers sharing the cache may fetch a scene each");
                }
                return Some(Installing(None));
            }
        };
        match flock_nb(&f, libc::LOCK_EX) {
            Flock::Held => {}
            Flock::Busy => return None,
            Flock::Unsupported | Flock::Failed => return Some(Installing(None)),
        }
        // Still the file at that path (a removal of the scene may have taken it meanwhile):
        // otherwise the caller tries again, and opens the one there now.
        still_at(&f, &path).then_some(Installing(Some(f)))
    }
    #[cfg(not(unix))]
    {
        let _ = dir;
        Some(Installing(None))
    }
}

/// Removes the install lock's file of scene folder `dir`, unless a process holds the lock (a
/// process waiting for it then locks a new file: it would only lose the lock's effect, not
/// its files, as installs are atomic anyway).
fn forget_install_lock(dir: &Path) {
    if let Some(Installing(Some(_held))) = try_install_lock(dir) {
        let _ = std::fs::remove_file(install_lock_path(dir));
    }
}

/// Marks the scene folder `dir` used now and holds it in use (a shared lock) until the guard
/// is dropped: [`trim`] in any process sharing the folder leaves it alone meanwhile. `None`
/// when the folder is incomplete or being removed.
pub fn hold(dir: &Path) -> Option<InUse> {
    mark_used(dir);
    lock(dir, false)
}

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
        // The install lock of a scene that is not here (its fetch failed, or it was
        // discarded), unless a process is installing it.
        if let Some(scene) = name.strip_suffix(".installing") {
            if pkg::is_scene_id(scene) && !cache.join(scene).exists() {
                forget_install_lock(&cache.join(scene));
            }
            continue;
        }
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

/// Sets the modification time of `path` to the file system's "now": `futimens(UTIME_NOW)`,
/// which any user who may write the file may do (an explicit time needs its owner) and which
/// takes the server's clock on a network file system.
fn touch(path: &Path) -> std::io::Result<()> {
    let f = std::fs::File::options().write(true).open(path)?;
    #[cfg(unix)]
    {
        use std::os::fd::AsRawFd;
        let now = libc::timespec {
            tv_sec: 0,
            tv_nsec: libc::UTIME_NOW,
        };
        // SAFETY: a valid open descriptor and two initialised timespecs.
        if unsafe { libc::futimens(f.as_raw_fd(), [now, now].as_ptr()) } != 0 {
            return Err(std::io::Error::last_os_error());
        }
        Ok(())
    }
    #[cfg(not(unix))]
    f.set_modified(SystemTime::now())
}

/// Records that the scene folder `dir` is being used now (its `ok` file's modification time),
/// for [`trim`]'s order and its sparing of scenes in use. Best effort: a folder that cannot be
/// touched is only removed sooner.
pub fn mark_used(dir: &Path) {
    let _ = touch(&dir.join("ok"));
}

/// The cache folder's clock: the modification time of a file touched in it now (on a network
/// file system the server's, which the scenes' use times come from too), or this host's.
fn cache_now(cache: &Path) -> SystemTime {
    let clock = cache.join(".clock");
    let _ = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(&clock);
    touch(&clock)
        .and_then(|()| std::fs::metadata(&clock)?.modified())
        .unwrap_or_else(|_| SystemTime::now())
}

/// When the scene folder `dir` was last used: its `ok` file's modification time, else the
/// folder's, else long ago.
fn last_use(dir: &Path) -> SystemTime {
    std::fs::metadata(dir.join("ok"))
        .or_else(|_| std::fs::metadata(dir))
        .and_then(|m| m.modified())
        .unwrap_or(SystemTime::UNIX_EPOCH)
}

/// A scene folder of the cache: its bytes on disk and when it was last used.
struct Held {
    dir: PathBuf,
    bytes: u64,
    used: SystemTime,
}

/// The bytes of the files under `path` (a file's own length when it is one; symbolic links are
/// not followed, and a file of several names, as a single-file scene's package and its
/// unpacked copy are, counts once).
fn tree_bytes(path: &Path) -> u64 {
    let mut total = 0;
    let mut seen = std::collections::HashSet::new();
    let mut todo = vec![path.to_path_buf()];
    while let Some(p) = todo.pop() {
        let Ok(meta) = std::fs::symlink_metadata(&p) else {
            continue;
        };
        if meta.is_dir() {
            todo.extend(
                std::fs::read_dir(&p)
                    .into_iter()
                    .flatten()
                    .flatten()
                    .map(|e| e.path()),
            );
            continue;
        }
        #[cfg(unix)]
        {
            use std::os::unix::fs::MetadataExt;
            if meta.nlink() > 1 && !seen.insert((meta.dev(), meta.ino())) {
                continue;
            }
        }
        #[cfg(not(unix))]
        let _ = &mut seen;
        total += meta.len();
    }
    total
}

/// The scene folders in `cache` (named by a scene id), each with its size and last use.
fn held(cache: &Path) -> Vec<Held> {
    let mut out = Vec::new();
    for e in std::fs::read_dir(cache).into_iter().flatten().flatten() {
        let name = e.file_name();
        let is_scene = name.to_str().is_some_and(pkg::is_scene_id);
        if !is_scene || !e.file_type().is_ok_and(|t| t.is_dir()) {
            continue;
        }
        let dir = e.path();
        // A folder a worker made holds its package; anything else of such a name is not ours.
        if !dir.join("blob").is_file() {
            continue;
        }
        let used = last_use(&dir);
        out.push(Held {
            bytes: tree_bytes(&dir),
            dir,
            used,
        });
    }
    out
}

/// What [`trim`] did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Trimmed {
    /// Scene folders removed.
    pub removed: usize,
    /// Their bytes.
    pub freed: u64,
    /// The bytes the scene folders hold after it.
    pub held: u64,
}

/// Removes the least recently used scenes from `cache` until its scene folders hold at most
/// `max_bytes`, sparing `keep` (the scene just installed), scenes a process reads ([`InUse`])
/// and scenes used within [`IN_USE`]: the bound may be exceeded while those alone exceed it.
pub fn trim(cache: &Path, max_bytes: u64, keep: Option<&Path>) -> Trimmed {
    let mut scenes = held(cache);
    scenes.sort_by_key(|h| h.used);
    let mut out = Trimmed {
        held: scenes.iter().map(|h| h.bytes).sum(),
        ..Trimmed::default()
    };
    let now = cache_now(cache);
    let grace = grace();
    let recent = |used: SystemTime| now.duration_since(used).map_or(true, |age| age < grace);
    for h in scenes {
        if out.held <= max_bytes {
            break;
        }
        // Looked at again just before: another process may have begun to use it since the
        // list was made (removing scenes can take a while).
        if recent(h.used) || keep == Some(h.dir.as_path()) || recent(last_use(&h.dir)) {
            continue;
        }
        // Not while a process reads it: moved aside under the lock (a folder without its `ok`
        // file, an unpack that did not finish, nobody can read), removed after it.
        let removing = lock(&h.dir, true);
        if removing.is_none() && h.dir.join("ok").exists() {
            continue;
        }
        let Some(aside) = move_aside(&h.dir) else {
            continue;
        };
        drop(removing);
        tracing::info!(
            path = %h.dir.display(),
            mib = h.bytes >> 20,
            "removed the least recently used scene from the disk cache"
        );
        let _ = std::fs::remove_dir_all(&aside);
        forget_install_lock(&h.dir);
        out.removed += 1;
        out.freed += h.bytes;
        out.held -= h.bytes;
    }
    out
}

/// Whether `e` comes from a full disk (or a full quota).
pub fn disk_full(e: &anyhow::Error) -> bool {
    let full = |io: &std::io::Error| {
        matches!(
            io.kind(),
            std::io::ErrorKind::StorageFull | std::io::ErrorKind::QuotaExceeded
        )
    };
    e.chain().any(|c| {
        c.downcast_ref::<std::io::Error>().is_some_and(full)
            || matches!(c.downcast_ref::<pkg::PackageError>(), Some(pkg::PackageError::Io(io)) if full(io))
    })
}

/// Moves `dir` aside (one rename, so no process sees it half removed) and removes it. Nothing
/// happens when it does not exist.
pub fn discard(dir: &Path) {
    if let Some(aside) = move_aside(dir) {
        let _ = std::fs::remove_dir_all(&aside);
    }
}

/// Moves `dir` aside under a name of this call's own (one rename): where it went, or `None`
/// when it could not be moved (gone already).
fn move_aside(dir: &Path) -> Option<PathBuf> {
    let aside = own_name(dir, "discarded");
    std::fs::rename(dir, &aside).ok().map(|()| aside)
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
        // A single-file scene's unpacked file is its package under a second name, not a copy.
        #[cfg(unix)]
        {
            use std::os::unix::fs::MetadataExt;
            let blob = std::fs::metadata(dir.join("blob")).unwrap();
            assert_eq!(blob.nlink(), 2);
            let ok = std::fs::metadata(dir.join("ok")).unwrap().len();
            assert_eq!(tree_bytes(&dir), blob.len() + ok, "counted once");
        }
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
        // Install locks: of the scene here, of a scene not here, and of one being installed.
        let lock_here = install_lock_path(&dir);
        std::fs::write(&lock_here, b"").unwrap();
        let gone = cache.path().join("2".repeat(64));
        std::fs::write(install_lock_path(&gone), b"").unwrap();
        let coming = cache.path().join("3".repeat(64));
        let installing = try_install_lock(&coming).unwrap();
        prepare_cache(cache.path()).unwrap();
        assert!(verify(&dir, &sha), "the installed scene stays");
        assert!(mine.exists() && fresh.exists() && other.exists());
        assert_eq!(!stale.exists(), cfg!(target_os = "linux"));
        assert!(lock_here.exists() && install_lock_path(&coming).exists());
        assert_eq!(
            !install_lock_path(&gone).exists(),
            cfg!(target_os = "linux"),
            "the lock of a scene not here goes"
        );
        drop(installing);
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

    /// The least recently used scenes go first, down to the bound; the scene just installed
    /// and scenes used lately stay whatever the bound.
    #[test]
    fn the_cache_keeps_to_its_bound_least_recently_used_first() {
        let cache = tempfile::tempdir().unwrap();
        let hours_ago = |h: u64| SystemTime::now() - Duration::from_secs(h * 3600);
        let scene = |n: usize, used: SystemTime| {
            // Scenes of one size: the same length of JSON, another number.
            let bytes = format!(r#"{{"objects": [], "n": {n:04}}}"#).into_bytes();
            let dir = cache.path().join(pkg::sha256_hex(&bytes));
            install(&dir, &bytes, pkg::SceneFormat::Json, "scene.json").unwrap();
            std::fs::File::options()
                .write(true)
                .open(dir.join("ok"))
                .unwrap()
                .set_modified(used)
                .unwrap();
            dir
        };
        let (oldest, older, lately) = (
            scene(1, hours_ago(3)),
            scene(2, hours_ago(2)),
            scene(3, hours_ago(0)),
        );
        let one = tree_bytes(&oldest);
        assert!(one > 0);
        assert_eq!(
            tree_bytes(cache.path()),
            3 * one,
            "three scenes of one size"
        );
        // Room for two: the oldest goes.
        let t = trim(cache.path(), 2 * one, None);
        assert_eq!((t.removed, t.freed, t.held), (1, one, 2 * one));
        assert!(!oldest.exists() && older.exists() && lately.exists());
        // A use moves a scene to the back of the queue.
        mark_used(&older);
        let newest = scene(4, hours_ago(1));
        let t = trim(cache.path(), one, Some(&newest));
        // `newest` is kept as just installed, `older` and `lately` as used lately: over the
        // bound, nothing to remove.
        assert_eq!((t.removed, t.held), (0, 3 * one));
        let t = trim(cache.path(), 0, None);
        assert_eq!(
            (t.removed, t.held),
            (1, 2 * one),
            "only the one not used lately"
        );
        assert!(!newest.exists() && older.exists() && lately.exists());
        assert!(verify(&older, older.file_name().unwrap().to_str().unwrap()));
        // Folders that are not scenes are neither counted nor removed.
        std::fs::write(cache.path().join("notes.txt"), vec![0u8; 4 * one as usize]).unwrap();
        assert_eq!(trim(cache.path(), 0, None).held, 2 * one);
        assert!(cache.path().join("notes.txt").exists());
        // Nor a folder named like a scene without a package in it.
        let stranger = cache.path().join("0".repeat(64));
        std::fs::create_dir_all(&stranger).unwrap();
        std::fs::write(stranger.join("file"), vec![0u8; one as usize]).unwrap();
        assert_eq!(trim(cache.path(), 0, None).held, 2 * one);
        assert!(stranger.join("file").exists());
        // A scene whose unpack never finished (no `ok` file): nobody can read it; it goes.
        let unfinished = cache.path().join("1".repeat(64));
        std::fs::create_dir_all(&unfinished).unwrap();
        std::fs::write(unfinished.join("blob"), b"x").unwrap();
        std::fs::File::open(&unfinished)
            .unwrap()
            .set_modified(hours_ago(5))
            .unwrap();
        assert_eq!(trim(cache.path(), 0, None).removed, 1);
        assert!(!unfinished.exists());
        // A scene a process reads stays however old its last use; released, it goes.
        let read = scene(5, hours_ago(0));
        let guard = hold(&read).unwrap();
        std::fs::File::options()
            .write(true)
            .open(read.join("ok"))
            .unwrap()
            .set_modified(hours_ago(5))
            .unwrap();
        if cfg!(unix) {
            assert_eq!(trim(cache.path(), 0, None).removed, 0, "held");
            assert!(read.exists());
        }
        drop(guard);
        let t = trim(cache.path(), 2 * one, None);
        assert_eq!(t.removed, 1);
        assert!(!read.exists());
    }

    #[test]
    fn a_full_disk_is_told_apart_from_other_failures() {
        let full = std::io::Error::from(std::io::ErrorKind::StorageFull);
        let e = anyhow::Error::from(full).context("writing the scene");
        assert!(disk_full(&e));
        let e = anyhow::Error::from(pkg::PackageError::Io(std::io::Error::from(
            std::io::ErrorKind::QuotaExceeded,
        )))
        .context("unpacking");
        assert!(disk_full(&e));
        let e = anyhow::Error::from(std::io::Error::from(std::io::ErrorKind::PermissionDenied));
        assert!(!disk_full(&e));
        assert!(!disk_full(&anyhow::anyhow!("no space left on device")));
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

    /// Processes sharing a cache that need one scene at the same moment fetch and unpack it
    /// once: the first takes the install lock, the others wait for it and then find the scene
    /// installed (as the worker does, `scene_file`). Threads stand in for the processes: a
    /// local file system's `flock` is held by an open file, so two opens in one process
    /// exclude each other too (over NFS, where flock is a POSIX lock held by the process, they
    /// would not: a worker runs one lease at a time).
    #[cfg(unix)]
    #[test]
    fn a_scene_is_fetched_once_by_the_processes_that_need_it_at_once() {
        let cache = tempfile::tempdir().unwrap();
        let (bytes, sha) = json_scene();
        let dir = cache.path().join(&sha);
        let fetched = AtomicU64::new(0);
        std::thread::scope(|s| {
            for _ in 0..6 {
                s.spawn(|| {
                    let _installing = loop {
                        match try_install_lock(&dir) {
                            Some(l) => break l,
                            None => std::thread::sleep(Duration::from_millis(5)),
                        }
                    };
                    if !verify(&dir, &sha) {
                        fetched.fetch_add(1, Ordering::Relaxed);
                        // A download takes a while: the others queue on the lock meanwhile.
                        std::thread::sleep(Duration::from_millis(50));
                        install(&dir, &bytes, pkg::SceneFormat::Json, "scene.json").unwrap();
                    }
                });
            }
        });
        assert_eq!(fetched.into_inner(), 1);
        assert!(verify(&dir, &sha));
        // Held, the lock is refused; released, taken.
        let held = try_install_lock(&dir).unwrap();
        assert!(held.0.is_some(), "a real lock on this file system");
        assert!(try_install_lock(&dir).is_none());
        drop(held);
        assert!(try_install_lock(&dir).is_some());
        // Removing the scene removes its lock's file, unless an install holds it.
        let lock_file = install_lock_path(&dir);
        assert!(lock_file.exists());
        let unused_for_an_hour = || {
            std::fs::File::options()
                .write(true)
                .open(dir.join("ok"))
                .unwrap()
                .set_modified(SystemTime::now() - Duration::from_secs(3600))
                .unwrap()
        };
        unused_for_an_hour();
        assert_eq!(trim(cache.path(), 0, None).removed, 1);
        assert!(!dir.exists() && !lock_file.exists());
        install(&dir, &bytes, pkg::SceneFormat::Json, "scene.json").unwrap();
        let installing = try_install_lock(&dir).unwrap();
        unused_for_an_hour();
        assert_eq!(trim(cache.path(), 0, None).removed, 1);
        assert!(lock_file.exists(), "held by an install");
        drop(installing);
    }
}
