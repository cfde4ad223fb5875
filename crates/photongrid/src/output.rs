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
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), OutputError> {
    let io = |source| OutputError::Io {
        path: path.to_path_buf(),
        source,
    };
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let name = path
        .file_name()
        .ok_or_else(|| io(std::io::Error::new(std::io::ErrorKind::InvalidInput, "not a file name")))?;
    let tmp = dir.join(format!(".{}.{}.tmp", name.to_string_lossy(), std::process::id()));
    let result = (|| {
        use std::io::Write;
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result.map_err(io)
}

/// Encode a film as a single-part EXR with float32 channels: `R,G,B` radiance, `A` coverage
/// (1 where the pixel's first camera ray hit a surface, 0 for the background: the background is
/// transparent) and the AOV layers `aovs` selects.
pub fn encode_exr(film: &Film, aovs: AovSelection) -> std::result::Result<Vec<u8>, String> {
    let size = (film.width as usize, film.height as usize);
    let ch = |name: &str, f: &dyn Fn(usize) -> f32| {
        AnyChannel::new(name, FlatSamples::F32((0..film.color.len()).map(f).collect()))
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
    let ch = AnyChannel::new("Y", FlatSamples::F32(field.data.clone()));
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
    fn unwritable_path_is_an_error() {
        let film = Film::new(2, 2);
        let e = write_exr(Path::new("/nonexistent-dir/x.exr"), &film, AovSelection::default()).unwrap_err();
        assert!(e.to_string().contains("/nonexistent-dir/x.exr"));
    }
}
