//! Loading density grids from files: limits, errors, and the reader picked by extension.

use super::grid::DensityGrid;
use glam::Affine3A;
use std::path::{Path, PathBuf};

/// Bounds on what a grid file may make the renderer allocate. Every size read from a header is
/// checked against these and against the file's length before anything is allocated.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct GridLimits {
    /// Most voxels of the dense grid (512³ by default: 512 MiB of f32).
    pub max_voxels: u64,
    /// Largest file read, in bytes (2 GiB by default).
    pub max_file_bytes: u64,
}

impl Default for GridLimits {
    fn default() -> Self {
        Self {
            max_voxels: 512 * 512 * 512,
            max_file_bytes: 2 << 30,
        }
    }
}

/// What is wrong with a grid file's contents.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum GridFormatError {
    /// The bytes are not a well-formed file of the format (truncated, corrupted, inconsistent).
    #[error("{0}")]
    Invalid(String),
    /// A well-formed file using a feature the reader does not support.
    #[error("unsupported: {0}")]
    Unsupported(String),
    /// The grid is larger than [`GridLimits`] allow.
    #[error("{what} has {count} voxels, more than the limit of {limit}")]
    TooLarge {
        /// What was too large.
        what: String,
        /// Its size in voxels.
        count: u64,
        /// The limit.
        limit: u64,
    },
}

/// Why a grid file could not be loaded; the message names the file.
#[derive(Debug, thiserror::Error)]
pub enum GridFileError {
    /// The file could not be read.
    #[error("cannot read {}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The error.
        source: std::io::Error,
    },
    /// The file's contents are not a usable grid.
    #[error("{}: {source}", path.display())]
    Format {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        source: GridFormatError,
    },
}

/// A density grid read from a file, and where it sits in the space of the object that holds it.
#[derive(Clone, Debug, PartialEq)]
pub struct LoadedGrid {
    /// The density, over the box the file states (`.vol`: its header's box; `.vdb`: its active
    /// voxels' world positions, for axis-aligned index-to-world maps).
    pub density: DensityGrid,
    /// From the density's space to the object's space: the identity, except for `.vdb` grids
    /// whose index-to-world map rotates or shears (then `density` is in index space).
    pub transform: Affine3A,
}

/// Loads the density grid in `path`, picking the reader by extension: `.vol` (Mitsuba 3) or
/// `.vdb` (OpenVDB; `grid_name` selects a grid, else the one named `density`, else the only
/// float grid). Only a regular file is read, and at most `limits.max_file_bytes` of it (a
/// bounded read: a file larger than its metadata says is refused too). A scene front end reads
/// the file through the scene's resolver instead and calls [`load_grid_bytes`].
pub fn load_grid_file(
    path: &Path,
    grid_name: Option<&str>,
    limits: &GridLimits,
) -> Result<LoadedGrid, GridFileError> {
    use std::io::Read;
    grid_kind(path)?;
    let io = |source| GridFileError::Io {
        path: path.to_owned(),
        source,
    };
    let too_large = |n: u64| GridFileError::Format {
        path: path.to_owned(),
        source: GridFormatError::Unsupported(format!(
            "the file has {n} bytes or more, more than the limit of {}",
            limits.max_file_bytes
        )),
    };
    // The type before opening: opening a FIFO would wait for a writer.
    let meta = std::fs::metadata(path).map_err(io)?;
    if !meta.is_file() {
        return Err(io(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            "not a regular file",
        )));
    }
    if meta.len() > limits.max_file_bytes {
        return Err(too_large(meta.len()));
    }
    let mut bytes = Vec::with_capacity(meta.len() as usize);
    std::fs::File::open(path)
        .map_err(io)?
        .take(limits.max_file_bytes.saturating_add(1))
        .read_to_end(&mut bytes)
        .map_err(io)?;
    if bytes.len() as u64 > limits.max_file_bytes {
        return Err(too_large(bytes.len() as u64));
    }
    load_grid_bytes(&bytes, path, grid_name, limits)
}

/// Reads the density grid in `bytes`, the contents of the file `path` (which picks the reader
/// by extension and names the file in errors), as [`load_grid_file`] does.
pub fn load_grid_bytes(
    bytes: &[u8],
    path: &Path,
    grid_name: Option<&str>,
    limits: &GridLimits,
) -> Result<LoadedGrid, GridFileError> {
    let format = |source| GridFileError::Format {
        path: path.to_owned(),
        source,
    };
    if bytes.len() as u64 > limits.max_file_bytes {
        return Err(format(GridFormatError::Unsupported(format!(
            "the file has {} bytes, more than the limit of {}",
            bytes.len(),
            limits.max_file_bytes
        ))));
    }
    if grid_kind(path)? == "vol" {
        if let Some(name) = grid_name {
            return Err(format(GridFormatError::Unsupported(format!(
                "`grid` ('{name}') names a grid of a .vdb file; a .vol file holds one: remove it"
            ))));
        }
        let density = super::vol::read_vol(bytes, limits).map_err(format)?;
        Ok(LoadedGrid {
            density,
            transform: Affine3A::IDENTITY,
        })
    } else {
        let grid = super::vdb::read_vdb(bytes, grid_name, limits).map_err(format)?;
        grid.to_density(limits).map_err(format)
    }
}

