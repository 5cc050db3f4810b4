//! Scene packages on disk: content ids, safe archive extraction, packing the files of a scene.

use super::{single_file_name, SceneFormat};
use sha2::{Digest, Sha256};
use std::io::Read;
use std::path::{Component, Path, PathBuf};

/// Why a scene package could not be read.
#[derive(Debug, thiserror::Error)]
pub enum PackageError {
    /// The content is none of the known formats.
    #[error("cannot tell the scene format: expected glTF, GLB, a raytile JSON scene, tar or zip (give ?format=)")]
    UnknownFormat,
    /// The archive is malformed.
    #[error("bad archive: {0}")]
    Archive(String),
    /// An archive member would land outside the folder, or is a link or device.
    #[error("refusing archive member '{0}': {1}")]
    UnsafeMember(String, &'static str),
    /// Two members land on the same path once their names are normalised (`a` and `./a`, a
    /// name given twice), or a member is a file where another one needs a folder (`a` and
    /// `a/b`).
    #[error("refusing archive member '{0}': {1}")]
    Clash(String, String),
    /// The archive unpacks to too much data or too many files.
    #[error("archive too large when unpacked (limit {0} bytes, {1} files)")]
    TooLarge(u64, usize),
    /// No scene file, or several, at the archive root.
    #[error("{0}")]
    Entry(String),
    /// Disk trouble (said as the OS says it, once: an error chain would repeat a source).
    #[error(transparent)]
    Io(#[from] std::io::Error),
}

/// Limits of [`unpack`].
#[derive(Clone, Copy, Debug)]
pub struct UnpackLimits {
    /// Total unpacked bytes.
    pub max_bytes: u64,
    /// Number of members.
    pub max_files: usize,
}

impl Default for UnpackLimits {
    fn default() -> Self {
        Self {
            max_bytes: 2 << 30,
            max_files: 10_000,
        }
    }
}

/// Hex sha256 of bytes.
pub fn sha256_hex(bytes: &[u8]) -> String {
    hex::encode(Sha256::digest(bytes))
}

/// Hex sha256 of a file, streamed.
pub fn sha256_file(path: &Path) -> std::io::Result<String> {
    let mut f = std::fs::File::open(path)?;
    let mut h = Sha256::new();
    let mut buf = vec![0u8; 1 << 16];
    loop {
        let n = f.read(&mut buf)?;
        if n == 0 {
            break;
        }
        h.update(&buf[..n]);
    }
    Ok(hex::encode(h.finalize()))
}

/// Scene id of a blob with digest `sha256` and the archive entry asked for, if any. The entry
/// counts by the file it names: `./scene.json` and `a//b.gltf` are `scene.json` and
/// `a/b.gltf` ([`normal_entry`]).
pub fn scene_id(sha256: &str, entry: Option<&str>) -> String {
    match entry {
        None => sha256.to_string(),
        Some(e) => sha256_hex(format!("{sha256}\0{}", normal_entry(e)).as_bytes()),
    }
}

/// An archive entry as the member it names: `.` parts and repeated slashes dropped, parts
/// joined by `/`. A name that no member can have (absolute, with `..`, a backslash or NUL) or
/// that names nothing is returned as given, for the unpacking to refuse.
pub fn normal_entry(entry: &str) -> String {
    match safe_relative(entry) {
        Ok(p) if p.components().next().is_some() => p
            .components()
            .map(|c| c.as_os_str().to_string_lossy())
            .collect::<Vec<_>>()
            .join("/"),
        _ => entry.to_string(),
    }
}

/// Checks an archive member name and returns it as a relative path.
fn safe_relative(name: &str) -> Result<PathBuf, PackageError> {
    let p = Path::new(name);
    let mut out = PathBuf::new();
    for c in p.components() {
        match c {
            Component::Normal(s) => out.push(s),
            Component::CurDir => {}
            Component::ParentDir => {
                return Err(PackageError::UnsafeMember(name.into(), "contains '..'"))
            }
            Component::RootDir | Component::Prefix(_) => {
                return Err(PackageError::UnsafeMember(name.into(), "absolute path"))
            }
        }
    }
    if name.contains('\\') || name.contains('\0') {
        return Err(PackageError::UnsafeMember(
            name.into(),
            "backslash or NUL in name",
        ));
    }
    Ok(out)
}

/// Copies a member of `declared` bytes (what its header says), at most `budget` bytes of it,
/// from `r` into a new file. A member declared or found larger is refused before (or as soon
/// as) it goes over; an error reading the member is the archive's fault, an error writing the
/// file the disk's.
fn copy_limited(
    r: &mut dyn Read,
    declared: u64,
    dest: &Path,
    budget: &mut u64,
    limits: UnpackLimits,
) -> Result<(), PackageError> {
    if declared > *budget {
        return Err(PackageError::TooLarge(limits.max_bytes, limits.max_files));
    }
    if let Some(parent) = dest.parent() {
        std::fs::create_dir_all(parent)?;
    }
    let mut f = std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(dest)?;
    let mut limited = r.take(*budget + 1);
    let mut buf = vec![0u8; 1 << 16];
    let mut n: u64 = 0;
    loop {
        let got = match limited.read(&mut buf) {
            Ok(0) => break,
            Ok(got) => got,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            Err(e) => return Err(PackageError::Archive(format!("reading a member: {e}"))),
        };
        n += got as u64;
        if n > *budget {
            return Err(PackageError::TooLarge(limits.max_bytes, limits.max_files));
        }
        std::io::Write::write_all(&mut f, &buf[..got])?;
    }
    *budget -= n;
    Ok(())
}

/// Unpacks a blob of `format` into `dir` (which must exist and be empty) and returns the scene
/// file to load. For archives, `entry` names the scene file; without it, the single
/// `.gltf`/`.glb`/`.json` at the archive root (or in its single top folder) is taken.
pub fn unpack(
    blob: &Path,
    format: SceneFormat,
    entry: Option<&str>,
    dir: &Path,
    limits: UnpackLimits,
) -> Result<PathBuf, PackageError> {
    let mut budget = limits.max_bytes;
    let mut files: Vec<PathBuf> = Vec::new();
    match format {
        SceneFormat::Gltf | SceneFormat::Glb | SceneFormat::Json => {
            let dest = dir.join(single_file_name(format));
            // A second name for the package's bytes, not a second copy of them (where the
            // file system has links: a copy otherwise).
            // (Unix only, where a worker's cache counts a file of several names once.)
            if !cfg!(unix) || std::fs::hard_link(blob, &dest).is_err() {
                std::fs::copy(blob, &dest)?;
            }
            return Ok(dest);
        }
        SceneFormat::Tar => {
            // Every member is looked at before anything is written: an archive whose paths
            // clash is refused as a whole.
            let mut paths = MemberPaths::default();
            let mut ar = tar::Archive::new(std::fs::File::open(blob)?);
            let entries = ar
                .entries_with_seek()
                .map_err(|e| PackageError::Archive(e.to_string()))?;
            for e in entries {
                let e = e.map_err(|e| PackageError::Archive(e.to_string()))?;
                if let Some(m) = tar_member(&e)? {
                    paths.add(&m, limits)?;
                }
            }
            let mut ar = tar::Archive::new(std::fs::File::open(blob)?);
            let entries = ar
                .entries()
                .map_err(|e| PackageError::Archive(e.to_string()))?;
            for e in entries {
                let mut e = e.map_err(|e| PackageError::Archive(e.to_string()))?;
                let Some(m) = tar_member(&e)? else { continue };
                if m.is_dir {
                    continue;
                }
                let declared = e.header().size().unwrap_or(u64::MAX);
                copy_limited(&mut e, declared, &dir.join(&m.rel), &mut budget, limits)?;
                files.push(m.rel);
            }
        }
        SceneFormat::Zip => {
            let f = std::fs::File::open(blob)?;
            let mut ar =
                zip::ZipArchive::new(f).map_err(|e| PackageError::Archive(e.to_string()))?;
            if ar.len() > limits.max_files {
                return Err(PackageError::TooLarge(limits.max_bytes, limits.max_files));
            }
            // The zip reader keeps one member per name: a name given twice is found in the
            // central directory itself.
            let start = ar.central_directory_start();
            zip_duplicate_name(&mut std::fs::File::open(blob)?, start, ar.len(), limits)?;
            let mut paths = MemberPaths::default();
            for i in 0..ar.len() {
                let e = ar
                    .by_index_raw(i)
                    .map_err(|e| PackageError::Archive(e.to_string()))?;
                if let Some(m) = zip_member(e.name(), e.is_dir(), e.is_symlink())? {
                    paths.add(&m, limits)?;
                }
            }
            for i in 0..ar.len() {
                let mut e = ar
                    .by_index(i)
                    .map_err(|e| PackageError::Archive(e.to_string()))?;
                let Some(m) = zip_member(e.name(), e.is_dir(), e.is_symlink())? else {
                    continue;
                };
                if m.is_dir {
                    continue;
                }
                let declared = e.size();
                copy_limited(&mut e, declared, &dir.join(&m.rel), &mut budget, limits)?;
                files.push(m.rel);
            }
        }
    }
    pick_entry(&files, entry).map(|rel| dir.join(rel))
}

/// An archive member that unpacks to something: a file or a folder, by its name in the
/// archive and its normalised relative path.
struct Member {
    name: String,
    rel: PathBuf,
    is_dir: bool,
}

/// A tar member as unpacked: `None` for the records that are no file of the scene (pax and
/// GNU long-name records, the archive's own root folder); links and special files refused.
fn tar_member<R: Read>(e: &tar::Entry<'_, R>) -> Result<Option<Member>, PackageError> {
    let name = e
        .path()
        .map_err(|e| PackageError::Archive(e.to_string()))?
        .to_string_lossy()
        .into_owned();
    let rel = safe_relative(&name)?;
    let kind = e.header().entry_type();
    if kind.is_pax_global_extensions() || kind.is_pax_local_extensions() || kind.is_gnu_longname() {
        return Ok(None);
    }
    let is_dir = kind.is_dir();
    if !is_dir && !kind.is_file() {
        return Err(PackageError::UnsafeMember(
            name,
            "links and special files are not allowed",
        ));
    }
    if rel.as_os_str().is_empty() {
        return Ok(None);
    }
    Ok(Some(Member { name, rel, is_dir }))
}

/// A zip member as unpacked (see [`tar_member`]).
fn zip_member(name: &str, is_dir: bool, is_link: bool) -> Result<Option<Member>, PackageError> {
    let rel = safe_relative(name)?;
    if is_link && !is_dir {
        return Err(PackageError::UnsafeMember(
            name.into(),
            "links are not allowed",
        ));
    }
    if rel.as_os_str().is_empty() {
        return Ok(None);
    }
    Ok(Some(Member {
        name: name.into(),
        rel,
        is_dir,
    }))
}

/// The paths an archive's members unpack to, each with the first member that needs it: a
/// file, or a folder (named, or holding a file). Two members clash when they are the same
/// file, or when one is a file and the other needs that path to be a folder.
#[derive(Default)]
struct MemberPaths {
    files: std::collections::HashMap<PathBuf, String>,
    folders: std::collections::HashMap<PathBuf, String>,
    named_folders: usize,
}

impl MemberPaths {
    fn add(&mut self, m: &Member, limits: UnpackLimits) -> Result<(), PackageError> {
        let clash = |why: String| Err(PackageError::Clash(m.name.clone(), why));
        if m.is_dir {
            self.named_folders += 1;
        }
        if (!m.is_dir && self.files.len() >= limits.max_files)
            || self.named_folders > limits.max_files
        {
            return Err(PackageError::TooLarge(limits.max_bytes, limits.max_files));
        }
        if let Some(other) = self.files.get(&m.rel) {
            return clash(if m.is_dir {
                format!("member '{other}' is a file of that path, so it cannot be a folder")
            } else {
                format!("member '{other}' is the same file (names are compared after removing './' and repeated '/')")
            });
        }
        if !m.is_dir {
            if let Some(other) = self.folders.get(&m.rel) {
                return clash(format!(
                    "member '{other}' makes that path a folder, so it cannot be a file"
                ));
            }
        }
        // The folders this member needs: its parents, and itself if it is one.
        let skip = usize::from(!m.is_dir);
        for folder in m.rel.ancestors().skip(skip) {
            if folder.as_os_str().is_empty() {
                break;
            }
            if let Some(other) = self.files.get(folder) {
                return clash(format!(
                    "member '{other}' is a file, so '{}' cannot be a folder",
                    folder.display()
                ));
            }
            self.folders
                .entry(folder.to_path_buf())
                .or_insert_with(|| m.name.clone());
        }
        if !m.is_dir {
            self.files.insert(m.rel.clone(), m.name.clone());
        }
        Ok(())
    }
}

/// Reads the names in a zip's central directory (at `start`, `members` the number of distinct
/// names the zip reader found) and refuses the archive when a name is given twice: the
/// reader would keep only one of them.
fn zip_duplicate_name<R: Read + std::io::Seek>(
    r: &mut R,
    start: u64,
    members: usize,
    limits: UnpackLimits,
) -> Result<(), PackageError> {
    const CENTRAL_HEADER: [u8; 4] = [0x50, 0x4b, 0x01, 0x02];
    let bad = |e: std::io::Error| PackageError::Archive(format!("reading the zip directory: {e}"));
    r.seek(std::io::SeekFrom::Start(start)).map_err(bad)?;
    let mut r = std::io::BufReader::new(r);
    let mut seen = std::collections::HashSet::new();
    let mut fixed = [0u8; 46];
    loop {
        match r.read_exact(&mut fixed) {
            Ok(()) if fixed[..4] == CENTRAL_HEADER => {}
            // The end of the directory (the end records follow it).
            _ => break,
        }
        let len = |i: usize| u16::from_le_bytes([fixed[i], fixed[i + 1]]) as usize;
        let (name_len, rest) = (len(28), len(30) + len(32));
        let mut name = vec![0u8; name_len];
        r.read_exact(&mut name).map_err(bad)?;
        std::io::copy(&mut (&mut r).take(rest as u64), &mut std::io::sink()).map_err(bad)?;
        if seen.contains(&name) {
            let name = String::from_utf8_lossy(&name).into_owned();
            return Err(PackageError::Clash(
                name,
                "the archive holds that name twice".into(),
            ));
        }
        seen.insert(name);
        if seen.len() > members.max(limits.max_files) {
            return Err(PackageError::TooLarge(limits.max_bytes, limits.max_files));
        }
    }
    Ok(())
}

fn is_scene_file(p: &Path) -> bool {
    matches!(
        p.extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase)
            .as_deref(),
        Some("gltf" | "glb" | "json")
    )
}

fn pick_entry(files: &[PathBuf], entry: Option<&str>) -> Result<PathBuf, PackageError> {
    if let Some(e) = entry {
        // A name no member may have is the entry's fault, not the archive's.
        let want = safe_relative(e).map_err(|err| match err {
            PackageError::UnsafeMember(_, why) => {
                PackageError::Entry(format!("entry '{e}' refused: {why}"))
            }
            other => other,
        })?;
        return files
            .iter()
            .find(|f| **f == want)
            .cloned()
            .ok_or_else(|| PackageError::Entry(format!("entry '{e}' is not in the archive")));
    }
    let at_depth = |d: usize| -> Vec<&PathBuf> {
        files
            .iter()
            .filter(|f| f.components().count() == d && is_scene_file(f))
            .collect()
    };
    let mut found = at_depth(1);
    if found.is_empty() {
        // A folder archived with its own name: `scene/scene.gltf`.
        let tops: std::collections::BTreeSet<_> =
            files.iter().filter_map(|f| f.components().next()).collect();
        if tops.len() == 1 {
            found = at_depth(2);
        }
    }
    match found.as_slice() {
        [one] => Ok((*one).clone()),
        [] => Err(PackageError::Entry(
            "no .gltf, .glb or .json scene file at the archive root".into(),
        )),
        many => Err(PackageError::Entry(format!(
            "several scene files at the archive root ({}); choose one with ?entry=",
            many.iter()
                .map(|p| p.to_string_lossy().into_owned())
                .collect::<Vec<_>>()
                .join(", ")
        ))),
    }
}

/// A file to pack: where it is and its name in the archive.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct PackFile {
    /// The file on disk.
    pub path: PathBuf,
    /// Its name in the archive: relative, `/`-separated, no `..`.
    pub name: String,
    /// Its size when it was checked: a file that no longer has it is an error.
    pub size: u64,
}

