//! Job images kept for the requests that follow, and HTTP's conditional and range requests on
//! them (RFC 9110, sections 13 and 14).
//!
//! An image is named by its job's results version ([`Sched::results_version`]: it changes
//! whenever a result is stored, and at every start) and its format: the same name, the same
//! bytes. That name is the image's entity tag, so a client that holds the image (a browser
//! showing a job's preview, a download tool resuming a large EXR) is answered 304 Not Modified,
//! or the bytes it asks for, without the frame being made again; and the last images made are
//! kept, up to a byte budget, for the next client that asks for the same one.
//!
//! [`Sched::results_version`]: crate::sched::Sched::results_version

use axum::body::Bytes;
use axum::http::{header, HeaderMap};
use std::collections::VecDeque;
use std::ops::Range;

/// The entity tag of an image of a job whose results version is `version`, in format `ext`
/// (`png`, `exr`, `hdr`): a strong tag, quoted as a header writes it.
pub fn entity_tag(version: &str, ext: &str) -> String {
    format!("\"{version}-{ext}\"")
}

/// The last images made, least recently used first, at most `limit` bytes together.
#[derive(Debug)]
pub struct ImageCache {
    limit: usize,
    held: usize,
    entries: VecDeque<Entry>,
}

#[derive(Debug)]
struct Entry {
    job: String,
    ext: &'static str,
    etag: String,
    bytes: Bytes,
    /// The samples the frame's results dropped as NaN, infinite or too large.
    dropped: u64,
}

impl ImageCache {
    /// An empty cache that holds at most `limit` bytes of images (0: none).
    pub fn new(limit: usize) -> ImageCache {
        ImageCache {
            limit,
            held: 0,
            entries: VecDeque::new(),
        }
    }

    /// The image of `job` tagged `etag`, if kept; it becomes the most recently used.
    pub fn get(&mut self, job: &str, etag: &str) -> Option<(Bytes, u64)> {
        let i = self
            .entries
            .iter()
            .position(|e| e.job == job && e.etag == etag)?;
        let e = self.entries.remove(i)?;
        let kept = (e.bytes.clone(), e.dropped);
        self.entries.push_back(e);
        Some(kept)
    }

    /// Keeps `bytes`, the image of `job` in format `ext` tagged `etag`, in place of any older
    /// image of the job in that format, and drops the least recently used images beyond the
    /// limit. An image larger than the limit is not kept.
    pub fn put(&mut self, job: &str, ext: &'static str, etag: String, bytes: Bytes, dropped: u64) {
        self.remove(|e| e.job == job && e.ext == ext);
        if bytes.len() > self.limit {
            return;
        }
        self.held += bytes.len();
        self.entries.push_back(Entry {
            job: job.to_string(),
            ext,
            etag,
            bytes,
            dropped,
        });
        while self.held > self.limit {
            let Some(e) = self.entries.pop_front() else {
                break;
            };
            self.held -= e.bytes.len();
        }
    }

    /// Drops every image of `job` (purged).
    pub fn forget(&mut self, job: &str) {
        self.remove(|e| e.job == job);
    }

    /// Bytes of the images kept.
    pub fn held(&self) -> usize {
        self.held
    }

    fn remove(&mut self, drop: impl Fn(&Entry) -> bool) {
        let held = &mut self.held;
        self.entries.retain(|e| {
            let gone = drop(e);
            if gone {
                *held -= e.bytes.len();
            }
            !gone
        });
    }
}

/// Whether the request's `If-None-Match` names `etag` (weak comparison: a `W/` prefix is
/// ignored) or is `*`: the client's copy is the current one.
pub fn not_modified(headers: &HeaderMap, etag: &str) -> bool {
    headers.get_all(header::IF_NONE_MATCH).iter().any(|v| {
        v.to_str().is_ok_and(|list| {
            list.split(',')
                .map(str::trim)
                .any(|t| t == "*" || t.strip_prefix("W/").unwrap_or(t) == etag)
        })
    })
}

