//! Where bytes come from: the scene file, buffer and image URIs (`data:` URIs and relative file
//! names, nothing else), and the rules for the files they name: only regular files are read,
//! and a file must resolve (symbolic links included) inside the scene's folder unless
//! [`LoadOptions::allow_external_uris`](super::LoadOptions) says otherwise. Nothing read from a
//! file is ever echoed in an error message.

use super::{LoadError, Loader};
use gltf::json::Root;
use std::borrow::Cow;
use std::io::Read;
use std::path::{Component, Path, PathBuf};

/// Where the bytes of a buffer or an image come from.
pub(super) enum Source<'a> {
    /// The GLB binary chunk (a buffer without a URI).
    Glb,
    /// A base64 `data:` URI: its media type and payload.
    Data { media_type: &'a str, payload: &'a str },
    /// A file: its resolved path and its length when it was checked.
    File { path: PathBuf, len: u64 },
    /// An image stored in a bufferView.
    View(usize),
}

/// The sources of every buffer and image of a file, resolved and checked.
pub(super) struct Sources<'a> {
    pub(super) buffers: Vec<Source<'a>>,
    pub(super) images: Vec<Source<'a>>,
}

/// Read a regular file of at most `limit` bytes (its length is checked before it is opened, so
/// a FIFO, a device or a folder is refused without blocking or reading).
pub(super) fn read_regular_file(path: &Path, limit: u64) -> std::io::Result<Vec<u8>> {
    let meta = std::fs::metadata(path)?;
    not_regular(&meta).map_or(Ok(()), |what| Err(std::io::Error::other(what)))?;
    if meta.len() > limit {
        return Err(std::io::Error::other(format!(
            "the file has {} bytes, more than the {limit} the loader may read (the memory budget)",
            meta.len()
        )));
    }
    let mut data = Vec::with_capacity(meta.len() as usize);
    std::fs::File::open(path)?.take(meta.len()).read_to_end(&mut data)?;
    Ok(data)
}

/// Why a file's metadata is not that of a regular file (None if it is one).
fn not_regular(meta: &std::fs::Metadata) -> Option<String> {
    if meta.is_file() {
        return None;
    }
    if meta.is_dir() {
        return Some("is a folder, not a file".into());
    }
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        let t = meta.file_type();
        let kind = if t.is_fifo() {
            "a FIFO (named pipe)"
        } else if t.is_char_device() || t.is_block_device() {
            "a device"
        } else if t.is_socket() {
            "a socket"
        } else {
            "a special file"
        };
        return Some(format!("is {kind}, not a regular file; only regular files are read"));
    }
    #[allow(unreachable_code)]
    Some("is not a regular file; only regular files are read".into())
}