/// Writes a tar archive of `files`, in the order given, to `out` as it goes (nothing is held
/// in memory but a copy buffer). Members are regular files with the names given and fixed
/// metadata (mode 0644, owner 0, time 0), so the same files always make the same bytes, and so
/// the same scene id. A name that [`unpack`] would refuse, or a file whose size changed since
/// it was checked, is an error.
pub fn pack_files(files: &[PackFile], out: impl std::io::Write) -> std::io::Result<()> {
    let mut b = tar::Builder::new(out);
    for f in files {
        let bad = |why: String| std::io::Error::new(std::io::ErrorKind::InvalidInput, why);
        let rel = safe_relative(&f.name).map_err(|e| bad(e.to_string()))?;
        // Names as tar writes them (so that `packed_size` is exact): `a/b`, no `.` or empty
        // components.
        let normal = rel
            .components()
            .map(|c| c.as_os_str().to_string_lossy())
            .collect::<Vec<_>>()
            .join("/");
        if rel.as_os_str().is_empty() || normal != f.name {
            return Err(bad(format!(
                "archive member name '{}' is not a plain relative path",
                f.name
            )));
        }
        let file = std::fs::File::open(&f.path)?;
        let meta = file.metadata()?;
        if !meta.is_file() || meta.len() != f.size {
            return Err(bad(format!(
                "{} changed since it was checked (it is no longer a regular file of {} bytes)",
                f.path.display(),
                f.size
            )));
        }
        let mut h = tar::Header::new_gnu();
        h.set_entry_type(tar::EntryType::Regular);
        h.set_size(f.size);
        h.set_mode(0o644);
        h.set_mtime(0);
        h.set_uid(0);
        h.set_gid(0);
        let mut data = Exact {
            inner: file.take(f.size),
            left: f.size,
        };
        // `append_data` writes a GNU long-name record for names over 100 bytes.
        b.append_data(&mut h, &f.name, &mut data)?;
    }
    b.into_inner()?.flush()
}

