//! The one way the scene loaders read files. Every file a scene names (a JSON scene's
//! textures, environment map and glTF includes; a glTF file's buffers and images) and the scene
//! file itself are read through a [`SceneFiles`], which applies its [`FilePolicy`]:
//!
//! - [`FilePolicy::Trusted`], for a scene on the user's own machine (`raytile render`): a JSON
//!   scene's paths may be absolute or lead out of its folder (they name the user's own files).
//! - [`FilePolicy::Confined`], for anything that came over the network (the coordinator
//!   validating an upload, a worker rendering a lease) and for what `raytile submit` is about
//!   to send: relative paths inside the scene's root only. No absolute path, no `..` leading
//!   out of the root, no symbolic link leading out of it (the path is canonicalised and must
//!   keep the canonical root as its prefix), and a budget of bytes read for the scene as a
//!   whole.
//!
//! Under both policies:
//! - a glTF URI stays inside the glTF file's own folder (a downloaded model must not read its
//!   user's files; the glTF loader checks the URI's syntax, this module where it leads);
//! - only regular files are read: the type is checked before the file is opened, the file is
//!   opened without blocking and without following a link, and the type is checked again on
//!   the open handle, so a FIFO cannot hang a thread and a device cannot be read;
//! - every read is bounded by `Read::take`, so a file that grows, a special file or a sparse
//!   file cannot defeat the size check made from its metadata;
//! - a scene file that includes itself, directly or through other files, is refused;
//! - the memory that decoding takes (texels, vertices, indices) is charged to one budget for
//!   the whole scene before it is allocated.
//!
//! The resolver records every file it read ([`SceneFiles::used`]: `raytile submit` packs
//! exactly those) and the first refusal ([`SceneFiles::refusal`], whose
//! [`Refusal::hint`] says how to fix the scene).

use std::cell::{Cell, RefCell};
use std::fs::File;
use std::io::Read;
use std::path::{Component, Path, PathBuf};

/// Largest file read under [`FilePolicy::Trusted`] (4 GiB).
pub const TRUSTED_FILE_CAP: u64 = 1 << 32;
/// Default largest file of a confined scene (1 GiB).
pub const DEFAULT_FILE_CAP: u64 = 1 << 30;
/// Default most bytes read for a confined scene, all its files together (2 GiB).
pub const DEFAULT_SCENE_BUDGET: u64 = 2 << 30;
/// Default memory the loaders may allocate for a scene's decoded data (8 GiB).
pub const DEFAULT_MEMORY_LIMIT: u64 = 8 << 30;

/// Where a scene's files may come from.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum FilePolicy {
    /// The user's own scene on the user's own machine: JSON paths may be absolute or leave the
    /// scene's folder. Regular files only, each at most [`TRUSTED_FILE_CAP`] bytes.
    Trusted,
    /// A scene from the network: every file inside `root`.
    Confined {
        /// The scene's root folder (the scene file's own folder).
        root: PathBuf,
        /// Largest file read, in bytes.
        per_file_cap: u64,
        /// Most bytes read for the scene, all its files together (a file read twice counts
        /// twice).
        scene_budget: u64,
    },
}

impl FilePolicy {
    /// Confined to `root` with the default caps.
    pub fn confined(root: impl Into<PathBuf>) -> FilePolicy {
        FilePolicy::Confined {
            root: root.into(),
            per_file_cap: DEFAULT_FILE_CAP,
            scene_budget: DEFAULT_SCENE_BUDGET,
        }
    }
}

