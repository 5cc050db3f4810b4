//! The SQLite store under `--data-dir`: jobs, task states, workers and finished tile data.
//! A large finished tile (a `bdpt` result with its splats can be hundreds of MB) is kept as a
//! file under `results/` that its row names: it is written and synced before the scheduler's
//! lock is taken ([`Staged`]), and the transaction only moves it into place, so the lock is
//! never held while hundreds of MB go to disk.
//!
//! The scheduler writes through this module on every state change, so a restarted coordinator
//! finds every job, every finished tile and every lease that was out.
//!
//! States are typed values everywhere else; this module is the one place that names them in
//! the database ([`job_state_name`], [`StoredTask`]). The names are part of the file format:
//! changing one needs a migration.

use raytile_proto::JobState;
use rusqlite::{params, Connection, OptionalExtension};
use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// Free pages a purge, and then each tick of the lease checker, gives back (of 4 KiB: 8 MB);
/// [`Store::shrink`]. Both hold the scheduler's lock meanwhile: a step is some milliseconds.
pub const SHRINK_PAGES: u32 = 2048;

/// Schema, applied on open (idempotent). `auto_vacuum` takes effect only on a new database;
/// `journal_size_limit` truncates the write-ahead log to 64 MB at each checkpoint, where it
/// would otherwise keep the size of its largest burst of writes.
const SCHEMA: &str = "
PRAGMA auto_vacuum = INCREMENTAL;
PRAGMA journal_mode = WAL;
PRAGMA synchronous = NORMAL;
PRAGMA journal_size_limit = 67108864;
CREATE TABLE IF NOT EXISTS jobs (
    id TEXT PRIMARY KEY,
    seq INTEGER NOT NULL,
    scene TEXT NOT NULL,
    settings TEXT NOT NULL,
    priority INTEGER NOT NULL,
    state TEXT NOT NULL,
    error TEXT,
    created_ms INTEGER NOT NULL,
    started_ms INTEGER,
    finished_ms INTEGER
);
CREATE TABLE IF NOT EXISTS tasks (
    job_id TEXT NOT NULL,
    idx INTEGER NOT NULL,
    state TEXT NOT NULL,
    failures INTEGER NOT NULL DEFAULT 0,
    worker TEXT,
    lease TEXT,
    PRIMARY KEY (job_id, idx)
);
CREATE TABLE IF NOT EXISTS results (
    job_id TEXT NOT NULL,
    idx INTEGER NOT NULL,
    data BLOB NOT NULL,
    file TEXT,
    PRIMARY KEY (job_id, idx)
);
CREATE TABLE IF NOT EXISTS workers (
    id TEXT PRIMARY KEY,
    name TEXT NOT NULL,
    threads INTEGER NOT NULL,
    registered_ms INTEGER NOT NULL
);
CREATE TABLE IF NOT EXISTS meta (
    key TEXT PRIMARY KEY,
    value TEXT NOT NULL
);
CREATE TABLE IF NOT EXISTS blocked (
    job_id TEXT NOT NULL,
    worker TEXT NOT NULL,
    failures INTEGER NOT NULL,
    PRIMARY KEY (job_id, worker)
);
";

/// A row of the `jobs` table.
#[derive(Clone, Debug)]
pub struct JobRow {
    /// Job id.
    pub id: String,
    /// Submission order.
    pub seq: u64,
    /// Scene id.
    pub scene: String,
    /// RenderSettings as JSON.
    pub settings: String,
    /// Priority.
    pub priority: i32,
    /// State.
    pub state: JobState,
    /// Failure message.
    pub error: Option<String>,
    /// Submission time.
    pub created_ms: u64,
    /// First lease.
    pub started_ms: Option<u64>,
    /// End time.
    pub finished_ms: Option<u64>,
    /// The renderer version ([`raytile_core::RENDER_VERSION`]) that made every stored tile
    /// of the job, where known: `None` for a job finished before a release that recorded it.
    /// Only a job whose tiles the current renderer made can have a lost tile rendered again.
    pub render_version: Option<u32>,
}

/// A task's state as stored: the scheduler's state less the lease deadline, which lives in
/// memory only (after a restart every lease gets the grace period).
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum StoredTask {
    /// Waiting for a worker.
    Queued,
    /// Out with `worker` under `lease`.
    Leased {
        /// Worker id.
        worker: String,
        /// Lease id.
        lease: String,
    },
    /// Result stored, delivered by `worker`.
    Done {
        /// Worker id.
        worker: String,
    },
    /// Failed too often.
    Failed,
}

/// Task state names in the `tasks` table.
const TASK_QUEUED: &str = "queued";
const TASK_LEASED: &str = "leased";
const TASK_DONE: &str = "done";
const TASK_FAILED: &str = "failed";

impl StoredTask {
    /// The `state`, `worker` and `lease` columns.
    fn columns(&self) -> (&'static str, Option<&str>, Option<&str>) {
        match self {
            StoredTask::Queued => (TASK_QUEUED, None, None),
            StoredTask::Leased { worker, lease } => (TASK_LEASED, Some(worker), Some(lease)),
            StoredTask::Done { worker } => (TASK_DONE, Some(worker), None),
            StoredTask::Failed => (TASK_FAILED, None, None),
        }
    }

    /// From the `state`, `worker` and `lease` columns. What cannot be resumed (an unknown
    /// state, a lease without its worker or id) is queued again: rendering a task twice costs
    /// time, never bits.
    fn from_columns(state: &str, worker: Option<String>, lease: Option<String>) -> StoredTask {
        match (state, worker, lease) {
            (TASK_DONE, worker, _) => StoredTask::Done {
                worker: worker.unwrap_or_default(),
            },
            (TASK_FAILED, ..) => StoredTask::Failed,
            (TASK_LEASED, Some(worker), Some(lease)) => StoredTask::Leased { worker, lease },
            (TASK_LEASED | TASK_QUEUED, ..) => StoredTask::Queued,
            (other, ..) => {
                tracing::warn!("a task stored in the unknown state '{other}' is queued again");
                StoredTask::Queued
            }
        }
    }
}

/// A job state's name in the `jobs` table.
pub fn job_state_name(s: JobState) -> &'static str {
    match s {
        JobState::Queued => "queued",
        JobState::Running => "running",
        JobState::Done => "done",
        JobState::Failed => "failed",
        JobState::Cancelled => "cancelled",
    }
}

/// Parses [`job_state_name`]; an unknown name reads as queued, so the job runs (again).
fn parse_job_state(name: &str) -> JobState {
    JobState::ALL
        .into_iter()
        .find(|&s| job_state_name(s) == name)
        .unwrap_or_else(|| {
            tracing::warn!("a job stored in the unknown state '{name}' is queued again");
            JobState::Queued
        })
}

/// A row of the `tasks` table.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TaskRow {
    /// Task index.
    pub idx: u32,
    /// State, with the worker and lease it names.
    pub state: StoredTask,
    /// Failures so far.
    pub failures: u32,
}

/// The open database.
pub struct Store {
    conn: Connection,
    path: PathBuf,
    /// Where results stored as files live (`results/` beside the database).
    results: PathBuf,
    /// The database file's identity (device, inode) when it was opened, and whether its loss
    /// was reported ([`Store::check_file`]).
    file_id: Option<(u64, u64)>,
    file_lost: std::cell::Cell<bool>,
    /// Whether the database gives free pages back (`auto_vacuum = INCREMENTAL`: made by this
    /// release or a later one), and whether the last attempt failed (said once until one works).
    shrinks: bool,
    shrink_failing: std::cell::Cell<bool>,
    #[cfg(test)]
    faults: Faults,
}

/// A file's (device, inode), where the platform has them.
fn file_id(path: &Path) -> Option<(u64, u64)> {
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        std::fs::metadata(path).ok().map(|m| (m.dev(), m.ino()))
    }
    #[cfg(not(unix))]
    {
        let _ = path;
        None
    }
}

