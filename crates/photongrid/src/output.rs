//! Writing images: one single-part EXR (float32 `R,G,B,A` plus optional AOV layers named as
//! Blender names its passes) and an optional PNG preview, both written atomically (temporary
//! file, then rename).

use crate::film::Film;
use exr::prelude::{AnyChannel, AnyChannels, Encoding, FlatSamples, Layer, LayerAttributes, WritableImage};
use std::path::{Path, PathBuf};

/// Output failures, naming the file.
#[derive(Debug, thiserror::Error)]
pub enum OutputError {
    /// The file could not be written.
    #[error("{path}: cannot write: {source}; check that the folder exists and is writable")]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// EXR encoding or decoding failed.
    #[error("{path}: EXR error: {message}")]
    Exr {
        /// The file.
        path: PathBuf,
        /// What the EXR library said.
        message: String,
    },
    /// The output is refused before anything is written: it is not a regular file, it is an
    /// input, or it is another output.
    #[error("{path}: {message}")]
    Refused {
        /// The file.
        path: PathBuf,
        /// Why, and what to do.
        message: String,
    },
    /// PNG encoding failed.
    #[error("{path}: PNG error: {message}")]
    Png {
        /// The file.
        path: PathBuf,
        /// What the PNG encoder said.
        message: String,
    },
}

/// Which AOV layers to add to the EXR. Their channels are named as Blender names the passes
/// (`<pass>.<channel>`), so Blender's image and compositor nodes show them as passes.
#[derive(Clone, Copy, Debug, Default, serde::Serialize)]
pub struct AovSelection {
    /// `DiffCol.R/G/B`: albedo of the first diffuse surface (Blender's Diffuse Color).
    pub albedo: bool,
    /// `Normal.X/Y/Z`: shading normal at the first hit, world space of the file (glTF: Y up).
    pub normal: bool,
    /// `Depth.Z`: the film's depth; [`BACKGROUND_DEPTH`] where the camera ray hit nothing.
    pub depth: bool,
    /// `PhotonDensity.X` (photons/m²) and `PhotonRadius.X` (m) of the photon estimate.
    pub photons: bool,
}

/// `Depth.Z` where the camera ray hit nothing: what Blender's Cycles writes for the background.
pub const BACKGROUND_DEPTH: f32 = 1e10;

impl AovSelection {
    /// Every layer.
    pub fn all() -> Self {
        AovSelection {
            albedo: true,
            normal: true,
            depth: true,
            photons: true,
        }
    }
}

/// `name` with every character other than letters, digits, `-` and `_` made `_`, for file names.
pub fn safe_name(name: &str) -> String {
    name.chars()
        .map(|c| {
            if c.is_alphanumeric() || c == '-' || c == '_' {
                c
            } else {
                '_'
            }
        })
        .collect()
}

/// Output path for a camera: `{camera}` replaced (by the name with characters other than
/// letters, digits, `-` and `_` made `_`), or the name appended when several cameras share one path.
pub fn output_for(pattern: &Path, camera: &str, several: bool) -> PathBuf {
    let s = pattern.to_string_lossy();
    let safe = safe_name(camera);
    if s.contains("{camera}") {
        return PathBuf::from(s.replace("{camera}", &safe));
    }
    if !several {
        return pattern.to_path_buf();
    }
    let stem = pattern
        .file_stem()
        .map(|s| s.to_string_lossy().to_string())
        .unwrap_or_default();
    let ext = pattern
        .extension()
        .map(|e| format!(".{}", e.to_string_lossy()))
        .unwrap_or_default();
    pattern.with_file_name(format!("{stem}_{safe}{ext}"))
}