/// What part of an image to send.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Part {
    /// All of it (200).
    Whole,
    /// These bytes (206).
    Bytes(Range<usize>),
    /// Nothing: the range starts past the end (416).
    Unsatisfiable,
}

/// The part of an image of `len` bytes tagged `etag` that a request asks for: one range of a
/// `Range: bytes=…` header (`a-b`, `a-`, or the last `n` bytes, `-n`) whose `If-Range`, if
/// any, names this image (strong comparison: only these very bytes may be resumed). The whole
/// image for no `Range`, another unit, several ranges, a range this cannot read, or an
/// `If-Range` naming another image or a date, as RFC 9110 lets a server answer a range request
/// it does not serve.
pub fn requested_part(headers: &HeaderMap, etag: &str, len: usize) -> Part {
    let Some(range) = headers.get(header::RANGE) else {
        return Part::Whole;
    };
    if let Some(if_range) = headers.get(header::IF_RANGE) {
        if if_range.as_bytes() != etag.as_bytes() {
            return Part::Whole;
        }
    }
    let Some(spec) = range.to_str().ok().and_then(|r| {
        let (unit, spec) = r.trim().split_once('=')?;
        unit.eq_ignore_ascii_case("bytes").then_some(spec)
    }) else {
        return Part::Whole;
    };
    if spec.contains(',') {
        return Part::Whole;
    }
    let Some((first, last)) = spec.trim().split_once('-') else {
        return Part::Whole;
    };
    // A position: digits only; beyond u64 it is past any end.
    let number = |s: &str| -> Option<u64> {
        (!s.is_empty() && s.bytes().all(|b| b.is_ascii_digit()))
            .then(|| s.parse().unwrap_or(u64::MAX))
    };
    let len64 = len as u64;
    match (first, last) {
        ("", n) => match number(n) {
            None => Part::Whole,
            Some(0) => Part::Unsatisfiable,
            Some(_) if len == 0 => Part::Unsatisfiable,
            Some(n) => Part::Bytes((len64 - n.min(len64)) as usize..len),
        },
        (a, b) => {
            let Some(start) = number(a) else {
                return Part::Whole;
            };
            let end = if b.is_empty() {
                u64::MAX
            } else {
                match number(b) {
                    Some(end) if end >= start => end,
                    _ => return Part::Whole,
                }
            };
            if start >= len64 {
                Part::Unsatisfiable
            } else {
                Part::Bytes(start as usize..end.saturating_add(1).min(len64) as usize)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use axum::http::HeaderValue;

    fn headers(pairs: &[(header::HeaderName, &str)]) -> HeaderMap {
        let mut h = HeaderMap::new();
        for (k, v) in pairs {
            h.append(k.clone(), HeaderValue::from_str(v).unwrap());
        }
        h
    }

    #[test]
    fn if_none_match_names_the_tag_or_any() {
        let tag = entity_tag("18c-3", "png");
        assert_eq!(tag, "\"18c-3-png\"");
        let m = |v: &str| not_modified(&headers(&[(header::IF_NONE_MATCH, v)]), &tag);
        assert!(m("\"18c-3-png\""));
        assert!(m("W/\"18c-3-png\""));
        assert!(m("\"x\", \"18c-3-png\""));
        assert!(m("*"));
        assert!(!m("\"18c-2-png\""));
        assert!(!m("\"18c-3-exr\""));
        assert!(!m("18c-3-png"), "an unquoted tag is not the tag");
        assert!(!not_modified(&HeaderMap::new(), &tag));
        // Two header lines are one list.
        let two = headers(&[
            (header::IF_NONE_MATCH, "\"a\""),
            (header::IF_NONE_MATCH, "\"18c-3-png\""),
        ]);
        assert!(not_modified(&two, &tag));
    }

    #[test]
    fn one_byte_range_is_served_and_anything_else_is_the_whole_image() {
        let tag = "\"t\"";
        let part = |range: &str| requested_part(&headers(&[(header::RANGE, range)]), tag, 100);
        assert_eq!(part("bytes=0-9"), Part::Bytes(0..10));
        assert_eq!(part("bytes=90-"), Part::Bytes(90..100));
        assert_eq!(part("bytes=90-1000"), Part::Bytes(90..100));
        assert_eq!(part("bytes=-10"), Part::Bytes(90..100));
        assert_eq!(part("bytes=-1000"), Part::Bytes(0..100));
        assert_eq!(part("Bytes=5-5"), Part::Bytes(5..6));
        assert_eq!(
            part("bytes=99-99999999999999999999999"),
            Part::Bytes(99..100)
        );
        assert_eq!(part("bytes=100-"), Part::Unsatisfiable);
        assert_eq!(part("bytes=99999999999999999999999-"), Part::Unsatisfiable);
        assert_eq!(part("bytes=-0"), Part::Unsatisfiable);
        for whole in [
            "bytes=0-1,5-6",
            "bytes=9-0",
            "bytes=a-b",
            "bytes=-",
            "bytes=5",
            "bytes=+1-2",
            "items=0-1",
            "0-1",
        ] {
            assert_eq!(part(whole), Part::Whole, "{whole}");
        }
        assert_eq!(requested_part(&HeaderMap::new(), tag, 100), Part::Whole);
        // Nothing to serve from an empty image but the whole of it.
        let empty = |range: &str| requested_part(&headers(&[(header::RANGE, range)]), tag, 0);
        assert_eq!(empty("bytes=0-"), Part::Unsatisfiable);
        assert_eq!(empty("bytes=-5"), Part::Unsatisfiable);
        // If-Range: only for these very bytes.
        let with_if = |if_range: &str| {
            requested_part(
                &headers(&[(header::RANGE, "bytes=0-9"), (header::IF_RANGE, if_range)]),
                tag,
                100,
            )
        };
        assert_eq!(with_if("\"t\""), Part::Bytes(0..10));
        assert_eq!(with_if("\"u\""), Part::Whole);
        assert_eq!(with_if("W/\"t\""), Part::Whole);
        assert_eq!(with_if("Sun, 06 Dec 2026 18:00:00 GMT"), Part::Whole);
    }

    #[test]
    fn the_cache_keeps_the_newest_image_of_each_job_and_format_within_its_limit() {
        let b = |n: usize| Bytes::from(vec![0u8; n]);
        let mut c = ImageCache::new(100);
        c.put("j1", "png", "\"a\"".into(), b(40), 0);
        c.put("j1", "exr", "\"b\"".into(), b(40), 0);
        assert_eq!(c.held(), 80);
        assert_eq!(c.get("j1", "\"a\"").map(|x| x.0.len()), Some(40));
        // A newer png of j1 replaces the older one.
        c.put("j1", "png", "\"c\"".into(), b(30), 0);
        assert!(c.get("j1", "\"a\"").is_none());
        assert_eq!(c.held(), 70);
        // Over the limit: the least recently used goes (the exr, not read since).
        c.put("j2", "png", "\"d\"".into(), b(50), 0);
        assert!(c.get("j1", "\"b\"").is_none());
        assert!(c.get("j1", "\"c\"").is_some() && c.get("j2", "\"d\"").is_some());
        assert_eq!(c.held(), 80);
        // Larger than the whole cache: not kept, and the older image of its kind is gone.
        c.put("j2", "png", "\"e\"".into(), b(101), 0);
        assert!(c.get("j2", "\"e\"").is_none() && c.get("j2", "\"d\"").is_none());
        c.forget("j1");
        assert_eq!(c.held(), 0);
        let mut none = ImageCache::new(0);
        none.put("j", "png", "\"a\"".into(), b(1), 0);
        assert!(none.get("j", "\"a\"").is_none());
    }
}