impl Store {
    /// Opens (creating if needed) `dir/raytile.sqlite3`.
    pub fn open(dir: &Path) -> rusqlite::Result<Store> {
        let path = dir.join("raytile.sqlite3");
        let conn = Connection::open(&path)?;
        conn.busy_timeout(std::time::Duration::from_secs(10))?;
        conn.execute_batch(SCHEMA)?;
        // Columns later releases added: a database of a release before result files holds
        // its rows' data; one before checksums has none to check (NULL); one before jobs
        // recorded their renderer does not know which made a finished job's tiles.
        add_column(&conn, "results", "file", "TEXT")?;
        add_column(&conn, "results", "sum", "INTEGER")?;
        add_column(&conn, "jobs", "render_version", "INTEGER")?;
        let results = dir.join("results");
        let had_results = results.try_exists().map_err(|e| io_error_at(&results, e))?;
        if !had_results {
            check_no_files_named(&conn, &results)?;
        }
        std::fs::create_dir_all(&results).map_err(|e| io_error_at(&results, e))?;
        // SQLite's code for incremental auto-vacuum.
        let shrinks = conn.query_row("PRAGMA auto_vacuum", [], |r| r.get::<_, i64>(0))? == 2;
        let mut store = Store {
            conn,
            file_id: file_id(&path),
            file_lost: std::cell::Cell::new(false),
            shrinks,
            shrink_failing: std::cell::Cell::new(false),
            path,
            results,
            #[cfg(test)]
            faults: Faults::default(),
        };
        store.check_results_belong()?;
        store.discard_other_renderer_tiles()?;
        store.mark_unfinished_jobs_current()?;
        store.remove_unnamed_files()?;
        store.requeue_missing_files()?;
        Ok(store)
    }

    /// Where results stored as files live.
    pub fn results_dir(&self) -> &Path {
        &self.results
    }

    /// A database that never served (new: the file was deleted or emptied) beside a
    /// `results/` that holds the results of jobs, or a `scenes/` that holds uploaded scenes, is
    /// not the database they belong to: starting on it would set the results aside as results
    /// of unknown jobs and begin an empty farm, every job forgotten. Refused, so that the right
    /// one can be put back. Folders of purges that a stop interrupted (`.purged-*`) and results
    /// set aside before (`.orphaned/`) do not count.
    fn check_results_belong(&self) -> rusqlite::Result<()> {
        let used: bool = self.conn.query_row(
            "SELECT EXISTS (SELECT 1 FROM meta WHERE key = 'id_epoch')
                 OR EXISTS (SELECT 1 FROM jobs)",
            [],
            |r| r.get(0),
        )?;
        if used {
            return Ok(());
        }
        // Folders that hold something, but for those whose names begin with a dot.
        let held = |dir: &Path| {
            std::fs::read_dir(dir)
                .into_iter()
                .flatten()
                .flatten()
                .filter(|e| !e.file_name().to_string_lossy().starts_with('.'))
                .filter(|e| e.file_type().is_ok_and(|t| t.is_dir()))
                .filter(|e| std::fs::read_dir(e.path()).is_ok_and(|mut d| d.next().is_some()))
                .count()
        };
        let scenes = self.path.with_file_name("scenes");
        let (results, uploads) = (held(&self.results), held(&scenes));
        let (what, folder) = match (results, uploads) {
            (0, 0) => return Ok(()),
            (0, n) => (format!("the {n} scene(s) uploaded to it"), &scenes),
            (n, _) => (format!("the stored results of {n} job(s)"), &self.results),
        };
        let message = format!(
            "{} is a new database, but {} holds {what}: this is not their database (it was \
             deleted or emptied). Put the database back from a backup, or move {} aside to \
             start an empty farm",
            self.path.display(),
            folder.display(),
            folder.display()
        );
        Err(rusqlite::Error::SqliteFailure(
            rusqlite::ffi::Error::new(rusqlite::ffi::SQLITE_CANTOPEN),
            Some(message),
        ))
    }

    /// Rows whose result file is gone (removed by hand, or lost by a file system that did not
    /// keep a synced rename) are deleted, and their tasks queued again: the tiles are rendered
    /// again rather than missing from the frame. A `done` job whose tiles the current renderer
    /// made is running again until they are; a cancelled or failed one keeps its state, and
    /// renders them if it is retried. The frame of a finished job of another renderer goes
    /// without them, with an error in the log. Returns how many rows were deleted.
    fn requeue_missing_files(&mut self) -> rusqlite::Result<usize> {
        let missing: Vec<(String, u32)> = {
            let mut st = self
                .conn
                .prepare("SELECT job_id, idx, file FROM results WHERE file IS NOT NULL")?;
            let rows = st.query_map([], |r| {
                let file = r.get_ref(2)?.as_str().ok().map(String::from);
                Ok((r.get::<_, String>(0)?, r.get(1)?, file))
            })?;
            let mut out = Vec::new();
            for row in rows {
                let (job, idx, file) = row?;
                // Only a file known to be gone: one that cannot be looked at (permissions, an
                // I/O error) is left to the reads, which say why. A name that is not text is
                // damaged: it names no file.
                let gone =
                    file.is_none_or(|f| matches!(self.results.join(f).try_exists(), Ok(false)));
                if gone {
                    out.push((job, idx));
                }
            }
            out
        };
        if missing.is_empty() {
            return Ok(0);
        }
        let tx = self.conn.transaction()?;
        let mut lacking = 0;
        let mut reopened = std::collections::BTreeSet::new();
        for (job, idx) in &missing {
            tx.execute(
                "DELETE FROM results WHERE job_id = ?1 AND idx = ?2",
                params![job, idx],
            )?;
            let requeued = tx.execute(
                &format!(
                    "UPDATE tasks SET state = '{TASK_QUEUED}', worker = NULL, lease = NULL,
                         failures = 0
                     WHERE job_id = ?1 AND idx = ?2 AND job_id IN
                         (SELECT id FROM jobs WHERE state IN ('{}', '{}')
                             OR render_version = ?3)",
                    job_state_name(JobState::Queued),
                    job_state_name(JobState::Running),
                ),
                params![job, idx, raytile_core::RENDER_VERSION],
            )?;
            if requeued == 0 {
                lacking += 1;
                tracing::error!(%job, idx, "the result file of a finished job's task is missing");
                continue;
            }
            let reopen = tx.execute(
                &format!(
                    "UPDATE jobs SET state = '{}', finished_ms = NULL WHERE id = ?1 AND state = '{}'",
                    job_state_name(JobState::Running),
                    job_state_name(JobState::Done),
                ),
                params![job],
            )?;
            if reopen > 0 {
                // As a repair while running does: no worker blocked from it any more.
                tx.execute("DELETE FROM blocked WHERE job_id = ?1", params![job])?;
                reopened.insert(job.clone());
            }
        }
        tx.commit()?;
        for job in &reopened {
            tracing::warn!(%job, "a finished job lost stored tiles: it runs again until they are rendered again");
        }
        if lacking == 0 {
            tracing::warn!(
                count = missing.len(),
                "result files named by the database are missing: their tasks are queued again"
            );
        } else {
            tracing::warn!(
                count = missing.len(),
                queued_again = missing.len() - lacking,
                lacking,
                "result files named by the database are missing: their tasks are queued again, \
                 but for finished jobs that cannot be rendered again (another renderer version \
                 made them, or they were cancelled or failed), whose frames lack those tiles"
            );
        }
        Ok(missing.len())
    }

    /// Records the current renderer as the maker of every unfinished job's tiles: after
    /// [`Store::discard_other_renderer_tiles`] it is, whatever the database said before.
    fn mark_unfinished_jobs_current(&mut self) -> rusqlite::Result<()> {
        self.conn.execute(
            &format!(
                "UPDATE jobs SET render_version = ?1 WHERE state IN ('{}', '{}')
                 AND render_version IS NOT ?1",
                job_state_name(JobState::Queued),
                job_state_name(JobState::Running)
            ),
            params![raytile_core::RENDER_VERSION],
        )?;
        Ok(())
    }