/// Why a file was not read.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Refusal {
    /// An absolute path in a confined scene.
    Absolute,
    /// `..` leads out of the scene's root.
    LeavesRoot,
    /// The path, after symbolic links, ends outside the scene's root.
    OutsideRoot,
    /// A glTF URI that, after symbolic links, ends outside the glTF file's folder.
    OutsideFolder,
    /// A glTF URI with `..` (glTF URIs stay in the file's folder).
    ParentInUri,
    /// A glTF URI with a scheme (`file:`, `http:`): only `data:` URIs and relative paths.
    Scheme,
    /// A name that cannot be a relative path: empty, NUL, backslash, ':', percent-encoding
    /// that is not UTF-8. The text says which.
    BadName(&'static str),
    /// Not a regular file: the kind found (a folder, a FIFO, a device...).
    NotRegular(&'static str),
    /// Larger than a file may be.
    TooLarge {
        /// The file's size (or the bytes read before it was cut off).
        bytes: u64,
        /// The cap.
        cap: u64,
    },
    /// The scene's files together are larger than its budget.
    OverBudget {
        /// The budget, in bytes.
        budget: u64,
    },
    /// The scene includes itself: the chain of files, outermost first.
    IncludesItself(Vec<String>),
    /// A glTF file loaded from memory names an external file.
    NoFolder,
    /// The file could not be read (missing, no permission): the system's message.
    Unreadable(String),
}

impl std::fmt::Display for Refusal {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Refusal::Absolute => f.write_str(
                "absolute paths are refused: a scene names its files relative to its \
                     folder, so that it renders the same on any machine",
            ),
            Refusal::LeavesRoot => f.write_str("'..' leads out of the scene's folder"),
            Refusal::OutsideRoot => f.write_str(
                "it resolves outside the scene's folder (a symbolic link leads out of it)",
            ),
            Refusal::OutsideFolder => f.write_str(
                "it resolves outside the glTF file's folder (a symbolic link leads out of it)",
            ),
            Refusal::ParentInUri => f.write_str("'..' is refused in a glTF URI"),
            Refusal::Scheme => {
                f.write_str("URIs with a scheme are refused (only data: URIs and relative paths)")
            }
            Refusal::BadName(why) => f.write_str(why),
            Refusal::NotRegular(kind) => write!(f, "not a regular file (a {kind})"),
            Refusal::TooLarge { bytes, cap } => {
                write!(
                    f,
                    "{bytes} bytes or more, over the {cap} bytes a file may have"
                )
            }
            Refusal::OverBudget { budget } => write!(
                f,
                "the scene's files together are over the {budget} bytes a scene may read"
            ),
            Refusal::IncludesItself(chain) => {
                write!(f, "the scene includes itself ({})", chain.join(" → "))
            }
            Refusal::NoFolder => f.write_str("the scene was not loaded from a folder"),
            Refusal::Unreadable(e) => write!(f, "cannot read it: {e}"),
        }
    }
}

impl Refusal {
    /// How the scene's author can fix it, for `raytile submit`.
    pub fn hint(&self) -> Option<&'static str> {
        Some(match self {
            Refusal::Absolute | Refusal::OutsideRoot | Refusal::OutsideFolder | Refusal::NoFolder => {
                "copy the file next to the scene (or into a folder below it) and name it relative to the scene"
            }
            Refusal::LeavesRoot | Refusal::ParentInUri => {
                "remove the '..': copy the file into the scene's folder and name it relative to the scene"
            }
            Refusal::Scheme | Refusal::BadName(_) => {
                "name the file with a plain relative path such as \"textures/wood.png\""
            }
            Refusal::NotRegular(_) => "name a regular file",
            Refusal::TooLarge { .. } | Refusal::OverBudget { .. } => {
                "make the files smaller (or ask the farm's operator for larger limits)"
            }
            Refusal::IncludesItself(_) => "remove the include that leads back to the scene",
            Refusal::Unreadable(_) => return None,
        })
    }
}

/// A file a scene names that was not read: where the scene names it, the name, and why.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FileError {
    /// Where the scene names the file: a JSON path (`textures.wood.path`) or a glTF field
    /// (`buffers[0].uri`); empty for the scene file itself.
    pub field: String,
    /// The name as the scene writes it, quoted and shortened for messages.
    pub path: String,
    /// Why it was not read.
    pub refusal: Refusal,
}

impl FileError {
    /// The message without the field (for loaders that name the field their own way).
    pub fn describe(&self) -> String {
        match &self.refusal {
            Refusal::Unreadable(e) => format!("cannot read {}: {e}", self.path),
            r => format!("{} refused: {r}", self.path),
        }
    }
}

impl std::fmt::Display for FileError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if self.field.is_empty() {
            f.write_str(&self.describe())
        } else {
            write!(f, "{}: {}", self.field, self.describe())
        }
    }
}

impl std::error::Error for FileError {}

/// A file the resolver read.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct UsedFile {
    /// The file as opened (canonical: no symbolic link, no `..`).
    pub path: PathBuf,
    /// Under the confined policy, its name relative to the root as the scene reaches it (a
    /// link inside the root keeps its own name, so that a copy of the files under these names
    /// loads the same); `None` under [`FilePolicy::Trusted`].
    pub name: Option<PathBuf>,
    /// Its size in bytes.
    pub bytes: u64,
}