/// Write `bytes` to `path` atomically: a reader sees the old file or the whole new one.
///
/// The bytes go to a temporary file beside `path`, `.<name>.<pid>-<host>.<random>.tmp`,
/// created exclusively (`O_CREAT|O_EXCL`: a file or symbolic link already at that name is
/// never opened, so a planted link cannot redirect the write), then renamed over `path`. An
/// existing `path` that is not a regular file (a folder, device, FIFO or socket, after
/// following symbolic links) is refused and left alone. Temporary files of earlier writes to
/// the same `path` that were killed before their rename are removed first ([`clean_stale_temps`]).
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), OutputError> {
    let io = |source| OutputError::Io {
        path: path.to_path_buf(),
        source,
    };
    check_output_kind(path)?;
    let dir = parent_dir(path);
    let name = path
        .file_name()
        .filter(|n| !n.is_empty() && *n != "." && *n != "..")
        .ok_or_else(|| io(std::io::Error::new(std::io::ErrorKind::InvalidInput, "not a file name")))?;
    let name = name.to_string_lossy();
    clean_stale_temps(path);
    let (tmp, mut f) = create_temp(&dir, &name).map_err(io)?;
    let result = (|| {
        use std::io::Write;
        f.write_all(bytes)?;
        f.sync_all()?;
        drop(f);
        std::fs::rename(&tmp, path)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result.map_err(io)
}

/// The folder of `path` (`.` for a bare file name).
fn parent_dir(path: &Path) -> PathBuf {
    path.parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."))
        .to_path_buf()
}

/// Temporary files older than this are stale whoever made them (a write takes seconds).
const STALE_TEMP_SECONDS: u64 = 3600;

/// The part of a temporary file's name taken from the output's name: at most 200 bytes, so
/// that the whole name stays within the usual 255-byte limit.
fn temp_stem(name: &str) -> &str {
    let mut end = name.len().min(200);
    while !name.is_char_boundary(end) {
        end -= 1;
    }
    &name[..end]
}

/// A short tag of this machine (hash of its host name), so that a process id in a temporary
/// file's name is only judged on the machine that wrote it (outputs on shared folders).
fn host_tag() -> String {
    static TAG: std::sync::OnceLock<String> = std::sync::OnceLock::new();
    TAG.get_or_init(|| {
        let host = std::fs::read_to_string("/proc/sys/kernel/hostname")
            .or_else(|_| std::fs::read_to_string("/etc/hostname"))
            .unwrap_or_default();
        let mut h: u32 = 0x811c_9dc5;
        for b in host.trim().bytes() {
            h ^= b as u32;
            h = h.wrapping_mul(0x0100_0193);
        }
        format!("{h:08x}")
    })
    .clone()
}

/// 64 unpredictable bits: std's per-process random SipHash keys over the time and a counter.
fn random_u64() -> u64 {
    use std::hash::{BuildHasher, Hasher};
    static COUNTER: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
    let mut h = std::collections::hash_map::RandomState::new().build_hasher();
    h.write_u64(COUNTER.fetch_add(1, std::sync::atomic::Ordering::Relaxed));
    h.write_u128(
        std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_nanos())
            .unwrap_or(0),
    );
    h.write_u32(std::process::id());
    h.finish()
}

/// Create a new temporary file for `name` in `dir`, exclusively (never an existing file or
/// link), under a random name.
fn create_temp(dir: &Path, name: &str) -> std::io::Result<(PathBuf, std::fs::File)> {
    let mut last = None;
    for _ in 0..16 {
        let tmp = dir.join(format!(
            ".{}.{}-{}.{:016x}.tmp",
            temp_stem(name),
            std::process::id(),
            host_tag(),
            random_u64()
        ));
        match std::fs::OpenOptions::new().write(true).create_new(true).open(&tmp) {
            Ok(f) => return Ok((tmp, f)),
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => last = Some(e),
            Err(e) => return Err(e),
        }
    }
    Err(last.unwrap_or_else(|| std::io::Error::other("no free temporary file name")))
}

/// The writer of a temporary file of ours for an output named `name`, from the file's name:
/// `Some(Some((pid, host)))` for `.<name>.<pid>-<host>.<16 hex>.tmp`, `Some(None)` for the
/// older `.<name>.<pid>.tmp`, `None` for any other name.
fn temp_writer(file: &str, name: &str) -> Option<Option<(u32, String)>> {
    let rest = file.strip_prefix('.')?.strip_suffix(".tmp")?;
    let rest = rest.strip_prefix(temp_stem(name))?.strip_prefix('.')?;
    if let Some((who, random)) = rest.split_once('.') {
        let (pid, host) = who.split_once('-')?;
        let ok = random.len() == 16
            && random.bytes().all(|b| b.is_ascii_hexdigit())
            && host.len() == 8
            && host.bytes().all(|b| b.is_ascii_hexdigit());
        let pid: u32 = pid.parse().ok().filter(|_| ok)?;
        return Some(Some((pid, host.to_string())));
    }
    // Before random names: `.<name>.<pid>.tmp`.
    (!rest.is_empty() && rest.bytes().all(|b| b.is_ascii_digit()) && temp_stem(name) == name).then_some(None)
}

/// Remove the temporary files that killed writes to `path` left beside it: regular files
/// whose names follow this module's pattern for `path`'s name, and that are older than an
/// hour or were made on this machine by a process that no longer runs. Anything else —
/// other names, links, folders, a live writer's file — is left alone. Returns how many were
/// removed. Errors are ignored (cleaning is a courtesy, the write does not depend on it).
pub fn clean_stale_temps(path: &Path) -> usize {
    let Some(name) = path.file_name().map(|n| n.to_string_lossy().into_owned()) else {
        return 0;
    };
    let Ok(entries) = std::fs::read_dir(parent_dir(path)) else {
        return 0;
    };
    let own_pid = std::process::id();
    let mut removed = 0;
    for e in entries.flatten() {
        let file = e.file_name();
        let Some(writer) = file.to_str().and_then(|f| temp_writer(f, &name)) else {
            continue;
        };
        // `DirEntry::metadata` does not follow links.
        let Ok(meta) = e.metadata() else { continue };
        if !meta.is_file() {
            continue;
        }
        let old = meta
            .modified()
            .ok()
            .and_then(|m| m.elapsed().ok())
            .is_some_and(|age| age.as_secs() >= STALE_TEMP_SECONDS);
        let dead = match &writer {
            Some((pid, host)) => {
                *pid != own_pid
                    && *host == host_tag()
                    && Path::new("/proc/self").exists()
                    && !Path::new("/proc").join(pid.to_string()).exists()
            }
            None => false,
        };
        if (old || dead) && std::fs::remove_file(e.path()).is_ok() {
            removed += 1;
        }
    }
    removed
}

/// What kind of file system object `meta` is, for messages.
fn kind_of(meta: &std::fs::Metadata) -> &'static str {
    use std::os::unix::fs::FileTypeExt;
    let t = meta.file_type();
    if t.is_dir() {
        "a folder"
    } else if t.is_fifo() {
        "a FIFO (named pipe)"
    } else if t.is_char_device() || t.is_block_device() {
        "a device"
    } else if t.is_socket() {
        "a socket"
    } else if t.is_file() {
        "a regular file"
    } else {
        "not a regular file"
    }
}