/// The size in bytes of the archive [`pack_files`] writes for `files`, known before anything
/// is read: a streamed upload can say its length, and the coordinator refuse one over its limit
/// before it is sent.
pub fn packed_size(files: &[PackFile]) -> u64 {
    let blocks = |n: u64| n.div_ceil(512) * 512;
    let members: u64 = files
        .iter()
        .map(|f| {
            // A name longer than the header's 100 bytes goes first in a GNU long-name member:
            // a header and the name with its NUL.
            let long_name = if f.name.len() > 100 {
                512 + blocks(f.name.len() as u64 + 1)
            } else {
                0
            };
            long_name + 512 + blocks(f.size)
        })
        .sum();
    // The end of the archive: two empty blocks.
    members + 1024
}

/// Reads exactly `left` bytes: fewer (the file shrank since its header was written) is an
/// error rather than a corrupt archive.
struct Exact<R> {
    inner: R,
    left: u64,
}

impl<R: Read> Read for Exact<R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = self.inner.read(buf)?;
        if n == 0 && self.left > 0 && !buf.is_empty() {
            return Err(std::io::Error::new(
                std::io::ErrorKind::UnexpectedEof,
                "a file shrank while it was being packed",
            ));
        }
        self.left -= n as u64;
        Ok(n)
    }
}