/// A name resolved to a file, not yet read.
#[derive(Debug)]
pub(crate) struct Resolved {
    /// The path as named (joined to its base; `..` removed lexically under the confined
    /// policy): relative names inside the file resolve against its folder.
    pub named: PathBuf,
    /// The canonical path, which is opened.
    pub canonical: PathBuf,
    /// The name relative to the confined root, as the scene reaches the file.
    pub name: Option<PathBuf>,
    /// The name for messages.
    pub shown: String,
}

/// A name shortened and quoted for messages (hostile scenes may hold huge or odd names).
pub(crate) fn show(name: &str) -> String {
    let short: String = name.chars().take(200).collect();
    format!("{short:?}")
}

/// The resolver: a [`FilePolicy`], the budgets of one scene, and what was read. Make one per
/// scene load; it is not shared between threads.
#[derive(Debug)]
pub struct SceneFiles {
    policy: FilePolicy,
    /// The canonical root, under the confined policy.
    root: Option<PathBuf>,
    per_file_cap: u64,
    scene_budget: u64,
    read_left: Cell<u64>,
    memory_limit: u64,
    memory_left: Cell<u64>,
    used: RefCell<Vec<UsedFile>>,
    /// The scene files being loaded, outermost first (canonical paths): includes are checked
    /// against it.
    loading: RefCell<Vec<PathBuf>>,
    refusal: RefCell<Option<FileError>>,
}

impl SceneFiles {
    /// A resolver with `policy`; the confined root must be an existing folder.
    pub fn new(policy: FilePolicy) -> std::io::Result<SceneFiles> {
        let (root, per_file_cap, scene_budget) = match &policy {
            FilePolicy::Trusted => (None, TRUSTED_FILE_CAP, u64::MAX),
            FilePolicy::Confined {
                root,
                per_file_cap,
                scene_budget,
            } => {
                let canonical = std::fs::canonicalize(root)?;
                if !canonical.is_dir() {
                    return Err(std::io::Error::new(
                        std::io::ErrorKind::InvalidInput,
                        format!("{} is not a folder", root.display()),
                    ));
                }
                (Some(canonical), *per_file_cap, *scene_budget)
            }
        };
        Ok(SceneFiles {
            policy,
            root,
            per_file_cap,
            scene_budget,
            read_left: Cell::new(scene_budget),
            memory_limit: DEFAULT_MEMORY_LIMIT,
            memory_left: Cell::new(DEFAULT_MEMORY_LIMIT),
            used: RefCell::new(Vec::new()),
            loading: RefCell::new(Vec::new()),
            refusal: RefCell::new(None),
        })
    }

    /// The resolver of `raytile render`: [`FilePolicy::Trusted`].
    pub fn trusted() -> SceneFiles {
        SceneFiles::new(FilePolicy::Trusted).expect("the trusted policy has no root to check")
    }

    /// A resolver confined to the folder of `scene` (the scene file), with `per_file_cap` and
    /// `scene_budget`: what the coordinator, the workers and `raytile submit` use.
    pub fn confined_to_scene(
        scene: &Path,
        per_file_cap: u64,
        scene_budget: u64,
    ) -> std::io::Result<SceneFiles> {
        SceneFiles::new(FilePolicy::Confined {
            root: folder_of(scene).to_path_buf(),
            per_file_cap,
            scene_budget,
        })
    }

    /// Sets the memory the loaders may allocate for the scene's decoded data (texels,
    /// vertices, indices, objects); default [`DEFAULT_MEMORY_LIMIT`].
    pub fn with_memory_limit(mut self, bytes: u64) -> SceneFiles {
        self.memory_limit = bytes;
        self.memory_left = Cell::new(bytes);
        self
    }

    /// The policy.
    pub fn policy(&self) -> &FilePolicy {
        &self.policy
    }

    /// The canonical root of a confined resolver.
    pub fn root(&self) -> Option<&Path> {
        self.root.as_deref()
    }

    /// Every file read so far (each once, in the order first read; the scene file first).
    pub fn used(&self) -> Vec<UsedFile> {
        self.used.borrow().clone()
    }

    /// Bytes read so far, all files together.
    pub fn bytes_read(&self) -> u64 {
        self.scene_budget - self.read_left.get()
    }