/// Refuse an output path that exists and is not a regular file once links are followed (a
/// folder, device, FIFO or socket would be replaced by a regular file, or block the writer).
pub fn check_output_kind(path: &Path) -> Result<(), OutputError> {
    match std::fs::metadata(path) {
        Ok(meta) if !meta.is_file() => Err(OutputError::Refused {
            path: path.to_path_buf(),
            message: format!(
                "is {}, not a regular file: outputs are only written as regular files; choose another file name",
                kind_of(&meta)
            ),
        }),
        _ => Ok(()),
    }
}

/// Where a path leads, for telling whether two spellings name the same file: every existing
/// prefix resolved (symbolic links, `..`, relative to the working folder), the rest taken as
/// spelt. With `follow_last` false the last component is not resolved: a write by rename
/// replaces a link there rather than the file it points to.
pub fn resolved(path: &Path, follow_last: bool) -> PathBuf {
    use std::path::Component;
    let absolute = if path.is_absolute() {
        path.to_path_buf()
    } else {
        std::env::current_dir().unwrap_or_default().join(path)
    };
    let components: Vec<Component> = absolute.components().collect();
    let mut out = PathBuf::new();
    let mut existing = true;
    for (i, c) in components.iter().enumerate() {
        let last = i + 1 == components.len();
        match c {
            Component::Prefix(_) | Component::RootDir => out.push(c.as_os_str()),
            Component::CurDir => {}
            // While `out` is resolved its parent is the physical one; after, `..` is lexical.
            Component::ParentDir => {
                out.pop();
            }
            Component::Normal(n) => {
                let next = out.join(n);
                if existing && (follow_last || !last) {
                    match std::fs::canonicalize(&next) {
                        Ok(p) => {
                            out = p;
                            continue;
                        }
                        Err(_) => existing = false,
                    }
                }
                out = next;
            }
        }
    }
    out
}