#[cfg(test)]
mod tests {
    use super::super::sniff;
    use super::*;

    fn tar_with(members: &[(&str, &[u8])]) -> Vec<u8> {
        let mut b = tar::Builder::new(Vec::new());
        for (name, data) in members {
            // A name ending in '/' is a folder record.
            let data = if name.ends_with('/') { &[][..] } else { data };
            let mut h = tar::Header::new_gnu();
            h.set_size(data.len() as u64);
            h.set_mode(0o644);
            h.set_entry_type(if name.ends_with('/') {
                tar::EntryType::Directory
            } else {
                tar::EntryType::Regular
            });
            // set_path refuses '..', so write the raw name as an attacker would.
            let raw = &mut h.as_old_mut().name;
            raw[..name.len()].copy_from_slice(name.as_bytes());
            h.set_cksum();
            b.append(&h, data).unwrap();
        }
        b.into_inner().unwrap()
    }

    fn check_unpack(blob: &[u8], entry: Option<&str>) -> Result<String, String> {
        let t = tempfile::tempdir().unwrap();
        let p = t.path().join("blob");
        std::fs::write(&p, blob).unwrap();
        let out = t.path().join("out");
        std::fs::create_dir(&out).unwrap();
        let fmt = sniff(blob).ok_or("sniff")?;
        unpack(
            &p,
            fmt,
            entry,
            &out,
            UnpackLimits {
                max_bytes: 1000,
                max_files: 10,
            },
        )
        .map(|p| p.strip_prefix(&out).unwrap().to_string_lossy().into_owned())
        .map_err(|e| e.to_string())
    }