    /// The first file refused, if any.
    pub fn refusal(&self) -> Option<FileError> {
        self.refusal.borrow().clone()
    }

    fn refuse(&self, field: &str, shown: &str, refusal: Refusal) -> FileError {
        let e = FileError {
            field: field.to_string(),
            path: shown.to_string(),
            refusal,
        };
        self.refusal.borrow_mut().get_or_insert_with(|| e.clone());
        e
    }

    /// Records a refusal found by a loader (a glTF URI's syntax) and returns it.
    pub(crate) fn refused(&self, field: &str, shown: &str, refusal: Refusal) -> FileError {
        self.refuse(field, shown, refusal)
    }

    /// Takes `bytes` from the scene's memory budget, or says which part of the scene (`what`)
    /// went over it.
    pub(crate) fn charge_memory(&self, bytes: u64, what: &str) -> Result<(), String> {
        let left = self.memory_left.get();
        if bytes > left {
            return Err(format!(
                "{what}: the scene needs more memory than the {} bytes the loader may use",
                self.memory_limit
            ));
        }
        self.memory_left.set(left - bytes);
        Ok(())
    }

    /// Gives back `bytes` taken by [`SceneFiles::charge_memory`] for memory that is freed
    /// (the tree of a parsed JSON text).
    pub(crate) fn release_memory(&self, bytes: u64) {
        let left = self.memory_left.get().saturating_add(bytes);
        self.memory_left.set(left.min(self.memory_limit));
    }

    /// Checks that `len` bytes held in the scene itself (a `data:` URI) are within the
    /// per-file cap, before they are decoded.
    pub(crate) fn check_inline(&self, field: &str, shown: &str, len: u64) -> Result<(), FileError> {
        if len > self.per_file_cap {
            return Err(self.refuse(
                field,
                shown,
                Refusal::TooLarge {
                    bytes: len,
                    cap: self.per_file_cap,
                },
            ));
        }
        Ok(())
    }

    /// Reads the scene file itself (`path` as the program was given it). Under the confined
    /// policy it must be inside the root.
    pub(crate) fn read_scene(
        &self,
        path: &Path,
        cap: u64,
    ) -> Result<(Resolved, Vec<u8>), FileError> {
        let shown = show(&path.to_string_lossy());
        let canonical = std::fs::canonicalize(path)
            .map_err(|e| self.refuse("", &shown, Refusal::Unreadable(e.to_string())))?;
        let mut name = None;
        if let Some(root) = &self.root {
            if !canonical.starts_with(root) {
                return Err(self.refuse("", &shown, Refusal::OutsideRoot));
            }
            let folder = self
                .relative_folder(folder_of(path))
                .ok_or_else(|| self.refuse("", &shown, Refusal::OutsideRoot))?;
            name = path.file_name().map(|n| folder.join(n));
        }
        let r = Resolved {
            named: path.to_path_buf(),
            canonical,
            name,
            shown,
        };
        let bytes = self.read(&r, "", cap)?;
        Ok((r, bytes))
    }

    /// Resolves a path a JSON scene names at `field`, relative to `base` (the folder of the
    /// JSON file).
    pub(crate) fn resolve_path(
        &self,
        base: &Path,
        path: &Path,
        field: &str,
    ) -> Result<Resolved, FileError> {
        let shown = show(&path.to_string_lossy());
        let Some(root) = &self.root else {
            let named = if path.is_absolute() {
                path.to_path_buf()
            } else {
                base.join(path)
            };
            let canonical = std::fs::canonicalize(&named)
                .map_err(|e| self.refuse(field, &shown, Refusal::Unreadable(e.to_string())))?;
            return Ok(Resolved {
                named,
                canonical,
                name: None,
                shown,
            });
        };
        if path.has_root() || path.is_absolute() {
            return Err(self.refuse(field, &shown, Refusal::Absolute));
        }
        let base = std::fs::canonicalize(base)
            .map_err(|e| self.refuse(field, &shown, Refusal::Unreadable(e.to_string())))?;
        let rel_base = base
            .strip_prefix(root)
            .map_err(|_| self.refuse(field, &shown, Refusal::OutsideRoot))?;
        // `..` is taken lexically, against the root: it can never climb above it.
        let mut parts: Vec<&std::ffi::OsStr> =
            rel_base.components().map(|c| c.as_os_str()).collect();
        for c in path.components() {
            match c {
                Component::Normal(p) => parts.push(p),
                Component::CurDir => {}
                Component::ParentDir => {
                    if parts.pop().is_none() {
                        return Err(self.refuse(field, &shown, Refusal::LeavesRoot));
                    }
                }
                Component::RootDir | Component::Prefix(_) => {
                    return Err(self.refuse(field, &shown, Refusal::Absolute))
                }
            }
        }
        let name: PathBuf = parts.iter().collect();
        let named = root.join(&name);
        let canonical = std::fs::canonicalize(&named)
            .map_err(|e| self.refuse(field, &shown, Refusal::Unreadable(e.to_string())))?;
        if !canonical.starts_with(root) {
            return Err(self.refuse(field, &shown, Refusal::OutsideRoot));
        }
        Ok(Resolved {
            named,
            canonical,
            name: Some(name),
            shown,
        })
    }

