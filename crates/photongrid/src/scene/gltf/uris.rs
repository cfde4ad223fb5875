//! Buffer and image URIs: `data:` URIs, relative file names, and keeping files inside the
//! scene's folder.

use super::{LoadError, Loader};
use std::path::{Component, Path};

impl Loader<'_> {
    /// External URIs must stay inside the scene's folder and exist.
    pub(super) fn check_uris(&self, doc: &gltf::Document) -> Result<(), LoadError> {
        let mut uris = Vec::new();
        for b in doc.buffers() {
            if let gltf::buffer::Source::Uri(u) = b.source() {
                uris.push((format!("buffers[{}]", b.index()), u.to_string()));
            }
        }
        for i in doc.images() {
            if let gltf::image::Source::Uri { uri, .. } = i.source() {
                uris.push((format!("images[{}]", i.index()), uri.to_string()));
            }
        }
        for (element, uri) in uris {
            if uri.starts_with("data:") {
                continue;
            }
            if uri.contains("://") {
                return Err(self.invalid(
                    element,
                    format!(
                        "URI '{uri}' points outside the file system; only relative file names and data: URIs are read"
                    ),
                ));
            }
            let decoded = urlencoding_decode(&uri);
            let rel = Path::new(&decoded);
            if escapes(rel) && !self.options.allow_external_uris {
                return Err(self.invalid(
                    element,
                    format!("URI '{uri}' leaves the scene's folder; copy the file next to the scene (or pass --allow-external-uris)"),
                ));
            }
            let full = self.base.join(rel);
            if !full.is_file() {
                return Err(self.invalid(element, format!("file '{}' not found", full.display())));
            }
        }
        Ok(())
    }

    pub(super) fn buffer_error(&self, doc: &gltf::Document, e: gltf::Error) -> LoadError {
        match e {
            gltf::Error::BufferLength {
                buffer,
                expected,
                actual,
            } => self.invalid(
                format!("buffers[{buffer}]"),
                format!("declares {expected} bytes but only {actual} are present: the file is truncated"),
            ),
            gltf::Error::MissingBlob => self.invalid(
                "buffers[0]",
                "refers to the GLB binary chunk, which is missing: the file is truncated",
            ),
            other => self.invalid(format!("buffers (of {})", doc.buffers().len()), other.to_string()),
        }
    }
}

/// True if a relative path is absolute or climbs above its starting folder (`a/../../b`).
fn escapes(rel: &Path) -> bool {
    rel.is_absolute()
        || rel
            .components()
            .try_fold(0i32, |depth, c| match c {
                Component::ParentDir => (depth > 0).then_some(depth - 1),
                Component::Normal(_) => Some(depth + 1),
                Component::CurDir => Some(depth),
                _ => None,
            })
            .is_none()
}

/// Percent-decoding of URIs (glTF URIs are RFC 3986).
fn urlencoding_decode(s: &str) -> String {
    let bytes = s.as_bytes();
    let mut out = Vec::with_capacity(bytes.len());
    let mut i = 0;
    while i < bytes.len() {
        // Hex digits are read from the bytes: slicing the str could split a UTF-8 character.
        let hex = |b: u8| (b as char).to_digit(16);
        if bytes[i] == b'%' && i + 2 < bytes.len() {
            if let (Some(hi), Some(lo)) = (hex(bytes[i + 1]), hex(bytes[i + 2])) {
                out.push((hi * 16 + lo) as u8);
                i += 3;
                continue;
            }
        }
        out.push(bytes[i]);
        i += 1;
    }
    String::from_utf8_lossy(&out).into_owned()
}