    #[test]
    fn sniffs_formats() {
        assert_eq!(sniff(b"glTF\x02\0\0\0"), Some(SceneFormat::Glb));
        assert_eq!(sniff(b" {\"asset\":{}}"), Some(SceneFormat::Gltf));
        assert_eq!(sniff(b"{\"objects\":[]}"), Some(SceneFormat::Json));
        assert_eq!(sniff(b"PK\x03\x04rest"), Some(SceneFormat::Zip));
        assert_eq!(
            sniff(&tar_with(&[("a.gltf", b"{}")])),
            Some(SceneFormat::Tar)
        );
        assert_eq!(sniff(b"hello"), None);
    }

    #[test]
    fn an_entry_is_named_the_same_however_it_is_spelt() {
        let id = scene_id("ab", Some("scene.json"));
        for spelling in [
            "./scene.json",
            "././scene.json",
            ".//scene.json",
            "scene.json",
        ] {
            assert_eq!(scene_id("ab", Some(spelling)), id, "{spelling}");
        }
        assert_eq!(normal_entry("a//b/./c.gltf"), "a/b/c.gltf");
        assert_ne!(scene_id("ab", Some("a/scene.json")), id);
        assert_ne!(scene_id("ab", None), id);
        // Names no member has are kept for the unpacking to refuse.
        for bad in ["../x.json", "/x.json", ".", ""] {
            assert_eq!(normal_entry(bad), bad);
        }
    }