impl Loader<'_> {
    /// Resolve and check the URI of every buffer and image: syntax, scheme, confinement to the
    /// scene's folder, existence, regular file. Nothing is read yet.
    pub(super) fn resolve_uris<'r>(&self, root: &'r Root) -> Result<Sources<'r>, LoadError> {
        let mut sources = Sources {
            buffers: Vec::with_capacity(root.buffers.len()),
            images: Vec::with_capacity(root.images.len()),
        };
        for (b, buffer) in root.buffers.iter().enumerate() {
            sources.buffers.push(match &buffer.uri {
                Some(uri) => self.resolve(&format!("buffers[{b}]"), uri)?,
                None => Source::Glb,
            });
        }
        for (i, image) in root.images.iter().enumerate() {
            sources.images.push(match (&image.uri, &image.buffer_view) {
                (Some(uri), _) => self.resolve(&format!("images[{i}]"), uri)?,
                (None, Some(v)) => Source::View(v.value()),
                (None, None) => return Err(self.invalid(format!("images[{i}]"), "has neither a uri nor a bufferView")),
            });
        }
        Ok(sources)
    }

    fn resolve<'r>(&self, element: &str, uri: &'r str) -> Result<Source<'r>, LoadError> {
        if let Some(rest) = uri.strip_prefix("data:") {
            let Some((header, payload)) = rest.split_once(',') else {
                return Err(self.invalid(element, "data: URI has no ',' before its data"));
            };
            let Some(media_type) = header.strip_suffix(";base64") else {
                return Err(self.invalid(element, "data: URI is not base64 (only ';base64,' data URIs are read)"));
            };
            return Ok(Source::Data { media_type, payload });
        }
        if let Some(scheme) = scheme(uri) {
            return Err(self.invalid(
                element,
                format!("URI '{uri}' has the scheme '{scheme}:' and points outside the file system; only relative file names and data: URIs are read"),
            ));
        }
        let decoded = percent_decode(uri).map_err(|e| self.invalid(element, format!("URI '{uri}' {e}")))?;
        let rel = Path::new(&decoded);
        if escapes(rel) && !self.options.allow_external_uris {
            return Err(self.invalid(
                element,
                format!("URI '{uri}' leaves the scene's folder; copy the file next to the scene (or pass --allow-external-uris)"),
            ));
        }
        let full = self.base.join(rel);
        let meta = match std::fs::metadata(&full) {
            Ok(m) => m,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                return Err(self.invalid(element, format!("file '{}' not found", full.display())))
            }
            Err(e) => return Err(self.invalid(element, format!("cannot read '{}': {e}", full.display()))),
        };
        let resolved = self.confine(element, uri, &full)?;
        if let Some(what) = not_regular(&meta) {
            return Err(self.invalid(element, format!("'{}' {what}", full.display())));
        }
        Ok(Source::File {
            path: resolved,
            len: meta.len(),
        })
    }

    /// The canonical path of `full`, which must lie inside the scene's folder (symbolic links
    /// resolved) unless external URIs are allowed.
    fn confine(&self, element: &str, uri: &str, full: &Path) -> Result<PathBuf, LoadError> {
        let canonical = |p: &Path| {
            let p = if p.as_os_str().is_empty() { Path::new(".") } else { p };
            p.canonicalize()
                .map_err(|e| self.invalid(element, format!("cannot resolve '{}': {e}", p.display())))
        };
        let resolved = canonical(full)?;
        if !self.options.allow_external_uris && !resolved.starts_with(canonical(&self.base)?) {
            return Err(self.invalid(
                element,
                format!("URI '{uri}' resolves (through a symbolic link) to '{}', outside the scene's folder; copy the file next to the scene (or pass --allow-external-uris)", resolved.display()),
            ));
        }
        Ok(resolved)
    }

    /// The bytes of every buffer, each at least its declared byteLength (files are read up to
    /// that length, no further).
    pub(super) fn read_buffers(
        &self,
        root: &Root,
        sources: &Sources,
        mut blob: Option<Vec<u8>>,
    ) -> Result<Vec<Vec<u8>>, LoadError> {
        let mut out = Vec::with_capacity(root.buffers.len());
        for (b, buffer) in root.buffers.iter().enumerate() {
            let element = format!("buffers[{b}]");
            let declared = buffer.byte_length.0;
            let mut data = match &sources.buffers[b] {
                Source::Glb => blob.take().ok_or_else(|| {
                    self.invalid(
                        &element,
                        "refers to the GLB binary chunk, which is missing: the file is truncated",
                    )
                })?,
                Source::Data { payload, .. } => decode_base64(payload)
                    .map_err(|e| self.invalid(&element, format!("data: URI is not valid base64: {e}")))?,
                Source::File { path, len } => self.read_buffer_file(&element, path, *len, declared)?,
                Source::View(_) => unreachable!("buffers have no bufferView source"),
            };
            while data.len() % 4 != 0 {
                data.push(0);
            }
            if (data.len() as u64) < declared {
                return Err(self.invalid(
                    &element,
                    format!(
                        "declares {declared} bytes but only {} are present: the file is truncated",
                        data.len()
                    ),
                ));
            }
            out.push(data);
        }
        Ok(out)
    }

    fn read_buffer_file(&self, element: &str, path: &Path, len: u64, declared: u64) -> Result<Vec<u8>, LoadError> {
        if len < declared {
            return Err(self.invalid(
                element,
                format!(
                    "declares {declared} bytes but '{}' has only {len}: the file is truncated",
                    path.display()
                ),
            ));
        }
        let read = || -> std::io::Result<Vec<u8>> {
            let meta = std::fs::metadata(path)?;
            not_regular(&meta).map_or(Ok(()), |what| Err(std::io::Error::other(what)))?;
            let mut data = Vec::with_capacity(declared as usize);
            std::fs::File::open(path)?.take(declared).read_to_end(&mut data)?;
            Ok(data)
        };
        read().map_err(|e| self.invalid(element, format!("cannot read '{}': {e}", path.display())))
    }

    /// The encoded bytes of image `i` (at most `limit` from a file).
    pub(super) fn image_bytes<'b>(
        &self,
        root: &Root,
        sources: &Sources,
        buffers: &'b [Vec<u8>],
        i: usize,
        limit: u64,
    ) -> Result<Cow<'b, [u8]>, LoadError> {
        let element = format!("images[{i}]");
        match &sources.images[i] {
            Source::View(v) => {
                let view = &root.buffer_views[*v];
                let start = view.byte_offset.map(|o| o.0).unwrap_or(0) as usize;
                let end = start + view.byte_length.0 as usize;
                let data = buffers.get(view.buffer.value()).and_then(|b| b.get(start..end));
                let data = data.ok_or_else(|| self.invalid(&element, "its bufferView lies outside its buffer"))?;
                Ok(Cow::Borrowed(data))
            }
            Source::Data { payload, .. } => decode_base64(payload)
                .map(Cow::Owned)
                .map_err(|e| self.invalid(&element, format!("data: URI is not valid base64: {e}"))),
            Source::File { path, .. } => read_regular_file(path, limit)
                .map(Cow::Owned)
                .map_err(|e| self.invalid(&element, format!("cannot read '{}': {e}", path.display()))),
            Source::Glb => unreachable!("images have a uri or a bufferView"),
        }
    }
}