    /// Removes result files of the database's jobs that no row names: moved into place by a
    /// transaction that then failed, or tiles of another renderer version discarded while the
    /// coordinator stopped before it removed them; and what a stop left of a purge
    /// (`.purged-*`). The folder of a job the database does not know (a database put back
    /// from an older backup, or another farm's; a purge that a stop interrupted) is not
    /// deleted but moved into `results/.orphaned/`, with a warning: those may be the only copy
    /// of finished work.
    fn remove_unnamed_files(&self) -> rusqlite::Result<()> {
        let mut st = self
            .conn
            .prepare("SELECT file FROM results WHERE file IS NOT NULL")?;
        let named: std::collections::HashSet<String> =
            st.query_map([], |r| r.get(0))?.collect::<Result<_, _>>()?;
        drop(st);
        let mut st = self.conn.prepare("SELECT id FROM jobs")?;
        let known: std::collections::HashSet<String> =
            st.query_map([], |r| r.get(0))?.collect::<Result<_, _>>()?;
        drop(st);
        let Ok(jobs) = std::fs::read_dir(&self.results) else {
            return Ok(());
        };
        let orphaned = self.results.join(ORPHANED);
        let (mut removed, mut bytes, mut set_aside) = (0u64, 0u64, 0u64);
        for job in jobs.flatten() {
            let dir = job.path();
            let job_name = job.file_name().to_string_lossy().into_owned();
            if job_name == ORPHANED {
                continue;
            }
            if !job_name.starts_with('.') && !known.contains(&job_name) {
                let to = (0..)
                    .map(|n| match n {
                        0 => orphaned.join(&job_name),
                        n => orphaned.join(format!("{job_name}-{n}")),
                    })
                    .find(|p| !p.exists())
                    .expect("a free name");
                let moved =
                    std::fs::create_dir_all(&orphaned).and_then(|()| std::fs::rename(&dir, &to));
                match moved {
                    Ok(()) => set_aside += 1,
                    Err(e) => tracing::warn!(path = %dir.display(), "cannot set aside: {e}"),
                }
                continue;
            }
            let files = std::fs::read_dir(&dir).into_iter().flatten().flatten();
            let mut kept = 0;
            for f in files {
                let name = format!("{job_name}/{}", f.file_name().to_string_lossy());
                if named.contains(&name) {
                    kept += 1;
                    continue;
                }
                let size = f.metadata().map_or(0, |m| m.len());
                match std::fs::remove_file(f.path()) {
                    Ok(()) => (removed, bytes) = (removed + 1, bytes + size),
                    Err(e) => tracing::warn!(path = %f.path().display(), "cannot remove: {e}"),
                }
            }
            if kept == 0 {
                let _ = std::fs::remove_dir(&dir);
            }
        }
        if removed > 0 {
            tracing::warn!(
                files = removed,
                bytes,
                "removed result files that no stored result names: left by a write or purge \
                 that a stop interrupted, or by a power loss that undid the last commits"
            );
        }
        if set_aside > 0 {
            tracing::warn!(
                jobs = set_aside,
                path = %orphaned.display(),
                "set aside the stored results of jobs this database does not know (a database \
                 put back from an older backup, or another farm's?): delete them once they \
                 are not needed"
            );
        }
        Ok(())
    }

    /// Tiles of unfinished jobs stored by a coordinator of another renderer version
    /// ([`raytile_core::RENDER_VERSION`]; a database without one predates the check) would mix
    /// two renderers' arithmetic in one frame: they are deleted and their tasks queued again.
    /// Finished jobs keep their frames (each came from one renderer). Returns how many tiles
    /// were discarded.
    fn discard_other_renderer_tiles(&mut self) -> rusqlite::Result<usize> {
        let current = raytile_core::RENDER_VERSION.to_string();
        let stored: Option<String> = self
            .conn
            .query_row(
                "SELECT value FROM meta WHERE key = 'render_version'",
                [],
                |r| r.get(0),
            )
            .optional()?;
        if stored.as_deref() == Some(current.as_str()) {
            return Ok(0);
        }
        let tx = self.conn.transaction()?;
        // Another renderer ran on this database since this one last did: a finished job that
        // says this renderer made its tiles may have been finished by that one (a release
        // that did not record it), so it is no longer known.
        tx.execute(
            &format!(
                "UPDATE jobs SET render_version = NULL WHERE state NOT IN ('{}', '{}')
                 AND render_version = ?1",
                job_state_name(JobState::Queued),
                job_state_name(JobState::Running)
            ),
            params![raytile_core::RENDER_VERSION],
        )?;
        let unfinished = format!(
            "SELECT id FROM jobs WHERE state IN ('{}', '{}')",
            job_state_name(JobState::Queued),
            job_state_name(JobState::Running)
        );
        let discarded = tx.execute(
            &format!("DELETE FROM results WHERE job_id IN ({unfinished})"),
            [],
        )?;
        tx.execute(
            &format!(
                "UPDATE tasks SET state = '{TASK_QUEUED}', worker = NULL, lease = NULL
                 WHERE job_id IN ({unfinished}) AND state IN ('{TASK_DONE}', '{TASK_LEASED}')"
            ),
            [],
        )?;
        tx.execute(
            "INSERT OR REPLACE INTO meta (key, value) VALUES ('render_version', ?1)",
            params![current],
        )?;
        tx.commit()?;
        if discarded > 0 {
            tracing::warn!(
                discarded,
                stored = stored.as_deref().unwrap_or("none"),
                current = %current,
                "the database holds tiles of unfinished jobs from another renderer version: \
                 discarded, they will be rendered again"
            );
        }
        Ok(discarded)
    }

    /// The epoch of this start's ids: `at_least` (the wall-clock start time), raised above the
    /// previous start's epoch if need be, and remembered for the next start.
    pub fn next_epoch(&mut self, at_least: u64) -> rusqlite::Result<u64> {
        let tx = self.conn.transaction()?;
        let last: Option<String> = tx
            .query_row("SELECT value FROM meta WHERE key = 'id_epoch'", [], |r| {
                r.get(0)
            })
            .optional()?;
        let last = last.and_then(|v| v.parse::<u64>().ok());
        let epoch = last.map_or(at_least, |l| at_least.max(l + 1));
        tx.execute(
            "INSERT OR REPLACE INTO meta (key, value) VALUES ('id_epoch', ?1)",
            params![epoch.to_string()],
        )?;
        tx.commit()?;
        Ok(epoch)
    }

    /// The secret key of lease tags (`sched::ids`): made from the operating system's random
    /// numbers at the first start, kept in the database so that leases stay valid across
    /// restarts.
    pub fn lease_key(&mut self) -> rusqlite::Result<[u8; 32]> {
        let tx = self.conn.transaction()?;
        // Read as whatever SQLite holds (the column is not typed): a key that is not 64 hex
        // digits is replaced, with a warning, rather than keep the coordinator from starting.
        let kept: Option<Option<String>> = tx
            .query_row("SELECT value FROM meta WHERE key = 'lease_key'", [], |r| {
                Ok(r.get_ref(0)?.as_str().ok().map(str::to_owned))
            })
            .optional()?;
        let parse = |text: &str| -> Option<[u8; 32]> { hex::decode(text).ok()?.try_into().ok() };
        if let Some(key) = kept.as_ref().and_then(|k| k.as_deref()).and_then(parse) {
            return Ok(key);
        }
        if kept.is_some() {
            tracing::warn!(
                "the database's lease key is not 64 hex digits: a new one replaces it, and leases \
                 out now are refused when their results come (their tasks are rendered again)"
            );
        }
        let mut key = [0u8; 32];
        getrandom::fill(&mut key)
            .map_err(|e| rusqlite::Error::ToSqlConversionFailure(Box::new(e)))?;
        tx.execute(
            "INSERT OR REPLACE INTO meta (key, value) VALUES ('lease_key', ?1)",
            params![hex::encode(key)],
        )?;
        tx.commit()?;
        Ok(key)
    }

    /// A second connection for long reads (image composition) that must not hold the
    /// scheduler's lock.
    pub fn reader(&self) -> rusqlite::Result<Connection> {
        let c = Connection::open(&self.path)?;
        c.busy_timeout(std::time::Duration::from_secs(10))?;
        Ok(c)
    }