/// A file's device and inode: the same file, however its path is spelt.
type FileId = (u64, u64);

/// Device and inode of the file `path` leads to, if it exists.
fn file_id(path: &Path) -> Option<FileId> {
    use std::os::unix::fs::MetadataExt;
    std::fs::metadata(path).ok().map(|m| (m.dev(), m.ino()))
}

/// The files a run reads and writes, checked before any work: every output must be a
/// regular-file path in an existing folder, must not be one of the inputs (however spelt:
/// relative or absolute, through symbolic links, or a hard link to it), and must not be
/// another output.
#[derive(Debug, Default)]
pub struct OutputPlan {
    /// (what, as given, resolved without the last link, resolved fully, device and inode)
    inputs: Vec<(String, PathBuf, PathBuf, PathBuf, Option<FileId>)>,
    /// (what, as given, resolved without the last link, device and inode)
    outputs: Vec<(String, PathBuf, PathBuf, Option<FileId>)>,
    by_resolved: std::collections::HashMap<PathBuf, usize>,
}

impl OutputPlan {
    /// An empty plan.
    pub fn new() -> Self {
        Self::default()
    }

    /// A file the run reads (`what`: "the scene", "the jobs file"...); outputs may not replace it.
    pub fn input(&mut self, what: impl Into<String>, path: &Path) {
        self.inputs.push((
            what.into(),
            path.to_path_buf(),
            resolved(path, false),
            resolved(path, true),
            file_id(path),
        ));
    }

    /// A file the run writes (`what`: "--output", "--png of camera 'Cam'"...). Refused when
    /// it is not a regular file or it names an input or an earlier output. A missing folder
    /// is not refused: the CLI creates output folders before any work.
    pub fn output(&mut self, what: impl Into<String>, path: &Path) -> Result<(), OutputError> {
        let what = what.into();
        let refuse = |message: String| OutputError::Refused {
            path: path.to_path_buf(),
            message,
        };
        let name_ok = path.file_name().is_some_and(|n| !n.is_empty() && n != "." && n != "..");
        if !name_ok || path.as_os_str().to_string_lossy().ends_with('/') {
            return Err(refuse(format!("{what} is not a file name")));
        }
        check_output_kind(path).map_err(|e| match e {
            OutputError::Refused { message, .. } => refuse(format!("{what} {message}")),
            e => e,
        })?;
        let res = resolved(path, false);
        let id = file_id(path);
        for (input, given, entry, target, input_id) in &self.inputs {
            if res == *entry || res == *target || (id.is_some() && id == *input_id) {
                return Err(refuse(format!(
                    "{what} is {input} ({}): writing it would replace an input; choose another file name",
                    given.display()
                )));
            }
        }
        let clash = self
            .by_resolved
            .get(&res)
            .copied()
            .or_else(|| id.and_then(|id| self.outputs.iter().position(|(_, _, _, other)| *other == Some(id))));
        if let Some(i) = clash {
            let (other, given, _, _) = &self.outputs[i];
            let same = if given == path {
                String::new()
            } else {
                format!(" ({})", given.display())
            };
            return Err(refuse(format!(
                "{what} is the same file as {other}{same}: one would overwrite the other; give each its own file name"
            )));
        }
        self.by_resolved.insert(res.clone(), self.outputs.len());
        self.outputs.push((what, path.to_path_buf(), res, id));
        Ok(())
    }
}