/// The scheme of a URI (`file`, `http`, `C` of `C:/x`), if it has one: a ':' before the first
/// '/', '?' or '#'.
fn scheme(uri: &str) -> Option<&str> {
    let end = uri.find(['/', '?', '#']).unwrap_or(uri.len());
    uri[..end].find(':').map(|colon| &uri[..colon])
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

/// Percent-decoding of URIs (glTF URIs are RFC 3986). A '%' not followed by two hex digits is
/// kept as it is; escapes must decode to UTF-8 without NUL.
fn percent_decode(s: &str) -> Result<String, String> {
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
    if out.contains(&0) {
        return Err("contains a NUL byte (%00)".into());
    }
    String::from_utf8(out).map_err(|e| {
        format!(
            "has percent-escapes that do not decode to UTF-8 text (bytes {}); glTF URIs are UTF-8",
            e.as_bytes()[e.utf8_error().valid_up_to()..]
                .iter()
                .take(e.utf8_error().error_len().unwrap_or(4))
                .map(|b| format!("%{b:02x}"))
                .collect::<String>()
        )
    })
}

/// Standard base64 (RFC 4648), padding optional.
fn decode_base64(s: &str) -> Result<Vec<u8>, String> {
    let s = s.trim_end_matches('=');
    let mut out = Vec::with_capacity(s.len() / 4 * 3 + 3);
    let mut acc = 0u32;
    let mut bits = 0;
    for (i, c) in s.bytes().enumerate() {
        let v = match c {
            b'A'..=b'Z' => c - b'A',
            b'a'..=b'z' => c - b'a' + 26,
            b'0'..=b'9' => c - b'0' + 52,
            b'+' => 62,
            b'/' => 63,
            _ => return Err(format!("byte {i} of the data is not a base64 character")),
        };
        acc = acc << 6 | v as u32;
        bits += 6;
        if bits >= 8 {
            bits -= 8;
            out.push((acc >> bits) as u8);
            acc &= (1 << bits) - 1;
        }
    }
    if s.len() % 4 == 1 {
        return Err("the data's length is not that of base64".into());
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn base64_round_trip() {
        assert_eq!(decode_base64("aGVsbG8=").unwrap(), b"hello");
        assert_eq!(decode_base64("aGVsbG8").unwrap(), b"hello");
        assert_eq!(decode_base64("AAECAwQF").unwrap(), [0, 1, 2, 3, 4, 5]);
        assert!(decode_base64("aGV$").is_err());
        assert!(decode_base64("aGVsb").is_err());
    }

    #[test]
    fn schemes_and_escapes() {
        assert_eq!(scheme("file:/etc/passwd"), Some("file"));
        assert_eq!(scheme("http://x/y"), Some("http"));
        assert_eq!(scheme("C:/x.bin"), Some("C"));
        assert_eq!(scheme("a/b:c.bin"), None);
        assert_eq!(scheme("scene.bin"), None);
        assert_eq!(percent_decode("a%20b").unwrap(), "a b");
        assert_eq!(percent_decode("%€/x").unwrap(), "%€/x");
        assert!(percent_decode("%ff.bin").unwrap_err().contains("%ff"));
        assert!(percent_decode("a%00").is_err());
        assert!(escapes(Path::new("../x")));
        assert!(escapes(Path::new("a/../../x")));
        assert!(!escapes(Path::new("a/../x")));
    }
}