    #[test]
    fn unpacks_safe_archives_and_finds_the_entry() {
        let t = tar_with(&[("s.gltf", b"{}"), ("s.bin", b"12")]);
        assert_eq!(check_unpack(&t, None).unwrap(), "s.gltf");
        let t = tar_with(&[("dir/s.gltf", b"{}"), ("dir/tex/a.png", b"1")]);
        assert_eq!(check_unpack(&t, None).unwrap(), "dir/s.gltf");
        let t = tar_with(&[("a.gltf", b"{}"), ("b.gltf", b"{}")]);
        assert!(check_unpack(&t, None).unwrap_err().contains("entry"));
        assert_eq!(check_unpack(&t, Some("b.gltf")).unwrap(), "b.gltf");
    }

    #[test]
    fn packs_the_files_given_the_same_way_every_time() {
        let t = tempfile::tempdir().unwrap();
        std::fs::create_dir(t.path().join("tex")).unwrap();
        std::fs::write(t.path().join("s.gltf"), b"{}").unwrap();
        std::fs::write(t.path().join("tex/a.png"), b"png").unwrap();
        std::fs::write(t.path().join("unused.bin"), b"no").unwrap();
        let files = vec![
            PackFile {
                path: t.path().join("s.gltf"),
                name: "s.gltf".into(),
                size: 2,
            },
            PackFile {
                path: t.path().join("tex/a.png"),
                name: "tex/a.png".into(),
                size: 3,
            },
        ];
        let mut a = Vec::new();
        pack_files(&files, &mut a).unwrap();
        let mut b = Vec::new();
        pack_files(&files, &mut b).unwrap();
        assert_eq!(a, b, "the same files make the same bytes");
        assert_eq!(sniff(&a), Some(SceneFormat::Tar));
        // What is unpacked is what was listed, nothing else.
        let out = t.path().join("out");
        std::fs::create_dir(&out).unwrap();
        std::fs::write(t.path().join("blob"), &a).unwrap();
        let entry = unpack(
            &t.path().join("blob"),
            SceneFormat::Tar,
            None,
            &out,
            UnpackLimits::default(),
        )
        .unwrap();
        assert_eq!(entry, out.join("s.gltf"));
        assert_eq!(std::fs::read(out.join("tex/a.png")).unwrap(), b"png");
        assert!(!out.join("unused.bin").exists());
        // A file that changed since it was checked, or a hostile name, is an error.
        let mut changed = files.clone();
        changed[1].size = 4;
        assert!(pack_files(&changed, &mut Vec::new()).is_err());
        let mut hostile = files.clone();
        hostile[1].name = "../a.png".into();
        assert!(pack_files(&hostile, &mut Vec::new()).is_err());
        hostile[1].name = "tex//./a.png".into();
        assert!(pack_files(&hostile, &mut Vec::new()).is_err());
    }