/// Encode a film as a single-part EXR with float32 channels: `R,G,B` radiance, `A` coverage
/// (1 where the pixel's first camera ray hit a surface, 0 for the background: the background is
/// transparent) and the AOV layers `aovs` selects. A value that is NaN or infinite is written
/// as 0 (the render reports how many pixels were: [`Film::nonfinite`]), so that no image this
/// renderer writes holds a non-finite value.
pub fn encode_exr(film: &Film, aovs: AovSelection) -> std::result::Result<Vec<u8>, String> {
    let size = (film.width as usize, film.height as usize);
    let ch = |name: &str, f: &dyn Fn(usize) -> f32| {
        let finite = |i| Some(f(i)).filter(|v| v.is_finite()).unwrap_or(0.0);
        AnyChannel::new(name, FlatSamples::F32((0..film.color.len()).map(finite).collect()))
    };
    let hit = |i: usize| film.aov[i].depth > 0.0;
    let mut channels = vec![
        ch("R", &|i| film.color[i].x),
        ch("G", &|i| film.color[i].y),
        ch("B", &|i| film.color[i].z),
        ch("A", &|i| if hit(i) { 1.0 } else { 0.0 }),
    ];
    if aovs.albedo {
        channels.push(ch("DiffCol.R", &|i| film.aov[i].albedo.x));
        channels.push(ch("DiffCol.G", &|i| film.aov[i].albedo.y));
        channels.push(ch("DiffCol.B", &|i| film.aov[i].albedo.z));
    }
    if aovs.normal {
        channels.push(ch("Normal.X", &|i| film.aov[i].normal.x));
        channels.push(ch("Normal.Y", &|i| film.aov[i].normal.y));
        channels.push(ch("Normal.Z", &|i| film.aov[i].normal.z));
    }
    if aovs.depth {
        channels.push(ch("Depth.Z", &|i| {
            if hit(i) {
                film.aov[i].depth
            } else {
                BACKGROUND_DEPTH
            }
        }));
    }
    if aovs.photons {
        channels.push(ch("PhotonDensity.X", &|i| film.aov[i].density));
        channels.push(ch("PhotonRadius.X", &|i| film.aov[i].radius));
    }
    let layer = Layer::new(
        size,
        LayerAttributes::default(),
        Encoding::FAST_LOSSLESS,
        AnyChannels::sort(channels.into()),
    );
    let image = exr::image::Image::from_layer(layer);
    let mut buf = std::io::Cursor::new(Vec::new());
    image.write().to_buffered(&mut buf).map_err(|e| e.to_string())?;
    Ok(buf.into_inner())
}

/// Write the film as EXR, atomically.
pub fn write_exr(path: &Path, film: &Film, aovs: AovSelection) -> Result<(), OutputError> {
    let bytes = encode_exr(film, aovs).map_err(|message| OutputError::Exr {
        path: path.to_path_buf(),
        message,
    })?;
    write_atomic(path, &bytes)
}

