//! Reading the containers: GLB chunks, buffers and images from data URIs, the GLB binary chunk or
//! files in the scene's own folder. Nothing here trusts the file: every length is checked before
//! it is used, and external URIs are confined to the scene's folder.

use base64::Engine as _;
use std::io::Read as _;
use std::path::{Component, Path, PathBuf};

/// GLB magic, "glTF" little-endian.
const GLB_MAGIC: &[u8; 4] = b"glTF";
/// Chunk type of the JSON chunk ("JSON").
const CHUNK_JSON: u32 = 0x4E4F_534A;
/// Chunk type of the binary chunk ("BIN\0").
const CHUNK_BIN: u32 = 0x004E_4942;

/// The JSON text and the optional binary chunk of a .gltf or .glb file.
#[derive(Debug)]
pub(super) struct Container<'a> {
    /// The glTF JSON.
    pub json: &'a [u8],
    /// The GLB binary chunk, if any.
    pub bin: Option<&'a [u8]>,
}

/// Whether `bytes` starts with the GLB magic.
pub(super) fn is_glb(bytes: &[u8]) -> bool {
    bytes.starts_with(GLB_MAGIC)
}

fn read_u32(bytes: &[u8], at: usize) -> Option<u32> {
    let b = bytes.get(at..at.checked_add(4)?)?;
    Some(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
}

/// Splits a GLB file into its JSON and binary chunks.
pub(super) fn split_glb(bytes: &[u8]) -> Result<Container<'_>, String> {
    if !is_glb(bytes) {
        return Err("not a GLB file: wrong magic (expected \"glTF\")".into());
    }
    let version = read_u32(bytes, 4).ok_or("truncated GLB header (12 bytes expected)")?;
    if version != 2 {
        return Err(format!(
            "GLB version {version} is not supported (expected 2)"
        ));
    }
    let length = read_u32(bytes, 8).ok_or("truncated GLB header (12 bytes expected)")? as usize;
    if length > bytes.len() {
        return Err(format!(
            "truncated GLB: the header says {length} bytes but the file has {}",
            bytes.len()
        ));
    }
    let bytes = &bytes[..length];
    let mut at = 12usize;
    let mut json = None;
    let mut bin = None;
    let mut index = 0;
    while at < bytes.len() {
        let chunk_len = read_u32(bytes, at)
            .ok_or_else(|| format!("truncated GLB: chunk {index} header at byte {at}"))?
            as usize;
        let chunk_type = read_u32(bytes, at + 4)
            .ok_or_else(|| format!("truncated GLB: chunk {index} header at byte {at}"))?;
        let start = at + 8;
        let end = start
            .checked_add(chunk_len)
            .filter(|&e| e <= bytes.len())
            .ok_or_else(|| {
                format!(
                    "truncated GLB: chunk {index} claims {chunk_len} bytes at byte {start} but the file has {}",
                    bytes.len()
                )
            })?;
        let data = &bytes[start..end];
        match (index, chunk_type) {
            (0, CHUNK_JSON) => json = Some(data),
            (0, _) => return Err("GLB: the first chunk is not JSON".into()),
            (1, CHUNK_BIN) => bin = Some(data),
            // Unknown chunks must be ignored (glTF 2.0 §4.4.3.3).
            _ => {}
        }
        index += 1;
        // Chunks are 4-byte aligned.
        at = end.checked_add(3).map(|e| e & !3).unwrap_or(usize::MAX);
    }
    let json = json.ok_or("GLB has no JSON chunk")?;
    Ok(Container { json, bin })
}

/// A URI shortened and escaped for error messages (hostile files may hold huge or odd URIs).
pub(super) fn show_uri(uri: &str) -> String {
    if uri.starts_with("data:") {
        let head: String = uri.chars().take(40).collect();
        return format!("{head:?}...");
    }
    let short: String = uri.chars().take(200).collect();
    format!("{short:?}")
}

/// Decodes a `data:` URI.
fn decode_data_uri(uri: &str, what: &str) -> Result<Vec<u8>, String> {
    let rest = uri.get(5..).unwrap_or("");
    let (header, data) = rest
        .split_once(',')
        .ok_or_else(|| format!("{what}: malformed data URI {} (no ',')", show_uri(uri)))?;
    if header.ends_with(";base64") {
        let engine = base64::engine::GeneralPurpose::new(
            &base64::alphabet::STANDARD,
            base64::engine::GeneralPurposeConfig::new()
                .with_decode_padding_mode(base64::engine::DecodePaddingMode::Indifferent)
                .with_decode_allow_trailing_bits(true),
        );
        engine
            .decode(data.trim_end())
            .map_err(|e| format!("{what}: bad base64 in data URI: {e}"))
    } else {
        Ok(percent_encoding::percent_decode_str(data).collect())
    }
}