    /// Resolves `rel`, a relative path without `..` from a glTF URI (`shown` as the file
    /// writes it), inside `folder`, the glTF file's folder.
    pub(crate) fn resolve_in_folder(
        &self,
        folder: &Path,
        rel: &Path,
        field: &str,
        shown: &str,
    ) -> Result<Resolved, FileError> {
        let folder_canonical = std::fs::canonicalize(folder)
            .map_err(|e| self.refuse(field, shown, Refusal::Unreadable(e.to_string())))?;
        let named = folder.join(rel);
        let canonical = std::fs::canonicalize(&named)
            .map_err(|e| self.refuse(field, shown, Refusal::Unreadable(e.to_string())))?;
        if !canonical.starts_with(&folder_canonical) {
            return Err(self.refuse(field, shown, Refusal::OutsideFolder));
        }
        let mut name = None;
        if let Some(root) = &self.root {
            if !canonical.starts_with(root) {
                return Err(self.refuse(field, shown, Refusal::OutsideRoot));
            }
            let folder = self
                .relative_folder(folder)
                .ok_or_else(|| self.refuse(field, shown, Refusal::OutsideRoot))?;
            name = Some(folder.join(rel));
        }
        Ok(Resolved {
            named,
            canonical,
            name,
            shown: shown.to_string(),
        })
    }

    /// A folder's name relative to the confined root: lexically when it is written under the
    /// root (the folders the resolver made), else from its canonical path (the folder of the
    /// scene file as the program was given it).
    fn relative_folder(&self, folder: &Path) -> Option<PathBuf> {
        let root = self.root.as_ref()?;
        if let Ok(rel) = folder.strip_prefix(root) {
            return Some(rel.to_path_buf());
        }
        let canonical = std::fs::canonicalize(folder).ok()?;
        canonical.strip_prefix(root).ok().map(Path::to_path_buf)
    }

    /// Marks `r` (a scene file: the scene, or a file it includes) as being loaded; refuses it
    /// if it already is (the scene includes itself). Pair with [`SceneFiles::leave`].
    pub(crate) fn enter(&self, r: &Resolved, field: &str) -> Result<(), FileError> {
        let mut loading = self.loading.borrow_mut();
        if let Some(at) = loading.iter().position(|p| *p == r.canonical) {
            let chain = loading[at..]
                .iter()
                .chain(std::iter::once(&r.canonical))
                .map(|p| {
                    p.file_name().map_or_else(
                        || p.display().to_string(),
                        |n| n.to_string_lossy().into_owned(),
                    )
                })
                .collect();
            drop(loading);
            return Err(self.refuse(field, &r.shown, Refusal::IncludesItself(chain)));
        }
        loading.push(r.canonical.clone());
        Ok(())
    }

    /// Ends what [`SceneFiles::enter`] began.
    pub(crate) fn leave(&self) {
        self.loading.borrow_mut().pop();
    }