/// Write a 2D field (a plane's count texture) as a one-channel `Y` EXR, atomically.
pub fn write_field_exr(path: &Path, field: &crate::grid::wavelet::Field2) -> Result<(), OutputError> {
    let data = field
        .data
        .iter()
        .map(|v| if v.is_finite() { *v } else { 0.0 })
        .collect();
    let ch = AnyChannel::new("Y", FlatSamples::F32(data));
    let layer = Layer::new(
        (field.width, field.height),
        LayerAttributes::default(),
        Encoding::FAST_LOSSLESS,
        AnyChannels::sort(vec![ch].into()),
    );
    let mut buf = std::io::Cursor::new(Vec::new());
    exr::image::Image::from_layer(layer)
        .write()
        .to_buffered(&mut buf)
        .map_err(|e| OutputError::Exr {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
    write_atomic(path, &buf.into_inner())
}

/// Linear → sRGB 8-bit with exposure and clipping (preview only).
pub fn linear_to_srgb8(v: f32) -> u8 {
    let v = v.clamp(0.0, 1.0);
    let s = if v <= 0.003_130_8 {
        12.92 * v
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    };
    (s * 255.0 + 0.5) as u8
}

/// Write an sRGB PNG preview (clipped at 1 after `exposure` stops), atomically.
pub fn write_png(path: &Path, film: &Film, exposure: f32) -> Result<(), OutputError> {
    let scale = 2f32.powf(exposure);
    let mut rgb = Vec::with_capacity(film.color.len() * 3);
    for c in &film.color {
        for v in c.to_array() {
            rgb.push(linear_to_srgb8(if v.is_finite() { v * scale } else { 0.0 }));
        }
    }
    let mut bytes = Vec::new();
    let enc = image::codecs::png::PngEncoder::new(&mut bytes);
    image::ImageEncoder::write_image(enc, &rgb, film.width, film.height, image::ExtendedColorType::Rgb8).map_err(
        |e| OutputError::Png {
            path: path.to_path_buf(),
            message: e.to_string(),
        },
    )?;
    write_atomic(path, &bytes)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Rgb;

    #[test]
    fn exr_round_trip_with_aovs() {
        let mut film = Film::new(5, 3);
        for (i, c) in film.color.iter_mut().enumerate() {
            *c = Rgb::new(i as f32, 0.5, 1e-3);
        }
        film.aov[7].depth = 2.5;
        let dir = std::env::temp_dir().join(format!("pg-exr-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("a.exr");
        write_exr(&p, &film, AovSelection::all()).unwrap();
        let image = exr::prelude::read_all_flat_layers_from_file(&p).unwrap();
        let layer = &image.layer_data[0];
        assert_eq!((layer.size.width(), layer.size.height()), (5, 3));
        let channel = |name: &str| {
            let c = layer
                .channel_data
                .list
                .iter()
                .find(|c| c.name.to_string() == name)
                .unwrap();
            match &c.sample_data {
                FlatSamples::F32(v) => v.clone(),
                _ => panic!("{name} is not f32"),
            }
        };
        assert_eq!([channel("R")[7], channel("G")[7], channel("B")[7]], [7.0, 0.5, 1e-3]);
        let names: Vec<String> = layer.channel_data.list.iter().map(|c| c.name.to_string()).collect();
        for name in [
            "A",
            "DiffCol.R",
            "Normal.Z",
            "Depth.Z",
            "PhotonDensity.X",
            "PhotonRadius.X",
        ] {
            assert!(names.contains(&name.to_string()), "{name} not in {names:?}");
        }
        // Pixel 7 saw a surface at 2.5 m; the others saw the background.
        assert_eq!((channel("A")[7], channel("Depth.Z")[7]), (1.0, 2.5));
        assert_eq!((channel("A")[0], channel("Depth.Z")[0]), (0.0, BACKGROUND_DEPTH));
        // No temporary file left behind.
        assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 1);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn non_finite_values_are_written_as_zero() {
        let mut film = Film::new(3, 1);
        film.color[0] = Rgb::new(f32::NAN, 1.0, 2.0);
        film.color[1] = Rgb::new(f32::INFINITY, f32::NEG_INFINITY, 0.5);
        film.color[2] = Rgb::new(1.0, 1.0, 1.0);
        assert_eq!(film.nonfinite(), 2);
        // The stats' mean stays a number (non-finite values count as 0, as written).
        assert_eq!(film.mean(), [1.0 / 3.0, 2.0 / 3.0, 3.5 / 3.0]);
        let p = std::env::temp_dir().join(format!("pg-nonfinite-{}.exr", std::process::id()));
        write_exr(&p, &film, AovSelection::all()).unwrap();
        let image = exr::prelude::read_all_flat_layers_from_file(&p).unwrap();
        std::fs::remove_file(&p).unwrap();
        for c in &image.layer_data[0].channel_data.list {
            if let FlatSamples::F32(v) = &c.sample_data {
                assert!(v.iter().all(|x| x.is_finite()), "{}: {v:?}", c.name);
            }
        }
    }

    #[test]
    fn temporary_names_are_recognised_only_in_our_pattern() {
        assert_eq!(
            temp_writer(".a.exr.12-0123abcd.0123456789abcdef.tmp", "a.exr"),
            Some(Some((12, "0123abcd".to_string())))
        );
        assert_eq!(temp_writer(".a.exr.12.tmp", "a.exr"), Some(None));
        for other in [
            ".a.exr.tmp",
            ".b.exr.12.tmp",
            "a.exr.12.tmp",
            ".a.exr.12-0123abcd.xyz.tmp",
            ".a.exr.x12.tmp",
        ] {
            assert_eq!(temp_writer(other, "a.exr"), None, "{other}");
        }
    }

    #[test]
    fn stale_temporary_files_of_dead_writers_are_removed() {
        let dir = std::env::temp_dir().join(format!("pg-stale-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let out = dir.join("a.exr");
        // Above Linux's largest pid (2^22): no such process.
        let dead = dir.join(format!(".a.exr.4194999-{}.0123456789abcdef.tmp", host_tag()));
        let mine = dir.join(format!(
            ".a.exr.{}-{}.0123456789abcdef.tmp",
            std::process::id(),
            host_tag()
        ));
        let other_host = dir.join(".a.exr.4194999-00000000.0123456789abcdef.tmp");
        for p in [&dead, &mine, &other_host] {
            std::fs::write(p, b"x").unwrap();
        }
        if host_tag() != "00000000" {
            assert_eq!(clean_stale_temps(&out), 1);
            assert!(!dead.exists() && mine.exists() && other_host.exists());
        }
        // The write itself leaves nothing but the output (and the files it must not touch).
        write_atomic(&out, b"new").unwrap();
        assert_eq!(std::fs::read(&out).unwrap(), b"new");
        let left = std::fs::read_dir(&dir).unwrap().count();
        assert_eq!(left, 3);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn plan_refuses_inputs_and_duplicates_by_where_they_lead() {
        let dir = std::env::temp_dir().join(format!("pg-plan-{}", std::process::id()));
        std::fs::create_dir_all(dir.join("sub")).unwrap();
        let scene = dir.join("s.glb");
        std::fs::write(&scene, b"glb").unwrap();
        let hard = dir.join("hard.glb");
        std::fs::hard_link(&scene, &hard).unwrap();
        let mut plan = OutputPlan::new();
        plan.input("the scene", &scene);
        let msg = |r: Result<(), OutputError>| r.unwrap_err().to_string();
        assert!(msg(plan.output("--output", &hard)).contains("is the scene"));
        assert!(msg(plan.output("--output", &dir.join("sub/../s.glb"))).contains("is the scene"));
        plan.output("--output", &dir.join("a.exr")).unwrap();
        assert!(msg(plan.output("--png", &dir.join("sub/../a.exr"))).contains("same file as --output"));
        plan.output("--png", &dir.join("none/x.png")).unwrap();
        assert!(msg(plan.output("--png", &dir.join("sub"))).contains("a folder"));
        plan.output("--png", &dir.join("sub/a.exr")).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn unwritable_path_is_an_error() {
        let film = Film::new(2, 2);
        let e = write_exr(Path::new("/nonexistent-dir/x.exr"), &film, AovSelection::default()).unwrap_err();
        assert!(e.to_string().contains("/nonexistent-dir/x.exr"));
    }
}