    /// Writes every change of one scheduler operation in one transaction: all of them are
    /// stored, or (the disk is full, the file read-only...) none is and the error says why.
    /// The scheduler changes its memory only after this returns `Ok`.
    pub fn write(&mut self, writes: &[Write<'_>]) -> rusqlite::Result<()> {
        if writes.is_empty() {
            return Ok(());
        }
        // Result files are moved into place first (a rename within the data directory), and
        // removed again if the transaction fails: a row never names a missing file.
        let mut placed = Vec::new();
        for w in writes {
            if let Write::Result {
                job,
                row,
                file: Some(staged),
                ..
            } = *w
            {
                if let Err(e) = self.place(job, row.idx, staged, &mut placed) {
                    remove_files(&placed);
                    return Err(e);
                }
            }
        }
        // The files of results dropped, removed once the rows that name them are gone.
        let mut dropped = Vec::new();
        for w in writes {
            if let Write::DropResult { job, row } = *w {
                // A damaged name (not text) names no file to remove.
                let file: Option<Option<String>> = self
                    .conn
                    .query_row(
                        "SELECT file FROM results WHERE job_id = ?1 AND idx = ?2",
                        params![job, row.idx],
                        |r| Ok(r.get_ref(0)?.as_str().ok().map(String::from)),
                    )
                    .optional()?;
                dropped.extend(file.flatten().map(|f| self.results.join(f)));
            }
        }
        let done = (|| {
            #[cfg(test)]
            self.faults.check()?;
            let tx = self.conn.transaction()?;
            for w in writes {
                apply(&tx, w)?;
            }
            tx.commit()
        })();
        if done.is_err() {
            remove_files(&placed);
        }
        done?;
        if !dropped.is_empty() {
            // A large result can be hundreds of MB: unlinked on a thread of its own, as a
            // purge's, not under the caller's lock.
            std::thread::spawn(move || remove_files(&dropped));
        }
        let mut purged = false;
        for w in writes {
            if let Write::DeleteJob(job) = *w {
                self.remove_job_files(job);
                purged = true;
            }
        }
        if purged {
            self.shrink(SHRINK_PAGES);
        }
        Ok(())
    }

    /// Gives back to the file system up to `pages` of the database's free pages (those the
    /// rows of purged jobs held; tiles stored in the database are most of its size), so that
    /// the file shrinks after purges rather than staying at its largest. A database made by a
    /// release before this one has no room for it (SQLite's `auto_vacuum` is fixed when the
    /// first table is made) and keeps its size: `VACUUM` it offline once (docs/farm.md).
    /// Bounded, since the caller holds the scheduler's lock: what is left is given back by
    /// the next calls. A failure (a full or read-only disk) only leaves the file larger, and
    /// is said once until a later call succeeds.
    pub fn shrink(&self, pages: u32) {
        if !self.shrinks || self.free_pages() == 0 {
            return;
        }
        // Each step of the statement gives back one page: stepped to its end.
        let run = || -> rusqlite::Result<()> {
            let mut stmt = self
                .conn
                .prepare(&format!("PRAGMA incremental_vacuum({pages})"))?;
            let mut rows = stmt.query([])?;
            while rows.next()?.is_some() {}
            Ok(())
        };
        match run() {
            Ok(()) => self.shrink_failing.set(false),
            Err(e) => {
                if !self.shrink_failing.replace(true) {
                    tracing::warn!("the database could not give back its free pages: {e}");
                }
            }
        }
    }

    /// Whether the database file is still the one this store opened: removed or replaced
    /// while the coordinator runs (a clean-up, a restore done too early), everything it writes
    /// goes to a file no one will open again, and the next start would begin without it.
    /// Said once, as an error in the log; called now and then.
    pub fn check_file(&self) -> bool {
        let Some(opened) = self.file_id else {
            return true;
        };
        let same = file_id(&self.path) == Some(opened);
        if !same && !self.file_lost.replace(true) {
            tracing::error!(
                path = %self.path.display(),
                "the database file was removed or replaced while the coordinator runs: what \
                 it stores from now on is lost when it stops: stop it, and put the database \
                 back from a backup"
            );
        }
        same
    }

    /// Free pages the database holds (SQLite's `freelist_count`), 0 if it cannot tell.
    pub fn free_pages(&self) -> u64 {
        self.conn
            .query_row("PRAGMA freelist_count", [], |r| r.get(0))
            .unwrap_or(0)
    }

    /// Removes a purged job's result files: its folder is renamed aside at once (a name no
    /// row uses), and emptied on a thread of its own, since unlinking many GB can take long
    /// and the caller holds the scheduler's lock. What a stop interrupts, the next start
    /// removes ([`Store::remove_unnamed_files`]).
    fn remove_job_files(&self, job: &str) {
        static NEXT: AtomicU64 = AtomicU64::new(0);
        let dir = self.results.join(job);
        let aside = self.results.join(format!(
            ".purged-{}-{}",
            std::process::id(),
            NEXT.fetch_add(1, Ordering::Relaxed)
        ));
        match std::fs::rename(&dir, &aside) {
            Ok(()) => {
                std::thread::spawn(move || {
                    if let Err(e) = std::fs::remove_dir_all(&aside) {
                        tracing::warn!(path = %aside.display(), "cannot remove: {e}");
                    }
                });
            }
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
            Err(e) => tracing::warn!(path = %dir.display(), "cannot remove: {e}"),
        }
    }

    /// Moves `staged` to its place as task `idx` of `job`'s result file, and syncs the folders
    /// that name it: the row that will name the file is not written before the file's name is
    /// on disk (its bytes were synced when it was staged).
    /// The file's new path is pushed to `placed` as soon as it is there.
    fn place(
        &self,
        job: &str,
        idx: u32,
        staged: &Staged,
        placed: &mut Vec<PathBuf>,
    ) -> rusqlite::Result<()> {
        let dir = self.results.join(job);
        std::fs::create_dir_all(&dir).map_err(|e| io_error_at(&dir, e))?;
        let path = self.results.join(result_file_name(job, idx, staged));
        std::fs::rename(&staged.path, &path).map_err(|e| {
            let to = format!("{} → {}", staged.path.display(), path.display());
            io_error_at(Path::new(&to), e)
        })?;
        placed.push(path);
        for d in [&dir, &self.results] {
            let synced = std::fs::File::open(d).and_then(|f| f.sync_all());
            synced.map_err(|e| io_error_at(d, e))?;
        }
        Ok(())
    }

    /// A switch that makes the next writes fail as a full disk would (tests only).
    #[cfg(test)]
    pub fn faults(&self) -> Faults {
        self.faults.clone()
    }

    /// Inserts a new job (its tasks are queued until a row says otherwise).
    pub fn insert_job(&mut self, j: &JobRow) -> rusqlite::Result<()> {
        self.write(&[Write::InsertJob(j)])
    }

    /// Writes one task's state.
    pub fn update_task(&mut self, job: &str, t: &TaskRow) -> rusqlite::Result<()> {
        self.write(&[Write::Task { job, row: t }])
    }

    /// Every job, in submission order.
    pub fn jobs(&self) -> rusqlite::Result<Vec<JobRow>> {
        let mut st = self.conn.prepare(
            "SELECT id, seq, scene, settings, priority, state, error, created_ms, started_ms,
                 finished_ms, render_version
             FROM jobs ORDER BY seq",
        )?;
        let rows = st.query_map([], |r| {
            Ok(JobRow {
                id: r.get(0)?,
                seq: r.get::<_, i64>(1)? as u64,
                scene: r.get(2)?,
                settings: r.get(3)?,
                priority: r.get(4)?,
                state: parse_job_state(&r.get::<_, String>(5)?),
                error: r.get(6)?,
                created_ms: r.get::<_, i64>(7)? as u64,
                started_ms: r.get::<_, Option<i64>>(8)?.map(|v| v as u64),
                finished_ms: r.get::<_, Option<i64>>(9)?.map(|v| v as u64),
                render_version: r.get(10)?,
            })
        })?;
        rows.collect()
    }

    /// The tasks of a job, by index.
    pub fn tasks(&self, job: &str) -> rusqlite::Result<Vec<TaskRow>> {
        let mut st = self.conn.prepare(
            "SELECT idx, state, failures, worker, lease FROM tasks WHERE job_id = ?1 ORDER BY idx",
        )?;
        let rows = st.query_map([job], |r| {
            Ok(TaskRow {
                idx: r.get(0)?,
                state: StoredTask::from_columns(&r.get::<_, String>(1)?, r.get(3)?, r.get(4)?),
                failures: r.get(2)?,
            })
        })?;
        rows.collect()
    }

    /// Per-worker failure counts of a job.
    pub fn blocked(&self, job: &str) -> rusqlite::Result<Vec<(String, u32)>> {
        let mut st = self
            .conn
            .prepare("SELECT worker, failures FROM blocked WHERE job_id = ?1")?;
        let rows = st.query_map([job], |r| Ok((r.get(0)?, r.get(1)?)))?;
        rows.collect()
    }

    /// Every registered worker: (id, name, threads, registered_ms).
    pub fn workers(&self) -> rusqlite::Result<Vec<(String, String, u32, u64)>> {
        let mut st = self
            .conn
            .prepare("SELECT id, name, threads, registered_ms FROM workers")?;
        let rows = st.query_map([], |r| {
            Ok((r.get(0)?, r.get(1)?, r.get(2)?, r.get::<_, i64>(3)? as u64))
        })?;
        rows.collect()
    }
}

/// One change to the store. A scheduler operation collects its changes and hands them to
/// [`Store::write`] together.
#[derive(Clone, Copy, Debug)]
pub enum Write<'a> {
    /// A new job. Its tasks get no rows: a task without a row is queued with no failures, so
    /// creating a job costs one row whatever its size.
    InsertJob(&'a JobRow),
    /// A job's state, error and times.
    Job {
        /// Job id.
        id: &'a str,
        /// State.
        state: JobState,
        /// Why it failed.
        error: Option<&'a str>,
        /// First lease.
        started_ms: Option<u64>,
        /// End.
        finished_ms: Option<u64>,
    },
    /// One task's state.
    Task {
        /// Job id.
        job: &'a str,
        /// The task.
        row: &'a TaskRow,
    },
    /// A finished task's result, stored with the task's done state.
    Result {
        /// Job id.
        job: &'a str,
        /// The task, done.
        row: &'a TaskRow,
        /// The encoded tile sums.
        data: &'a [u8],
        /// The same bytes, already written to a file: stored as that file instead.
        file: Option<&'a Staged>,
    },
    /// A stored result found missing or damaged, deleted (its file too, once stored) with the
    /// task's new state (queued: it is rendered again).
    DropResult {
        /// Job id.
        job: &'a str,
        /// The task, queued again.
        row: &'a TaskRow,
    },
    /// Every worker's failure count on a job, forgotten (a done job that runs again).
    ClearBlocked(&'a str),
    /// A worker's failure count on a job.
    Blocked {
        /// Job id.
        job: &'a str,
        /// Worker id.
        worker: &'a str,
        /// Failures so far.
        failures: u32,
    },
    /// A job with its tasks, results and failure counts.
    DeleteJob(&'a str),
    /// A job's priority.
    Priority {
        /// Job id.
        id: &'a str,
        /// New priority.
        priority: i32,
    },
    /// A registered worker.
    Worker {
        /// Worker id.
        id: &'a str,
        /// Name.
        name: &'a str,
        /// Threads.
        threads: u32,
        /// Registration time.
        registered_ms: u64,
    },
    /// A worker forgotten (its failure counts on jobs stay).
    ForgetWorker(&'a str),
}

/// Applies one change inside a transaction.
fn apply(tx: &Connection, w: &Write<'_>) -> rusqlite::Result<()> {
    match *w {
        Write::InsertJob(j) => {
            tx.execute(
                "INSERT INTO jobs (id, seq, scene, settings, priority, state, error, created_ms, started_ms, finished_ms, render_version)
                 VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11)",
                params![j.id, j.seq as i64, j.scene, j.settings, j.priority, job_state_name(j.state), j.error,
                        j.created_ms as i64, j.started_ms.map(|v| v as i64), j.finished_ms.map(|v| v as i64),
                        j.render_version],
            )?;
        }
        Write::Job {
            id,
            state,
            error,
            started_ms,
            finished_ms,
        } => {
            tx.execute(
                "UPDATE jobs SET state = ?2, error = ?3, started_ms = ?4, finished_ms = ?5 WHERE id = ?1",
                params![id, job_state_name(state), error, started_ms.map(|v| v as i64), finished_ms.map(|v| v as i64)],
            )?;
        }
        Write::Priority { id, priority } => {
            tx.execute(
                "UPDATE jobs SET priority = ?2 WHERE id = ?1",
                params![id, priority],
            )?;
        }
        Write::Task { job, row } => write_task(tx, job, row)?,
        Write::Result {
            job,
            row,
            data,
            file,
        } => {
            let (data, file, sum) = match file {
                Some(staged) => (
                    &[][..],
                    Some(result_file_name(job, row.idx, staged)),
                    staged.sum,
                ),
                None => (data, None, crc32fast::hash(data)),
            };
            tx.execute(
                "INSERT OR IGNORE INTO results (job_id, idx, data, file, sum) VALUES (?1, ?2, ?3, ?4, ?5)",
                params![job, row.idx, data, file, sum],
            )?;
            write_task(tx, job, row)?;
        }
        Write::DropResult { job, row } => {
            tx.execute(
                "DELETE FROM results WHERE job_id = ?1 AND idx = ?2",
                params![job, row.idx],
            )?;
            write_task(tx, job, row)?;
        }
        Write::Blocked {
            job,
            worker,
            failures,
        } => {
            tx.execute(
                "INSERT INTO blocked (job_id, worker, failures) VALUES (?1, ?2, ?3)
                 ON CONFLICT (job_id, worker) DO UPDATE SET failures = excluded.failures",
                params![job, worker, failures],
            )?;
        }
        Write::ClearBlocked(job) => {
            tx.execute("DELETE FROM blocked WHERE job_id = ?1", params![job])?;
        }
        Write::DeleteJob(job) => {
            for table in ["results", "tasks", "blocked"] {
                tx.execute(
                    &format!("DELETE FROM {table} WHERE job_id = ?1"),
                    params![job],
                )?;
            }
            tx.execute("DELETE FROM jobs WHERE id = ?1", params![job])?;
        }
        Write::Worker {
            id,
            name,
            threads,
            registered_ms,
        } => {
            tx.execute(
                "INSERT OR REPLACE INTO workers (id, name, threads, registered_ms) VALUES (?1, ?2, ?3, ?4)",
                params![id, name, threads, registered_ms as i64],
            )?;
        }
        Write::ForgetWorker(id) => {
            tx.execute("DELETE FROM workers WHERE id = ?1", params![id])?;
        }
    }
    Ok(())
}

/// Writes one task's state (inserting its row the first time it leaves the queue).
fn write_task(conn: &Connection, job: &str, t: &TaskRow) -> rusqlite::Result<()> {
    let (state, worker, lease) = t.state.columns();
    conn.execute(
        "INSERT INTO tasks (job_id, idx, state, failures, worker, lease) VALUES (?1, ?2, ?3, ?4, ?5, ?6)
         ON CONFLICT (job_id, idx) DO UPDATE SET state = excluded.state, failures = excluded.failures,
             worker = excluded.worker, lease = excluded.lease",
        params![job, t.idx, state, t.failures, worker, lease],
    )?;
    Ok(())
}

/// Injected write failures, shared between a test and the store it holds (tests only).
#[cfg(test)]
#[derive(Clone, Debug, Default)]
pub struct Faults(std::sync::Arc<std::sync::atomic::AtomicU32>);

#[cfg(test)]
impl Faults {
    /// Makes the next `n` calls of [`Store::write`] fail with `SQLITE_FULL`, writing nothing.
    pub fn fail_next(&self, n: u32) {
        self.0.store(n, std::sync::atomic::Ordering::SeqCst);
    }

    fn check(&self) -> rusqlite::Result<()> {
        use std::sync::atomic::Ordering::SeqCst;
        let take = self.0.fetch_update(SeqCst, SeqCst, |n| n.checked_sub(1));
        if take.is_ok() {
            return Err(rusqlite::Error::SqliteFailure(
                rusqlite::ffi::Error::new(rusqlite::ffi::SQLITE_FULL),
                Some("injected fault: database or disk is full".into()),
            ));
        }
        Ok(())
    }
}

/// Reads the stored results of a job's tasks `tasks` as (task index, bytes), through `conn`
/// (result files from `results`, [`Store::results_dir`]), calling `f` for each so the caller
/// never holds them all at once. Returns the tasks whose stored result was skipped: its file
/// missing, or its bytes no longer those stored (their checksum differs). The caller says
/// whether that is damage or a purge under way.
pub fn for_each_result(
    conn: &Connection,
    results: &Path,
    job: &str,
    tasks: std::ops::Range<usize>,
    mut f: impl FnMut(u32, &[u8]),
) -> rusqlite::Result<Vec<u32>> {
    let mut damaged = Vec::new();
    let mut st = conn.prepare_cached(
        "SELECT idx, data, file, sum FROM results WHERE job_id = ?1 AND idx >= ?2 AND idx < ?3
         ORDER BY idx",
    )?;
    let mut rows = st.query(params![job, tasks.start as i64, tasks.end as i64])?;
    while let Some(r) = rows.next()? {
        let idx: u32 = r.get(0)?;
        // A row whose columns do not read as their types (a sum out of range, text where bytes
        // belong) is as damaged as bytes that fail their sum.
        let columns = (|| -> rusqlite::Result<_> {
            let sum: Option<u32> = r.get(3)?;
            let file = r.get_ref(2)?.as_str_or_null()?;
            let blob = match file {
                Some(_) => None,
                None => Some(r.get_ref(1)?.as_blob()?),
            };
            Ok((sum, file, blob))
        })();
        let (sum, file, blob) = match columns {
            Ok(c) => c,
            Err(e) => {
                tracing::error!(%job, idx, "a stored result's row is damaged: {e}");
                damaged.push(idx);
                continue;
            }
        };
        let from_file;
        let data: &[u8] = match file {
            Some(file) => match std::fs::read(results.join(file)) {
                Ok(bytes) => {
                    from_file = bytes;
                    &from_file
                }
                // Purged while the frame was being made, removed by hand, or unreadable on a
                // failing disk (EIO): rendered again, if its job still can be.
                Err(e) if e.kind() == std::io::ErrorKind::NotFound || is_media_error(&e) => {
                    if e.kind() != std::io::ErrorKind::NotFound {
                        tracing::error!(%job, idx, file, "a stored result cannot be read: {e}");
                    }
                    damaged.push(idx);
                    continue;
                }
                Err(e) => return Err(io_error(e)),
            },
            None => blob.unwrap_or_default(),
        };
        if sum.is_none_or(|s| s == crc32fast::hash(data)) {
            f(idx, data);
        } else {
            tracing::error!(%job, idx, "a stored result's bytes do not match its checksum");
            damaged.push(idx);
        }
    }
    Ok(damaged)
}

/// A result written to a file in `results/.staging/` and synced, before the
/// scheduler's lock is taken; a [`Write::Result`] naming it moves it into `results/`.
/// Dropped unused, it removes its file.
#[derive(Debug)]
pub struct Staged {
    path: PathBuf,
    /// Unique among this process's staged files: part of the stored file's name.
    name: String,
    /// The bytes' CRC-32, stored in the row and checked when the file is read.
    sum: u32,
}

impl Staged {
    /// Writes `bytes` to a new file in `data_dir/results/.staging/` and syncs it to disk.
    /// Blocks: call it off the async runtime's threads. Staged inside `results/`, so that the
    /// rename that puts it in place never crosses file systems (`results/` may be a volume of
    /// its own, or a link to another disk). What a stop leaves there, the next start removes
    /// ([`Store::remove_unnamed_files`]).
    pub fn write(data_dir: &Path, bytes: &[u8]) -> rusqlite::Result<Staged> {
        static NEXT: AtomicU64 = AtomicU64::new(0);
        let name = format!(
            "{}-{}",
            std::process::id(),
            NEXT.fetch_add(1, Ordering::Relaxed)
        );
        let tmp = data_dir.join("results").join(STAGING);
        let staged = Staged {
            path: tmp.join(format!("result-{name}")),
            name,
            sum: crc32fast::hash(bytes),
        };
        let at = |e| io_error_at(&staged.path, e);
        // Made again if it was removed while the coordinator ran.
        std::fs::create_dir_all(&tmp).map_err(|e| io_error_at(&tmp, e))?;
        let mut f = std::fs::File::create(&staged.path).map_err(at)?;
        f.write_all(bytes).map_err(at)?;
        f.sync_all().map_err(at)?;
        Ok(staged)
    }
}

impl Drop for Staged {
    fn drop(&mut self) {
        // Moved into place, it is no longer there.
        let _ = std::fs::remove_file(&self.path);
    }
}

/// A database that names result files beside no `results/` folder at all: a volume not
/// mounted, or the folder removed. Refused, rather than render every such tile again.
fn check_no_files_named(conn: &Connection, results: &Path) -> rusqlite::Result<()> {
    let named: i64 = conn.query_row(
        "SELECT COUNT(*) FROM results WHERE file IS NOT NULL",
        [],
        |r| r.get(0),
    )?;
    if named == 0 {
        return Ok(());
    }
    let message = format!(
        "the database names {named} result file(s) under {}, which does not exist: is its \
         volume mounted? Put the folder back; to go on without those results (their tiles \
         are rendered again where their jobs can be), create it empty",
        results.display()
    );
    Err(rusqlite::Error::SqliteFailure(
        rusqlite::ffi::Error::new(rusqlite::ffi::SQLITE_CANTOPEN),
        Some(message),
    ))
}

/// Whether reading a file failed on its bytes (the medium, EIO), not on access to it.
fn is_media_error(e: &std::io::Error) -> bool {
    e.kind() == std::io::ErrorKind::InvalidData || e.raw_os_error() == Some(libc::EIO)
}

/// Adds `column` of type `decl` to `table` where a database made by an earlier release lacks
/// it.
fn add_column(conn: &Connection, table: &str, column: &str, decl: &str) -> rusqlite::Result<()> {
    let has: bool = conn.query_row(
        "SELECT COUNT(*) FROM pragma_table_info(?1) WHERE name = ?2",
        params![table, column],
        |r| r.get::<_, i64>(0).map(|n| n > 0),
    )?;
    if !has {
        conn.execute_batch(&format!("ALTER TABLE {table} ADD COLUMN {column} {decl}"))?;
    }
    Ok(())
}

/// A result file's name under `results/`, as its row stores it: `JOB/TASK-UNIQUE`.
fn result_file_name(job: &str, idx: u32, staged: &Staged) -> String {
    format!("{job}/{idx}-{}", staged.name)
}

fn remove_files(paths: &[PathBuf]) {
    for p in paths {
        let _ = std::fs::remove_file(p);
    }
}

/// The folder under `results/` that holds the results of jobs the database does not know.
const ORPHANED: &str = ".orphaned";

/// The folder of `results/` where large results are written before they are moved into place.
const STAGING: &str = ".staging";

/// A file error as the store's error: a full disk reads as SQLite's own, so it is answered
/// the same way (503, retryable).
fn io_error(e: std::io::Error) -> rusqlite::Error {
    failure(&e, e.to_string())
}

/// [`io_error`] naming the file, for the log.
fn io_error_at(path: &Path, e: std::io::Error) -> rusqlite::Error {
    failure(&e, format!("{}: {e}", path.display()))
}

fn failure(e: &std::io::Error, message: String) -> rusqlite::Error {
    let code = if e.raw_os_error() == Some(libc::ENOSPC) {
        rusqlite::ffi::SQLITE_FULL
    } else {
        rusqlite::ffi::SQLITE_IOERR
    };
    rusqlite::Error::SqliteFailure(rusqlite::ffi::Error::new(code), Some(message))
}

#[cfg(test)]
mod tests {
    use super::*;
    use axum::response::IntoResponse;
    use raytile_core::RENDER_VERSION;

    #[test]
    fn states_read_back_as_written() {
        let dir = tempfile::tempdir().unwrap();
        let mut store = Store::open(dir.path()).unwrap();
        for (i, state) in JobState::ALL.into_iter().enumerate() {
            store
                .insert_job(&job_row(&format!("j{i}"), i as u64, state))
                .unwrap();
        }
        let states: Vec<JobState> = store.jobs().unwrap().iter().map(|r| r.state).collect();
        assert_eq!(states, JobState::ALL);
        let tasks = [
            StoredTask::Queued,
            StoredTask::Leased {
                worker: "w".into(),
                lease: "l".into(),
            },
            StoredTask::Done { worker: "w".into() },
            StoredTask::Failed,
        ];
        for (idx, state) in tasks.iter().enumerate() {
            let row = TaskRow {
                idx: idx as u32,
                state: state.clone(),
                failures: idx as u32,
            };
            store.update_task("j0", &row).unwrap();
        }
        let back: Vec<(StoredTask, u32)> = store
            .tasks("j0")
            .unwrap()
            .into_iter()
            .map(|t| (t.state, t.failures))
            .collect();
        let want: Vec<(StoredTask, u32)> = tasks.into_iter().zip(0..).collect();
        assert_eq!(back, want);
    }

    #[test]
    fn a_lease_missing_its_worker_is_queued_again() {
        assert_eq!(
            StoredTask::from_columns(TASK_LEASED, None, Some("l".into())),
            StoredTask::Queued
        );
        assert_eq!(
            StoredTask::from_columns("paused", None, None),
            StoredTask::Queued
        );
        assert_eq!(parse_job_state("paused"), JobState::Queued);
    }

    #[test]
    fn every_start_gets_a_later_epoch() {
        let dir = tempfile::tempdir().unwrap();
        let mut store = Store::open(dir.path()).unwrap();
        assert_eq!(store.next_epoch(1000).unwrap(), 1000);
        // The same millisecond, and a clock set back: still a new epoch.
        assert_eq!(store.next_epoch(1000).unwrap(), 1001);
        drop(store);
        let mut store = Store::open(dir.path()).unwrap();
        assert_eq!(store.next_epoch(5).unwrap(), 1002);
        assert_eq!(store.next_epoch(9000).unwrap(), 9000);
    }

    #[test]
    fn the_lease_key_is_made_once_and_kept_and_a_broken_one_is_replaced() {
        let dir = tempfile::tempdir().unwrap();
        let mut store = Store::open(dir.path()).unwrap();
        let key = store.lease_key().unwrap();
        assert_ne!(key, [0; 32]);
        assert_eq!(store.lease_key().unwrap(), key);
        drop(store);
        let mut store = Store::open(dir.path()).unwrap();
        assert_eq!(store.lease_key().unwrap(), key, "kept across a restart");
        // Not 64 hex digits, or not text at all: replaced, the coordinator still starts.
        for broken in [
            rusqlite::types::Value::Text("zz".into()),
            rusqlite::types::Value::Blob(vec![1, 2, 3]),
        ] {
            store
                .conn
                .execute(
                    "UPDATE meta SET value = ?1 WHERE key = 'lease_key'",
                    params![broken],
                )
                .unwrap();
            let new = store.lease_key().unwrap();
            assert_ne!(new, key);
            assert_eq!(store.lease_key().unwrap(), new);
        }
    }

    fn job_row(id: &str, seq: u64, state: JobState) -> JobRow {
        JobRow {
            render_version: Some(RENDER_VERSION),
            id: id.into(),
            seq,
            scene: "s".into(),
            settings: "{}".into(),
            priority: 0,
            state,
            error: None,
            created_ms: 1,
            started_ms: None,
            finished_ms: None,
        }
    }

    fn results(store: &Store, job: &str) -> Vec<(u32, Vec<u8>)> {
        let mut out = Vec::new();
        for_each_result(&store.conn, store.results_dir(), job, 0..100, |i, d| {
            out.push((i, d.to_vec()))
        })
        .unwrap();
        out
    }

    fn done(idx: u32) -> TaskRow {
        TaskRow {
            idx,
            state: StoredTask::Done { worker: "w".into() },
            failures: 0,
        }
    }

    /// A database file removed or replaced while the store is open is noticed.
    #[test]
    fn a_database_file_removed_from_under_the_store_is_noticed() {
        let dir = tempfile::tempdir().unwrap();
        let store = Store::open(dir.path()).unwrap();
        assert!(store.check_file());
        std::fs::remove_file(dir.path().join("raytile.sqlite3")).unwrap();
        assert!(!store.check_file());
        // Replaced by another file of the same name: not the one open either.
        std::fs::write(dir.path().join("raytile.sqlite3"), b"").unwrap();
        assert!(!store.check_file());
    }

    /// The pages of a purged job's tiles go back to the file system: the database file
    /// shrinks to about its size before the job, by the purge's own step and then by the
    /// periodic ones.
    #[test]
    fn a_purge_gives_the_pages_of_its_tiles_back() {
        let dir = tempfile::tempdir().unwrap();
        let mut store = Store::open(dir.path()).unwrap();
        let size = |store: &Store| {
            store
                .conn
                .execute_batch("PRAGMA wal_checkpoint(TRUNCATE);")
                .unwrap();
            std::fs::metadata(&store.path).unwrap().len()
        };
        store
            .insert_job(&job_row("j", 0, JobState::Running))
            .unwrap();
        let empty = size(&store);
        // 24 MB of tiles: more than one purge gives back at once.
        let data = vec![7u8; 1 << 20];
        for idx in 0..24 {
            let row = done(idx);
            let write = Write::Result {
                job: "j",
                row: &row,
                data: &data,
                file: None,
            };
            store.write(&[write]).unwrap();
        }
        let full = size(&store);
        assert!(full > 24 << 20, "{full}");
        store.write(&[Write::DeleteJob("j")]).unwrap();
        let purged = size(&store);
        assert!(
            purged <= full - (u64::from(SHRINK_PAGES) * 4096) + (1 << 20),
            "{full} → {purged}"
        );
        assert!(store.free_pages() > 0);
        while store.free_pages() > 0 {
            store.shrink(SHRINK_PAGES);
        }
        let shrunk = size(&store);
        assert!(shrunk < empty + (1 << 20), "{empty} → {full} → {shrunk}");
    }

    /// A database of a release before result files (no `file` column) opens, and its results
    /// read back beside new ones stored as files.
    #[test]
    fn a_database_from_before_result_files_reads_on() {
        let dir = tempfile::tempdir().unwrap();
        let old = Connection::open(dir.path().join("raytile.sqlite3")).unwrap();
        old.execute_batch(
            "CREATE TABLE results (job_id TEXT NOT NULL, idx INTEGER NOT NULL,
                 data BLOB NOT NULL, PRIMARY KEY (job_id, idx));
             INSERT INTO results VALUES ('j', 0, x'0102');",
        )
        .unwrap();
        drop(old);
        let mut store = Store::open(dir.path()).unwrap();
        let staged = Staged::write(dir.path(), &[7, 8, 9]).unwrap();
        let row = done(1);
        store
            .write(&[Write::Result {
                job: "j",
                row: &row,
                data: &[7, 8, 9],
                file: Some(&staged),
            }])
            .unwrap();
        assert_eq!(results(&store, "j"), [(0, vec![1, 2]), (1, vec![7, 8, 9])]);
    }

    /// A write that fails leaves no result file behind, and the staged bytes are gone with
    /// their `Staged`: the worker's retry brings them again.
    #[test]
    fn a_failed_write_leaves_no_result_file() {
        let dir = tempfile::tempdir().unwrap();
        let mut store = Store::open(dir.path()).unwrap();
        let staged = Staged::write(dir.path(), &[1; 64]).unwrap();
        // Staged on the file system of `results/`, which may be a volume of its own: the
        // rename that places it cannot cross file systems.
        assert!(staged.path.starts_with(dir.path().join("results")));
        let row = done(0);
        let write = Write::Result {
            job: "j",
            row: &row,
            data: &[1; 64],
            file: Some(&staged),
        };
        store.faults().fail_next(1);
        assert!(store.write(&[write]).is_err());
        let left: Vec<_> = std::fs::read_dir(dir.path().join("results/j"))
            .unwrap()
            .collect();
        assert!(left.is_empty(), "{left:?}");
        assert!(results(&store, "j").is_empty());
        drop(staged);
        assert_eq!(
            std::fs::read_dir(dir.path().join("results").join(STAGING))
                .unwrap()
                .count(),
            0
        );
    }

    /// A row whose result file is gone is deleted at the next start, and its task queued
    /// again when its job is unfinished: the tile is rendered again, not missing.
    #[test]
    fn a_missing_result_file_queues_its_task_again() {
        let dir = tempfile::tempdir().unwrap();
        let mut store = Store::open(dir.path()).unwrap();
        // A running job; done jobs whose tiles this renderer, an older one and an unknown one
        // made; a cancelled job.
        let jobs = [
            ("run", JobState::Running, Some(RENDER_VERSION)),
            ("fin", JobState::Done, Some(RENDER_VERSION)),
            ("old", JobState::Done, Some(RENDER_VERSION - 1)),
            ("unknown", JobState::Done, None),
            ("cancelled", JobState::Cancelled, Some(RENDER_VERSION)),
        ];
        for (id, state, render_version) in jobs {
            let mut row = job_row(id, 0, state);
            row.render_version = render_version;
            row.finished_ms = state.is_final().then_some(5);
            store.insert_job(&row).unwrap();
            for idx in 0..2 {
                let staged = Staged::write(dir.path(), &[idx as u8; 8]).unwrap();
                let row = done(idx);
                store
                    .write(&[Write::Result {
                        job: id,
                        row: &row,
                        data: &[],
                        file: Some(&staged),
                    }])
                    .unwrap();
            }
        }
        drop(store);
        for (job, ..) in jobs {
            let first = std::fs::read_dir(dir.path().join("results").join(job))
                .unwrap()
                .flatten()
                .map(|e| e.path())
                .find(|p| p.file_name().unwrap().to_string_lossy().starts_with("0-"))
                .unwrap();
            std::fs::remove_file(first).unwrap();
        }
        let mut store = Store::open(dir.path()).unwrap();
        assert_eq!(store.requeue_missing_files().unwrap(), 0, "done at open");
        let states = |job| -> Vec<StoredTask> {
            store
                .tasks(job)
                .unwrap()
                .into_iter()
                .map(|t| t.state)
                .collect()
        };
        let done_w = StoredTask::Done { worker: "w".into() };
        let rows = store.jobs().unwrap();
        for (job, state, _) in jobs {
            assert_eq!(results(&store, job), [(1, vec![1; 8])], "{job}");
            // The cancelled job keeps its state, the task queued for a retry.
            let repaired = matches!(job, "run" | "fin" | "cancelled");
            let expected = if repaired {
                [StoredTask::Queued, done_w.clone()]
            } else {
                [done_w.clone(), done_w.clone()]
            };
            assert_eq!(states(job), expected, "{job}");
            let row = rows.iter().find(|r| r.id == job).unwrap();
            // The done job this renderer made runs again until the tile is made again.
            let state = if job == "fin" {
                JobState::Running
            } else {
                state
            };
            assert_eq!(row.state, state, "{job}");
            assert_eq!(row.finished_ms.is_some(), state.is_final(), "{job}");
        }
    }

    /// A database that names result files beside no `results/` folder (a volume not mounted)
    /// is refused, naming the folder; once the folder is there, empty, it starts and queues
    /// those tiles again.
    #[test]
    fn result_files_named_beside_no_results_folder_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let mut store = Store::open(dir.path()).unwrap();
        store
            .insert_job(&job_row("j", 0, JobState::Running))
            .unwrap();
        let staged = Staged::write(dir.path(), &[1; 8]).unwrap();
        let row = done(0);
        store
            .write(&[Write::Result {
                job: "j",
                row: &row,
                data: &[],
                file: Some(&staged),
            }])
            .unwrap();
        drop(store);
        let results = dir.path().join("results");
        std::fs::remove_dir_all(&results).unwrap();
        let e = Store::open(dir.path()).err().expect("refused").to_string();
        assert!(
            e.contains("names 1 result file") && e.contains(&results.display().to_string()),
            "{e}"
        );
        assert!(!results.exists(), "not made by a refused start");
        std::fs::create_dir(&results).unwrap();
        let store = Store::open(dir.path()).unwrap();
        assert_eq!(store.tasks("j").unwrap()[0].state, StoredTask::Queued);
    }

    /// A stored result whose bytes changed on disk or in the database (its checksum differs)
    /// is not handed out as a tile but named as damaged, like a missing file.
    #[test]
    fn a_damaged_result_is_named_not_read() {
        let dir = tempfile::tempdir().unwrap();
        let mut store = Store::open(dir.path()).unwrap();
        store
            .insert_job(&job_row("j", 0, JobState::Running))
            .unwrap();
        for idx in 0..4 {
            let bytes = [idx as u8 + 1; 8];
            // Tasks 0 and 1 inline, 2 and 3 as files.
            let staged = (idx >= 2).then(|| Staged::write(dir.path(), &bytes).unwrap());
            let row = done(idx);
            store
                .write(&[Write::Result {
                    job: "j",
                    row: &row,
                    data: &bytes,
                    file: staged.as_ref(),
                }])
                .unwrap();
        }
        let read = |store: &Store| {
            let mut got = Vec::new();
            let lost = for_each_result(&store.conn, &store.results, "j", 0..4, |i, d| {
                got.push((i, d.to_vec()))
            })
            .unwrap();
            (got.into_iter().map(|(i, _)| i).collect::<Vec<_>>(), lost)
        };
        assert_eq!(read(&store), (vec![0, 1, 2, 3], vec![]));
        // One byte of task 1's blob, and of task 3's file, changed.
        store
            .conn
            .execute(
                "UPDATE results SET data = x'0202020202020203' WHERE job_id = 'j' AND idx = 1",
                [],
            )
            .unwrap();
        let file: String = store
            .conn
            .query_row("SELECT file FROM results WHERE idx = 3", [], |r| r.get(0))
            .unwrap();
        std::fs::write(store.results.join(&file), [4, 4, 4, 4, 0, 4, 4, 4]).unwrap();
        assert_eq!(read(&store), (vec![0, 2], vec![1, 3]));
        // Dropped, a result's row and its file go, and its task is queued.
        let queued = TaskRow {
            idx: 3,
            state: StoredTask::Queued,
            failures: 0,
        };
        store
            .write(&[Write::DropResult {
                job: "j",
                row: &queued,
            }])
            .unwrap();
        let gone = std::time::Instant::now();
        while store.results.join(&file).exists() && gone.elapsed().as_secs() < 10 {
            std::thread::sleep(std::time::Duration::from_millis(10));
        }
        assert!(!store.results.join(&file).exists(), "removed, on a thread");
        assert_eq!(read(&store), (vec![0, 2], vec![1]));
        assert_eq!(store.tasks("j").unwrap()[3].state, StoredTask::Queued);
        // A row from before checksums (no sum) is read as it is.
        store
            .conn
            .execute("UPDATE results SET sum = NULL WHERE idx = 1", [])
            .unwrap();
        assert_eq!(read(&store), (vec![0, 1, 2], vec![]));
        // Columns that do not read as their types: a sum past 32 bits, text for bytes.
        store
            .conn
            .execute(
                "UPDATE results SET sum = sum + 4294967296 WHERE idx = 0",
                [],
            )
            .unwrap();
        store
            .conn
            .execute(
                "UPDATE results SET data = CAST(data AS TEXT) WHERE idx = 1",
                [],
            )
            .unwrap();
        assert_eq!(read(&store), (vec![2], vec![0, 1]));
    }

    /// A database lost or emptied beside the result files of its jobs is refused at start,
    /// naming both, rather than those files deleted as named by no row; moved aside, the
    /// results no longer stop a start, and an interrupted purge's folder never did. A
    /// `results/.staging/` removed while the coordinator runs is made again by the next result.
    #[test]
    fn results_without_their_database_are_refused_not_deleted() {
        let dir = tempfile::tempdir().unwrap();
        let mut store = Store::open(dir.path()).unwrap();
        store
            .insert_job(&job_row("j", 0, JobState::Running))
            .unwrap();
        assert!(!dir.path().join("results").join(STAGING).exists());
        let staged = Staged::write(dir.path(), &[5; 8]).unwrap();
        let row = done(0);
        store
            .write(&[Write::Result {
                job: "j",
                row: &row,
                data: &[],
                file: Some(&staged),
            }])
            .unwrap();
        drop(store);
        let db = dir.path().join("raytile.sqlite3");
        for lose in [
            |db: &Path| std::fs::remove_file(db).unwrap(),
            |db: &Path| std::fs::File::create(db).map(drop).unwrap(),
        ] {
            lose(&db);
            let _ = std::fs::remove_file(dir.path().join("raytile.sqlite3-wal"));
            let e = Store::open(dir.path()).err().expect("refused").to_string();
            assert!(
                e.contains("a new database")
                    && e.contains("results of 1 job")
                    && e.contains("backup"),
                "{e}"
            );
            let kept = dir.path().join("results").join("j");
            assert_eq!(std::fs::read_dir(&kept).unwrap().count(), 1, "kept");
        }
        // A database that knows other jobs (an older backup, another farm's): the results of
        // the job it does not know are set aside, not deleted.
        let elsewhere = dir.path().join("elsewhere");
        std::fs::create_dir(&elsewhere).unwrap();
        let mut other = Store::open(&elsewhere).unwrap();
        other.insert_job(&job_row("k", 1, JobState::Done)).unwrap();
        drop(other);
        std::fs::rename(elsewhere.join("raytile.sqlite3"), &db).unwrap();
        let _ = std::fs::remove_file(dir.path().join("raytile.sqlite3-wal"));
        Store::open(dir.path()).unwrap();
        let aside = dir.path().join("results").join(".orphaned").join("j");
        assert_eq!(std::fs::read_dir(&aside).unwrap().count(), 1, "set aside");
        assert!(!dir.path().join("results").join("j").exists());
        // Set aside (or an interrupted purge's leftovers): a new database starts.
        std::fs::remove_file(&db).unwrap();
        Store::open(dir.path()).unwrap();
        // Jobs whose results all live in the database leave none in `results/`: uploaded
        // scenes beside a new database say it was lost as well.
        let scene = dir.path().join("scenes").join("s-1");
        std::fs::create_dir_all(&scene).unwrap();
        std::fs::write(scene.join("meta.json"), "{}").unwrap();
        std::fs::remove_file(&db).unwrap();
        let _ = std::fs::remove_file(dir.path().join("raytile.sqlite3-wal"));
        let e = Store::open(dir.path()).err().expect("refused").to_string();
        assert!(e.contains("the 1 scene(s) uploaded to it"), "{e}");
    }

    /// A full disk while a result is staged or placed reads as SQLite's own full disk, which
    /// the API answers 503 `store_unavailable`, retryable: the worker sends the result again.
    #[test]
    fn a_full_disk_reads_as_the_stores_own() {
        let full = io_error(std::io::Error::from_raw_os_error(libc::ENOSPC));
        assert_eq!(
            full.sqlite_error_code(),
            Some(rusqlite::ErrorCode::DiskFull),
            "{full}"
        );
        let other = io_error(std::io::Error::from_raw_os_error(libc::EIO));
        assert_eq!(
            other.sqlite_error_code(),
            Some(rusqlite::ErrorCode::SystemIoFailure)
        );
        let answer = crate::error::AppError::StoreUnavailable(full).into_response();
        assert_eq!(answer.status(), axum::http::StatusCode::SERVICE_UNAVAILABLE);
    }
}