/// Checks a relative URI and turns it into a relative path, or says why it is refused.
fn relative_path(uri: &str) -> Result<PathBuf, String> {
    // A scheme (`http:`, `file:`, `C:`) comes before the first '/', '?' or '#'.
    let first_sep = uri.find(['/', '?', '#']).unwrap_or(uri.len());
    if uri[..first_sep].contains(':') {
        return Err("URIs with a scheme are refused (only data: URIs and relative paths)".into());
    }
    let decoded = percent_encoding::percent_decode_str(uri)
        .decode_utf8()
        .map_err(|_| "percent-encoding decodes to invalid UTF-8".to_string())?;
    if decoded.is_empty() {
        return Err("empty URI".into());
    }
    if decoded.contains('\0') || decoded.contains('\\') || decoded.contains(':') {
        return Err("NUL, backslash or ':' in a relative path is refused".into());
    }
    if decoded.starts_with('/') {
        return Err("absolute paths are refused".into());
    }
    let path = PathBuf::from(decoded.as_ref());
    for c in path.components() {
        match c {
            Component::Normal(_) | Component::CurDir => {}
            Component::ParentDir => return Err("'..' is refused".into()),
            Component::RootDir | Component::Prefix(_) => {
                return Err("absolute paths are refused".into())
            }
        }
    }
    Ok(path)
}

/// Reads the bytes a URI names: a data URI, or a file inside `base_dir` (never outside it).
/// `what` names the glTF object for messages; `max_len` caps how much is read.
pub(super) fn load_uri(
    uri: &str,
    base_dir: Option<&Path>,
    what: &str,
    max_len: u64,
) -> Result<Vec<u8>, String> {
    // `get` rather than slicing: byte 5 may fall inside a multi-byte character.
    if uri
        .get(..5)
        .is_some_and(|s| s.eq_ignore_ascii_case("data:"))
    {
        return decode_data_uri(uri, what);
    }
    let rel = relative_path(uri)
        .map_err(|why| format!("{what}: URI {} refused: {why}", show_uri(uri)))?;
    let base = base_dir.ok_or_else(|| {
        format!(
            "{what}: external URI {} refused: the scene was not loaded from a folder",
            show_uri(uri)
        )
    })?;
    let base = std::fs::canonicalize(base)
        .map_err(|e| format!("{what}: cannot resolve the scene folder: {e}"))?;
    let full = std::fs::canonicalize(base.join(&rel))
        .map_err(|e| format!("{what}: cannot read {}: {e}", show_uri(uri)))?;
    // Symbolic links may still point elsewhere: the resolved path must stay in the folder.
    if !full.starts_with(&base) {
        return Err(format!(
            "{what}: URI {} refused: it resolves outside the scene's folder",
            show_uri(uri)
        ));
    }
    let file = std::fs::File::open(&full)
        .map_err(|e| format!("{what}: cannot read {}: {e}", show_uri(uri)))?;
    let len = file
        .metadata()
        .map_err(|e| format!("{what}: cannot read {}: {e}", show_uri(uri)))?
        .len();
    if !file_is_regular(&full) {
        return Err(format!("{what}: {} is not a regular file", show_uri(uri)));
    }
    if len > max_len {
        return Err(format!(
            "{what}: {} is {len} bytes, more than the {max_len} allowed",
            show_uri(uri)
        ));
    }
    let mut bytes = Vec::with_capacity(len as usize);
    file.take(max_len)
        .read_to_end(&mut bytes)
        .map_err(|e| format!("{what}: cannot read {}: {e}", show_uri(uri)))?;
    Ok(bytes)
}

fn file_is_regular(path: &Path) -> bool {
    std::fs::metadata(path)
        .map(|m| m.is_file())
        .unwrap_or(false)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hostile_relative_paths_are_refused() {
        for uri in [
            "../secret.bin",
            "a/../../secret.bin",
            "/etc/passwd",
            "file:///etc/passwd",
            "http://x/y.bin",
            "%2e%2e/x.bin",
            "%2F%65tc/passwd",
            "%ff%fe.bin",
            "C:\\x.bin",
            "a\\..\\b",
            "",
        ] {
            assert!(relative_path(uri).is_err(), "{uri} accepted");
        }
        assert!(relative_path("textures/a%20b.png").is_ok());
        // Regression: a multi-byte character across byte 5 must not panic.
        assert!(load_uri("dataé.bin", None, "buffer 0", 1).is_err());
        assert!(load_uri("abcdé", None, "buffer 0", 1).is_err());
        assert_eq!(
            relative_path("a%20b.png").unwrap(),
            PathBuf::from("a b.png")
        );
    }

    #[test]
    fn data_uris_decode() {
        assert_eq!(
            decode_data_uri("data:application/octet-stream;base64,AAEC", "b").unwrap(),
            vec![0, 1, 2]
        );
        assert_eq!(
            decode_data_uri("data:,a%20b", "b").unwrap(),
            b"a b".to_vec()
        );
        assert!(decode_data_uri("data:;base64,@@@", "b").is_err());
    }

    #[test]
    fn glb_headers_are_checked() {
        assert!(split_glb(b"glTF").unwrap_err().contains("truncated"));
        assert!(split_glb(b"gltF\x02\0\0\0\x0c\0\0\0")
            .unwrap_err()
            .contains("magic"));
        // Header claims more bytes than there are.
        assert!(split_glb(b"glTF\x02\0\0\0\xff\0\0\0")
            .unwrap_err()
            .contains("truncated"));
        // Chunk claims more bytes than there are.
        let mut glb = b"glTF\x02\0\0\0\x18\0\0\0".to_vec();
        glb.extend_from_slice(&[0xff, 0xff, 0xff, 0xff]);
        glb.extend_from_slice(b"JSON{}  ");
        assert!(split_glb(&glb).unwrap_err().contains("chunk 0"));
    }
}
