//! Reading the containers: GLB chunks, buffers and images from data URIs, the GLB binary chunk or
//! files in the scene's own folder. Nothing here trusts the file: every length is checked before
//! it is used, and external URIs are read through the scene's resolver (`scene::files`), inside
//! the glTF file's own folder.

use super::super::files::{Refusal, SceneFiles};
use base64::Engine as _;
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

/// Decodes a `data:` URI, after checking that its payload is within the per-file cap.
fn decode_data_uri(uri: &str, files: &SceneFiles, field: &str) -> Result<Vec<u8>, String> {
    let rest = uri.get(5..).unwrap_or("");
    let (header, data) = rest
        .split_once(',')
        .ok_or_else(|| format!("{field}: malformed data URI {} (no ',')", show_uri(uri)))?;
    // Decoding never makes more bytes than the text has.
    files
        .check_inline(field, &show_uri(uri), data.len() as u64)
        .map_err(|e| e.to_string())?;
    if header.ends_with(";base64") {
        let engine = base64::engine::GeneralPurpose::new(
            &base64::alphabet::STANDARD,
            base64::engine::GeneralPurposeConfig::new()
                .with_decode_padding_mode(base64::engine::DecodePaddingMode::Indifferent)
                .with_decode_allow_trailing_bits(true),
        );
        engine
            .decode(data.trim_end())
            .map_err(|e| format!("{field}: bad base64 in data URI: {e}"))
    } else {
        Ok(percent_encoding::percent_decode_str(data).collect())
    }
}

/// Checks a relative URI and turns it into a relative path, or says why it is refused.
fn relative_path(uri: &str) -> Result<PathBuf, Refusal> {
    // A scheme (`http:`, `file:`, `C:`) comes before the first '/', '?' or '#'.
    let first_sep = uri.find(['/', '?', '#']).unwrap_or(uri.len());
    if uri[..first_sep].contains(':') {
        return Err(Refusal::Scheme);
    }
    let decoded = percent_encoding::percent_decode_str(uri)
        .decode_utf8()
        .map_err(|_| Refusal::BadName("percent-encoding decodes to invalid UTF-8"))?;
    if decoded.is_empty() {
        return Err(Refusal::BadName("empty URI"));
    }
    if decoded.contains('\0') || decoded.contains('\\') || decoded.contains(':') {
        return Err(Refusal::BadName(
            "NUL, backslash or ':' in a relative path is refused",
        ));
    }
    if decoded.starts_with('/') {
        return Err(Refusal::Absolute);
    }
    let path = PathBuf::from(decoded.as_ref());
    for c in path.components() {
        match c {
            Component::Normal(_) | Component::CurDir => {}
            Component::ParentDir => return Err(Refusal::ParentInUri),
            Component::RootDir | Component::Prefix(_) => return Err(Refusal::Absolute),
        }
    }
    Ok(path)
}

/// Reads the bytes a URI names: a data URI, or a file inside `base_dir` (never outside it),
/// through the scene's resolver. `field` names the glTF field for messages
/// (`buffers[0].uri`); `max_len` caps how much is read.
pub(super) fn load_uri(
    uri: &str,
    base_dir: Option<&Path>,
    files: &SceneFiles,
    field: &str,
    max_len: u64,
) -> Result<Vec<u8>, String> {
    // `get` rather than slicing: byte 5 may fall inside a multi-byte character.
    if uri
        .get(..5)
        .is_some_and(|s| s.eq_ignore_ascii_case("data:"))
    {
        return decode_data_uri(uri, files, field);
    }
    let shown = show_uri(uri);
    let refused = |r: Refusal| files.refused(field, &shown, r).to_string();
    let rel = relative_path(uri).map_err(refused)?;
    let base = base_dir.ok_or_else(|| refused(Refusal::NoFolder))?;
    let resolved = files
        .resolve_in_folder(base, &rel, field, &shown)
        .map_err(|e| e.to_string())?;
    files
        .read(&resolved, field, max_len)
        .map_err(|e| e.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hostile_relative_paths_are_refused() {
        for (uri, why) in [
            ("../secret.bin", Refusal::ParentInUri),
            ("a/../../secret.bin", Refusal::ParentInUri),
            ("/etc/passwd", Refusal::Absolute),
            ("file:///etc/passwd", Refusal::Scheme),
            ("http://x/y.bin", Refusal::Scheme),
            ("%2e%2e/x.bin", Refusal::ParentInUri),
            ("%2F%65tc/passwd", Refusal::Absolute),
        ] {
            assert_eq!(relative_path(uri), Err(why), "{uri}");
        }
        for uri in ["%ff%fe.bin", "C:\\x.bin", "a\\..\\b", ""] {
            assert!(
                matches!(
                    relative_path(uri),
                    Err(Refusal::Scheme | Refusal::BadName(_))
                ),
                "{uri} accepted"
            );
        }
        assert!(relative_path("textures/a%20b.png").is_ok());
        // Regression: a multi-byte character across byte 5 must not panic.
        let files = SceneFiles::trusted();
        assert!(load_uri("dataé.bin", None, &files, "buffers[0].uri", 1).is_err());
        assert!(load_uri("abcdé", None, &files, "buffers[0].uri", 1).is_err());
        assert_eq!(
            relative_path("a%20b.png").unwrap(),
            PathBuf::from("a b.png")
        );
        // From memory, an external URI is refused, and the refusal is recorded.
        let e = load_uri("a.bin", None, &files, "images[2].uri", 1).unwrap_err();
        assert_eq!(
            e,
            "images[2].uri: \"a.bin\" refused: the scene was not loaded from a folder"
        );
        assert_eq!(files.refusal().unwrap().field, "buffers[0].uri");
    }

    #[test]
    fn data_uris_decode_within_the_cap() {
        let files = SceneFiles::trusted();
        let f = "buffers[0].uri";
        assert_eq!(
            decode_data_uri("data:application/octet-stream;base64,AAEC", &files, f).unwrap(),
            vec![0, 1, 2]
        );
        assert_eq!(
            decode_data_uri("data:,a%20b", &files, f).unwrap(),
            b"a b".to_vec()
        );
        assert!(decode_data_uri("data:;base64,@@@", &files, f).is_err());
        let dir = std::env::temp_dir();
        let small = SceneFiles::new(super::super::super::files::FilePolicy::Confined {
            root: dir,
            per_file_cap: 3,
            scene_budget: 100,
        })
        .unwrap();
        let e = decode_data_uri("data:;base64,AAECAwQF", &small, f).unwrap_err();
        assert!(e.starts_with(f) && e.contains("over the 3 bytes"), "{e}");
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