/// The reader for `path`'s extension: `vol` or `vdb`.
fn grid_kind(path: &Path) -> Result<&'static str, GridFileError> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    match ext.as_deref() {
        Some("vol") => Ok("vol"),
        Some("vdb") => Ok("vdb"),
        _ => Err(GridFileError::Format {
            path: path.to_owned(),
            source: GridFormatError::Unsupported(
                "unknown grid file extension (expected .vol or .vdb)".into(),
            ),
        }),
    }
}

/// A bounds-checked little-endian reader over a byte slice: every read past the end is an
/// error naming what was being read, never a panic.
pub(crate) struct Cursor<'a> {
    bytes: &'a [u8],
    pos: usize,
}

impl<'a> Cursor<'a> {
    pub(crate) fn new(bytes: &'a [u8]) -> Self {
        Self { bytes, pos: 0 }
    }

    pub(crate) fn remaining(&self) -> usize {
        self.bytes.len() - self.pos
    }

    pub(crate) fn seek(&mut self, pos: u64, what: &str) -> Result<(), GridFormatError> {
        if pos > self.bytes.len() as u64 {
            return Err(GridFormatError::Invalid(format!(
                "{what} at byte {pos} is past the end of the file ({} bytes)",
                self.bytes.len()
            )));
        }
        self.pos = pos as usize;
        Ok(())
    }

    pub(crate) fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8], GridFormatError> {
        if n > self.remaining() {
            return Err(GridFormatError::Invalid(format!(
                "truncated: {what} needs {n} bytes at byte {}, the file has {} left",
                self.pos,
                self.remaining()
            )));
        }
        let s = &self.bytes[self.pos..self.pos + n];
        self.pos += n;
        Ok(s)
    }

    pub(crate) fn array<const N: usize>(&mut self, what: &str) -> Result<[u8; N], GridFormatError> {
        let s = self.take(N, what)?;
        let mut a = [0u8; N];
        a.copy_from_slice(s);
        Ok(a)
    }

    pub(crate) fn u8(&mut self, what: &str) -> Result<u8, GridFormatError> {
        Ok(self.array::<1>(what)?[0])
    }

    pub(crate) fn u32(&mut self, what: &str) -> Result<u32, GridFormatError> {
        Ok(u32::from_le_bytes(self.array(what)?))
    }

    pub(crate) fn i32(&mut self, what: &str) -> Result<i32, GridFormatError> {
        Ok(i32::from_le_bytes(self.array(what)?))
    }

    pub(crate) fn i64(&mut self, what: &str) -> Result<i64, GridFormatError> {
        Ok(i64::from_le_bytes(self.array(what)?))
    }

    pub(crate) fn u64(&mut self, what: &str) -> Result<u64, GridFormatError> {
        Ok(u64::from_le_bytes(self.array(what)?))
    }

    pub(crate) fn f32(&mut self, what: &str) -> Result<f32, GridFormatError> {
        Ok(f32::from_le_bytes(self.array(what)?))
    }

    pub(crate) fn f64(&mut self, what: &str) -> Result<f64, GridFormatError> {
        Ok(f64::from_le_bytes(self.array(what)?))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grid_files_are_read_bounded_and_regular_only() {
        let dir = std::env::temp_dir().join(format!("raytile-grid-file-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(dir.join("folder.vol")).unwrap();
        let limits = GridLimits {
            max_voxels: 1 << 20,
            max_file_bytes: 1 << 20,
        };
        let started = std::time::Instant::now();
        // A sparse file far over the limit: refused from its size, nothing read.
        let sparse = dir.join("sparse.vol");
        std::fs::File::create(&sparse)
            .unwrap()
            .set_len(10 << 30)
            .unwrap();
        let e = load_grid_file(&sparse, None, &limits)
            .unwrap_err()
            .to_string();
        assert!(e.contains("more than the limit"), "{e}");
        let e = load_grid_file(&dir.join("folder.vol"), None, &limits)
            .unwrap_err()
            .to_string();
        assert!(e.contains("not a regular file"), "{e}");
        #[cfg(unix)]
        {
            // A FIFO is refused before it is opened (no writer would ever come).
            let fifo = dir.join("fifo.vol");
            let c = std::ffi::CString::new(fifo.to_string_lossy().as_bytes()).unwrap();
            assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o644) }, 0);
            let e = load_grid_file(&fifo, None, &limits)
                .unwrap_err()
                .to_string();
            assert!(e.contains("not a regular file"), "{e}");
        }
        assert!(started.elapsed() < std::time::Duration::from_secs(1));
        // The bytes a resolver read are checked the same way.
        let e = load_grid_bytes(b"VOL", Path::new("smoke.vol"), None, &limits)
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("smoke.vol"), "{e}");
        // A grid name means a .vdb file: on a .vol file it is refused, not ignored.
        let e = load_grid_bytes(b"VOL", Path::new("smoke.vol"), Some("density"), &limits)
            .unwrap_err()
            .to_string();
        assert!(e.contains("a .vol file holds one"), "{e}");
        let e = load_grid_bytes(b"", Path::new("smoke.txt"), None, &limits)
            .unwrap_err()
            .to_string();
        assert!(e.contains("unknown grid file extension"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
