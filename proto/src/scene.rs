//! Scene packages: what `POST /v1/scenes` accepts and what workers download.
//!
//! A scene travels as one blob: a `.gltf` (buffers as data URIs), a `.glb`, a raytile JSON
//! scene, or a `.tar`/`.zip` of a scene folder. The id is the hex sha256 of the blob (plus the
//! chosen entry for archives uploaded with `?entry=`). `unpack` turns a blob into a folder on
//! disk and returns the scene file to load, refusing absolute paths, `..`, links and size bombs.
//!
//! Format detection is always here; ids, unpacking and packing (sha2, tar, zip) come with the
//! `package` feature, which the coordinator, the worker and the CLI enable.

#[cfg(feature = "package")]
mod package;
#[cfg(feature = "package")]
pub use package::*;

/// How a scene blob is to be read.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SceneFormat {
    /// glTF JSON.
    Gltf,
    /// Binary glTF.
    Glb,
    /// raytile's JSON scene.
    Json,
    /// Tar archive of a scene folder.
    Tar,
    /// Zip archive of a scene folder.
    Zip,
}

impl SceneFormat {
    /// Every format.
    pub const ALL: [SceneFormat; 5] = [Self::Gltf, Self::Glb, Self::Json, Self::Tar, Self::Zip];

    /// The name used in `?format=` and in leases.
    pub fn name(self) -> &'static str {
        match self {
            Self::Gltf => "gltf",
            Self::Glb => "glb",
            Self::Json => "json",
            Self::Tar => "tar",
            Self::Zip => "zip",
        }
    }

    /// Parses [`SceneFormat::name`].
    pub fn from_name(s: &str) -> Option<Self> {
        Self::ALL
            .into_iter()
            .find(|k| k.name().eq_ignore_ascii_case(s))
    }

    /// Reads a `Content-Type` header value, if it names a format.
    pub fn from_content_type(ct: &str) -> Option<Self> {
        let ct = ct
            .split(';')
            .next()
            .unwrap_or("")
            .trim()
            .to_ascii_lowercase();
        match ct.as_str() {
            "model/gltf+json" => Some(Self::Gltf),
            "model/gltf-binary" => Some(Self::Glb),
            "application/zip" | "application/x-zip-compressed" => Some(Self::Zip),
            "application/x-tar" | "application/tar" => Some(Self::Tar),
            _ => None,
        }
    }

    /// Whether the blob is an archive of a folder.
    pub fn is_archive(self) -> bool {
        matches!(self, Self::Tar | Self::Zip)
    }
}

/// Whether a string looks like a scene id (64 lowercase hex digits).
pub fn is_scene_id(s: &str) -> bool {
    s.len() == 64
        && s.bytes()
            .all(|b| b.is_ascii_digit() || (b'a'..=b'f').contains(&b))
}

/// Tells the format from the first bytes of a blob (up to 4 KiB is plenty).
pub fn sniff(head: &[u8]) -> Option<SceneFormat> {
    if head.starts_with(b"glTF") {
        return Some(SceneFormat::Glb);
    }
    if head.starts_with(b"PK\x03\x04") || head.starts_with(b"PK\x05\x06") {
        return Some(SceneFormat::Zip);
    }
    if head.len() >= 262 && &head[257..262] == b"ustar" {
        return Some(SceneFormat::Tar);
    }
    let text = head.strip_prefix(b"\xef\xbb\xbf").unwrap_or(head);
    let first = text.iter().find(|b| !b.is_ascii_whitespace())?;
    if *first == b'{' {
        // glTF JSON always has an "asset" object; raytile's scenes do not.
        let s = String::from_utf8_lossy(text);
        return Some(if s.contains("\"asset\"") {
            SceneFormat::Gltf
        } else {
            SceneFormat::Json
        });
    }
    None
}

/// The file name a single-file scene is stored under.
pub fn single_file_name(format: SceneFormat) -> &'static str {
    match format {
        SceneFormat::Gltf => "scene.gltf",
        SceneFormat::Glb => "scene.glb",
        _ => "scene.json",
    }
}