    /// Reads a resolved file, at most `cap` bytes (and at most the policy's per-file cap and
    /// what is left of the scene's budget).
    pub(crate) fn read(&self, r: &Resolved, field: &str, cap: u64) -> Result<Vec<u8>, FileError> {
        let refuse = |refusal| self.refuse(field, &r.shown, refusal);
        // The canonical path has no link left in it: its own type is the file's.
        let meta = std::fs::symlink_metadata(&r.canonical)
            .map_err(|e| refuse(Refusal::Unreadable(e.to_string())))?;
        if let Some(kind) = not_regular(&meta.file_type()) {
            return Err(refuse(Refusal::NotRegular(kind)));
        }
        let file =
            open_no_block(&r.canonical).map_err(|e| refuse(Refusal::Unreadable(e.to_string())))?;
        // Again on the handle: the path may have been replaced since.
        let meta = file
            .metadata()
            .map_err(|e| refuse(Refusal::Unreadable(e.to_string())))?;
        if let Some(kind) = not_regular(&meta.file_type()) {
            return Err(refuse(Refusal::NotRegular(kind)));
        }
        let cap = cap.min(self.per_file_cap);
        let left = self.read_left.get();
        let check = |n: u64| {
            if n > cap {
                Err(refuse(Refusal::TooLarge { bytes: n, cap }))
            } else if n > left {
                Err(refuse(Refusal::OverBudget {
                    budget: self.scene_budget,
                }))
            } else {
                Ok(())
            }
        };
        // The size the file claims, before reading anything: a sparse 10 GiB file is refused
        // at once.
        check(meta.len())?;
        let limit = cap.min(left);
        let mut bytes = Vec::with_capacity(meta.len() as usize);
        file.take(limit.saturating_add(1))
            .read_to_end(&mut bytes)
            .map_err(|e| refuse(Refusal::Unreadable(e.to_string())))?;
        // What was read: a file may be longer than it claimed.
        check(bytes.len() as u64)?;
        self.read_left.set(left - bytes.len() as u64);
        self.note_used(r, bytes.len() as u64);
        Ok(bytes)
    }

    /// Records that the scene uses the file `r` (of `bytes` bytes) by its name, once per name:
    /// what [`SceneFiles::read`] records, for a file whose contents the caller already holds
    /// (an image a JSON scene names twice, once through a link).
    pub(crate) fn note_used(&self, r: &Resolved, bytes: u64) {
        let mut used = self.used.borrow_mut();
        if !used
            .iter()
            .any(|u| u.path == r.canonical && u.name == r.name)
        {
            used.push(UsedFile {
                path: r.canonical.clone(),
                name: r.name.clone(),
                bytes,
            });
        }
    }
}

/// The folder of a file (`.` for a bare file name).
pub(crate) fn folder_of(path: &Path) -> &Path {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    }
}

/// What a file type is, when it is not a regular file.
fn not_regular(t: &std::fs::FileType) -> Option<&'static str> {
    if t.is_file() {
        return None;
    }
    if t.is_dir() {
        return Some("folder");
    }
    if t.is_symlink() {
        return Some("symbolic link");
    }
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        if t.is_fifo() {
            return Some("FIFO");
        }
        if t.is_socket() {
            return Some("socket");
        }
        if t.is_char_device() || t.is_block_device() {
            return Some("device");
        }
    }
    Some("special file")
}