    #[test]
    fn the_packed_size_is_known_before_packing() {
        let t = tempfile::tempdir().unwrap();
        let mut files = Vec::new();
        for (i, (name_len, size)) in [
            (1, 0),
            (99, 1),
            (100, 511),
            (101, 512),
            (511, 513),
            (512, 1),
        ]
        .into_iter()
        .enumerate()
        {
            // Names of the given length, in folders so that some have slashes.
            let name: String = format!("d{i}/")
                .chars()
                .chain(std::iter::repeat('n'))
                .take(name_len.max(4))
                .collect();
            let path = t.path().join(format!("f{i}"));
            std::fs::write(&path, vec![7u8; size]).unwrap();
            files.push(PackFile {
                path,
                name,
                size: size as u64,
            });
            let mut out = Vec::new();
            pack_files(&files, &mut out).unwrap();
            assert_eq!(packed_size(&files), out.len() as u64, "{files:?}");
        }
    }

    fn zip_with(members: &[(&str, &[u8])]) -> Vec<u8> {
        let mut w = zip::ZipWriter::new(std::io::Cursor::new(Vec::new()));
        for (name, data) in members {
            let opts = zip::write::SimpleFileOptions::default()
                .compression_method(zip::CompressionMethod::Stored);
            if let Some(folder) = name.strip_suffix('/') {
                w.add_directory(folder, opts).unwrap();
            } else {
                w.start_file(*name, opts).unwrap();
                std::io::Write::write_all(&mut w, data).unwrap();
            }
        }
        w.finish().unwrap().into_inner()
    }

    /// Unpacks into a fresh folder; the error, and whether anything was written.
    fn unpack_error(blob: &[u8]) -> (String, bool) {
        let t = tempfile::tempdir().unwrap();
        let p = t.path().join("blob");
        std::fs::write(&p, blob).unwrap();
        let out = t.path().join("out");
        std::fs::create_dir(&out).unwrap();
        let fmt = sniff(blob).unwrap();
        let e = unpack(&p, fmt, None, &out, UnpackLimits::default()).unwrap_err();
        let written = std::fs::read_dir(&out).unwrap().next().is_some();
        (e.to_string(), written)
    }