/// Opens a file for reading without blocking (a FIFO would otherwise wait for a writer) and
/// without following a final symbolic link.
fn open_no_block(path: &Path) -> std::io::Result<File> {
    let mut o = std::fs::OpenOptions::new();
    o.read(true);
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt;
        o.custom_flags(libc::O_NONBLOCK | libc::O_NOFOLLOW);
    }
    o.open(path)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A folder of its own under the system's temporary folder, removed when dropped.
    struct TempDir(PathBuf);

    impl TempDir {
        fn new(tag: &str) -> TempDir {
            let d =
                std::env::temp_dir().join(format!("raytile-files-{tag}-{}", std::process::id()));
            let _ = std::fs::remove_dir_all(&d);
            std::fs::create_dir_all(d.join("scene/sub")).unwrap();
            std::fs::write(d.join("secret.txt"), b"secret").unwrap();
            std::fs::write(d.join("scene/a.txt"), b"aaaa").unwrap();
            std::fs::write(d.join("scene/sub/b.txt"), b"bb").unwrap();
            TempDir(d)
        }
    }

    impl Drop for TempDir {
        fn drop(&mut self) {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }

    fn confined(root: &Path, per_file_cap: u64, scene_budget: u64) -> SceneFiles {
        SceneFiles::new(FilePolicy::Confined {
            root: root.to_path_buf(),
            per_file_cap,
            scene_budget,
        })
        .unwrap()
    }

    /// Reads `name` as a JSON scene in `base` would name it.
    fn read(files: &SceneFiles, base: &Path, name: &str) -> Result<Vec<u8>, Refusal> {
        files
            .resolve_path(base, Path::new(name), "textures.t.path")
            .and_then(|r| files.read(&r, "textures.t.path", u64::MAX))
            .map_err(|e| e.refusal)
    }

    #[test]
    fn confined_paths_stay_in_the_root() {
        let t = TempDir::new("paths");
        let root = t.0.join("scene");
        let sub = root.join("sub");
        let files = confined(&root, 1 << 20, 1 << 20);
        assert_eq!(read(&files, &root, "a.txt").unwrap(), b"aaaa");
        assert_eq!(read(&files, &root, "./sub/../a.txt").unwrap(), b"aaaa");
        // `..` inside the root is fine; out of it is not, however it is spelt.
        assert_eq!(read(&files, &sub, "../a.txt").unwrap(), b"aaaa");
        assert_eq!(
            read(&files, &root, "../secret.txt"),
            Err(Refusal::LeavesRoot)
        );
        assert_eq!(
            read(&files, &sub, "../../secret.txt"),
            Err(Refusal::LeavesRoot)
        );
        assert_eq!(
            read(&files, &root, "sub/../../secret.txt"),
            Err(Refusal::LeavesRoot)
        );
        let abs = t.0.join("secret.txt");
        assert_eq!(
            read(&files, &root, &abs.to_string_lossy()),
            Err(Refusal::Absolute)
        );
        // Even an absolute path into the root: the scene must not know where it lands.
        let abs = root.join("a.txt");
        assert_eq!(
            read(&files, &root, &abs.to_string_lossy()),
            Err(Refusal::Absolute)
        );
        assert!(matches!(
            read(&files, &root, "missing.txt"),
            Err(Refusal::Unreadable(_))
        ));
        // Each file once, named relative to the root, the first refusal kept.
        let used = files.used();
        assert_eq!(used.len(), 1);
        assert_eq!(used[0].name.as_deref(), Some(Path::new("a.txt")));
        assert_eq!(used[0].bytes, 4);
        assert_eq!(files.bytes_read(), 12);
        let first = files.refusal().unwrap();
        assert_eq!(first.refusal, Refusal::LeavesRoot);
        assert_eq!(first.field, "textures.t.path");
        assert_eq!(first.path, "\"../secret.txt\"");
        assert!(first.refusal.hint().unwrap().contains("'..'"));
        assert_eq!(
            first.to_string(),
            "textures.t.path: \"../secret.txt\" refused: '..' leads out of the scene's folder"
        );
    }

    #[cfg(unix)]
    #[test]
    fn links_out_of_the_root_and_special_files_are_refused() {
        let t = TempDir::new("links");
        let root = t.0.join("scene");
        std::os::unix::fs::symlink(t.0.join("secret.txt"), root.join("link.txt")).unwrap();
        std::os::unix::fs::symlink(&t.0, root.join("up")).unwrap();
        std::os::unix::fs::symlink("a.txt", root.join("inside.txt")).unwrap();
        std::os::unix::fs::symlink("/dev/zero", root.join("zero.png")).unwrap();
        let fifo = root.join("fifo.png");
        let c = std::ffi::CString::new(fifo.to_string_lossy().as_bytes()).unwrap();
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o644) }, 0);
        let files = confined(&root, 1 << 20, 1 << 20);
        assert_eq!(read(&files, &root, "link.txt"), Err(Refusal::OutsideRoot));
        assert_eq!(
            read(&files, &root, "up/secret.txt"),
            Err(Refusal::OutsideRoot)
        );
        assert_eq!(read(&files, &root, "zero.png"), Err(Refusal::OutsideRoot));
        // A link that stays inside is followed, and the file keeps the name the scene gives
        // it (a copy of the files under their names loads the same).
        assert_eq!(read(&files, &root, "inside.txt").unwrap(), b"aaaa");
        let used = files.used();
        assert_eq!(used[0].name.as_deref(), Some(Path::new("inside.txt")));
        assert_eq!(used[0].path, root.canonicalize().unwrap().join("a.txt"));
        // A FIFO is refused at once (no writer will ever come), a folder too.
        let started = std::time::Instant::now();
        assert_eq!(
            read(&files, &root, "fifo.png"),
            Err(Refusal::NotRegular("FIFO"))
        );
        assert!(started.elapsed() < std::time::Duration::from_secs(1));
        assert_eq!(
            read(&files, &root, "sub"),
            Err(Refusal::NotRegular("folder"))
        );
        // The trusted policy reads the user's files wherever they are, but still only
        // regular ones.
        let trusted = SceneFiles::trusted();
        assert_eq!(read(&trusted, &root, "link.txt").unwrap(), b"secret");
        assert_eq!(read(&trusted, &root, "../secret.txt").unwrap(), b"secret");
        assert_eq!(
            read(&trusted, &root, "/dev/zero"),
            Err(Refusal::NotRegular("device"))
        );
        assert_eq!(
            read(&trusted, &root, "fifo.png"),
            Err(Refusal::NotRegular("FIFO"))
        );
        assert_eq!(trusted.used()[0].name, None);
    }

    #[test]
    fn reads_are_capped_per_file_and_per_scene() {
        let t = TempDir::new("caps");
        let root = t.0.join("scene");
        // A sparse file claiming 10 GiB is refused from its size, without reading it.
        let sparse = File::create(root.join("sparse.bin")).unwrap();
        sparse.set_len(10 << 30).unwrap();
        let files = confined(&root, 3, 100);
        let started = std::time::Instant::now();
        assert_eq!(
            read(&files, &root, "sparse.bin"),
            Err(Refusal::TooLarge {
                bytes: 10 << 30,
                cap: 3
            })
        );
        assert!(started.elapsed() < std::time::Duration::from_secs(1));
        assert_eq!(
            read(&files, &root, "a.txt"),
            Err(Refusal::TooLarge { bytes: 4, cap: 3 })
        );
        // The budget counts every read: b.txt (2 bytes) fits twice in 5, not three times.
        let files = confined(&root, 100, 5);
        assert!(read(&files, &root, "sub/b.txt").is_ok());
        assert!(read(&files, &root, "sub/b.txt").is_ok());
        assert_eq!(
            read(&files, &root, "sub/b.txt"),
            Err(Refusal::OverBudget { budget: 5 })
        );
        assert_eq!(files.bytes_read(), 4);
        // The caller's own cap (an image's) applies too.
        let files = confined(&root, 100, 100);
        let r = files
            .resolve_path(&root, Path::new("a.txt"), "environment.path")
            .unwrap();
        assert_eq!(
            files.read(&r, "environment.path", 2).unwrap_err().refusal,
            Refusal::TooLarge { bytes: 4, cap: 2 }
        );
        // Memory: charged until the limit.
        let files = SceneFiles::trusted().with_memory_limit(10);
        assert!(files.charge_memory(6, "texture a").is_ok());
        let e = files.charge_memory(6, "texture b").unwrap_err();
        assert!(e.contains("texture b") && e.contains("10 bytes"), "{e}");
    }

    #[test]
    fn a_scene_that_includes_itself_is_refused() {
        let t = TempDir::new("cycle");
        let root = t.0.join("scene");
        let files = confined(&root, 100, 100);
        let a = files.resolve_path(&root, Path::new("a.txt"), "").unwrap();
        let b = files
            .resolve_path(&root, Path::new("sub/b.txt"), "objects[0].shape.path")
            .unwrap();
        files.enter(&a, "").unwrap();
        files.enter(&b, "objects[0].shape.path").unwrap();
        let again = files
            .resolve_path(
                &root.join("sub"),
                Path::new("../a.txt"),
                "objects[1].shape.path",
            )
            .unwrap();
        let e = files.enter(&again, "objects[1].shape.path").unwrap_err();
        assert_eq!(
            e.refusal,
            Refusal::IncludesItself(vec!["a.txt".into(), "b.txt".into(), "a.txt".into()])
        );
        files.leave();
        files.leave();
        // Once loaded, the same file may be included again (twice side by side is no cycle).
        files.enter(&a, "").unwrap();
    }

    #[test]
    fn the_scene_file_itself_must_be_in_the_root() {
        let t = TempDir::new("entry");
        let root = t.0.join("scene");
        let files = SceneFiles::confined_to_scene(&root.join("a.txt"), 100, 100).unwrap();
        assert_eq!(
            files.read_scene(&root.join("a.txt"), 100).unwrap().1,
            b"aaaa"
        );
        assert_eq!(
            files
                .read_scene(&t.0.join("secret.txt"), 100)
                .unwrap_err()
                .refusal,
            Refusal::OutsideRoot
        );
        assert!(SceneFiles::new(FilePolicy::confined(root.join("a.txt"))).is_err());
        assert_eq!(folder_of(Path::new("scene.json")), Path::new("."));
    }
}