    #[test]
    fn refuses_archives_whose_paths_clash_before_writing_anything() {
        let s: &[u8] = b"{}";
        type Members<'a> = &'a [(&'a str, &'a [u8])];
        let cases: [(Members, &str); 7] = [
            (&[("scene.json", s), ("scene.json", s)], "scene.json"),
            (&[("scene.json", s), ("./scene.json", s)], "./scene.json"),
            (&[("scene.json", s), ("x/y", s), ("x//y", s)], "x//y"),
            (&[("scene.json", s), ("a", s), ("a/b", s)], "a/b"),
            (&[("scene.json", s), ("a/b", s), ("a", s)], "a"),
            (&[("scene.json", s), ("a/", s), ("a", s)], "a"),
            (&[("scene.json", s), ("a", s), ("a/", s)], "a/"),
        ];
        for (members, culprit) in cases {
            let (e, written) = unpack_error(&tar_with(members));
            assert!(
                e.starts_with(&format!("refusing archive member '{culprit}': ")),
                "tar {members:?}: {e}"
            );
            assert!(
                !written,
                "tar {members:?}: files written before the refusal"
            );
        }
        // Zip: the writer refuses a name twice, so the second name is made equal afterwards.
        let mut z = zip_with(&[("scene.json", s), ("scene.jsoX", s)]);
        let mut at = 0;
        while let Some(i) = z[at..].windows(10).position(|w| w == b"scene.jsoX") {
            z[at + i + 9] = b'n';
            at += i + 10;
        }
        let (e, written) = unpack_error(&z);
        assert!(e.contains("'scene.json'") && e.contains("twice"), "{e}");
        assert!(!written);
        for (members, culprit) in [
            (&[("scene.json", s), ("a", s), ("a/b", s)][..], "a/b"),
            (
                &[("scene.json", s), ("./scene.json", s)][..],
                "./scene.json",
            ),
            (&[("scene.json", s), ("a/", s), ("a", s)][..], "a"),
        ] {
            let (e, written) = unpack_error(&zip_with(members));
            assert!(
                e.starts_with(&format!("refusing archive member '{culprit}': ")),
                "zip {members:?}: {e}"
            );
            assert!(
                !written,
                "zip {members:?}: files written before the refusal"
            );
        }
        // Folders named on their own and by their files are fine.
        let t = tar_with(&[("d/s.gltf", s), ("d/tex/a.png", s), ("d/tex/b.png", s)]);
        assert_eq!(check_unpack(&t, None).unwrap(), "d/s.gltf");
        let z = zip_with(&[
            ("d/", s),
            ("d/s.gltf", s),
            ("d/tex/", s),
            ("d/tex/a.png", s),
        ]);
        assert_eq!(check_unpack(&z, None).unwrap(), "d/s.gltf");
    }

    #[test]
    fn refuses_hostile_archives() {
        let t = tar_with(&[("../evil.gltf", b"{}")]);
        assert!(check_unpack(&t, None).unwrap_err().contains(".."));
        let t = tar_with(&[("/etc/evil.gltf", b"{}")]);
        assert!(check_unpack(&t, None).unwrap_err().contains("absolute"));
        let big = vec![0u8; 2000];
        let t = tar_with(&[("s.gltf", &big)]);
        assert!(check_unpack(&t, None).unwrap_err().contains("too large"));
        // A member claiming 10 GiB is refused from its header, before anything is written;
        // one whose data is cut short is the archive's fault, not the disk's.
        let mut t = tar_with(&[("s.gltf", b"{}")]);
        let mut h = tar::Header::new_gnu();
        h.set_size(10 << 30);
        h.set_mode(0o644);
        h.set_entry_type(tar::EntryType::Regular);
        h.set_path("huge.bin").unwrap();
        h.set_cksum();
        t.truncate(t.len() - 1024);
        t.extend_from_slice(h.as_bytes());
        t.extend_from_slice(&[0u8; 512]);
        assert!(check_unpack(&t, None).unwrap_err().contains("too large"));
        let mut cut = tar_with(&[("s.gltf", &[b' '; 600])]);
        cut.truncate(512 + 100);
        let e = check_unpack(&cut, None).unwrap_err();
        assert!(e.contains("bad archive"), "{e}");
        let mut b = tar::Builder::new(Vec::new());
        let mut h = tar::Header::new_gnu();
        h.set_entry_type(tar::EntryType::Symlink);
        h.set_size(0);
        b.append_link(&mut h, "s.gltf", "/etc/passwd").unwrap();
        let t = b.into_inner().unwrap();
        assert!(check_unpack(&t, None).unwrap_err().contains("link"));
    }
}
