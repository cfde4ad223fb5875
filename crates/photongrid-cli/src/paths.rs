//! Output paths, checked before any work: the name's extension matches the format written,
//! the folder is created, and a file can be created in it (so `-o /proc/x.exr` fails at once,
//! not after the render).

use std::path::Path;

/// What is written to a path, for its extension check.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    /// OpenEXR (`.exr`).
    Exr,
    /// PNG (`.png`).
    Png,
    /// Anything (JSON reports, journals).
    Any,
}

impl Format {
    fn extension(self) -> Option<&'static str> {
        match self {
            Format::Exr => Some("exr"),
            Format::Png => Some("png"),
            Format::Any => None,
        }
    }
}

/// Refuse a name whose extension is not the format's: `x.png` for an EXR would be an EXR that
/// every viewer opens as a broken PNG. `option` names the flag or key in the message.
pub fn check_extension(path: &Path, format: Format, option: &str) -> Result<(), String> {
    let Some(want) = format.extension() else {
        return Ok(());
    };
    let ext = path.extension().map(|e| e.to_string_lossy().to_lowercase());
    if ext.as_deref() == Some(want) {
        return Ok(());
    }
    let hint = match format {
        Format::Exr => {
            " (float radiance and passes); for an sRGB preview add --png PREVIEW.png, which --output cannot replace"
        }
        _ => "",
    };
    let what = match format {
        Format::Exr => "an OpenEXR image",
        _ => "a PNG image",
    };
    Err(match ext {
        Some(e) => format!(
            "{}: {option} writes {what}, but the name ends in .{e}: use a name ending in .{want}{hint}",
            path.display()
        ),
        None => format!(
            "{}: {option} writes {what}: use a name ending in .{want}{hint}",
            path.display()
        ),
    })
}

/// Make sure `path` can be written: create its folder (and parents) and create, then remove, a
/// file beside it. Fails with the path and the reason.
pub fn prepare(path: &Path) -> Result<(), String> {
    if path.is_dir() {
        return Err(format!("{}: is a folder, not a file name", path.display()));
    }
    let name = path
        .file_name()
        .ok_or_else(|| format!("{}: not a file name", path.display()))?;
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    if !dir.is_dir() {
        std::fs::create_dir_all(dir)
            .map_err(|e| format!("{}: cannot create the folder {}: {e}", path.display(), dir.display()))?;
    }
    let probe = dir.join(format!(".{}.{}.probe", name.to_string_lossy(), std::process::id()));
    match std::fs::OpenOptions::new().write(true).create_new(true).open(&probe) {
        Ok(f) => {
            drop(f);
            let _ = std::fs::remove_file(&probe);
            Ok(())
        }
        Err(e) => Err(format!(
            "{}: cannot write in {}: {e}; choose another folder",
            path.display(),
            dir.display()
        )),
    }
}

/// [`check_extension`] then [`prepare`].
pub fn check_output(path: &Path, format: Format, option: &str) -> Result<(), String> {
    check_extension(path, format, option)?;
    prepare(path)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn extensions() {
        assert!(check_extension(Path::new("a/b.exr"), Format::Exr, "--output").is_ok());
        assert!(check_extension(Path::new("b.EXR"), Format::Exr, "--output").is_ok());
        let e = check_extension(Path::new("x.png"), Format::Exr, "--output").unwrap_err();
        assert!(e.contains("x.png") && e.contains("OpenEXR") && e.contains(".exr") && e.contains("--png"));
        assert!(check_extension(Path::new("x"), Format::Exr, "--output").is_err());
        assert!(check_extension(Path::new("p.exr"), Format::Png, "--png").is_err());
        assert!(check_extension(Path::new("r.txt"), Format::Any, "--stats").is_ok());
    }

    #[test]
    fn folders_are_created_and_unwritable_ones_refused() {
        let dir = std::env::temp_dir().join(format!("pg-paths-{}", std::process::id()));
        let out = dir.join("a/b/out.exr");
        prepare(&out).unwrap();
        assert!(out.parent().unwrap().is_dir());
        assert_eq!(
            std::fs::read_dir(out.parent().unwrap()).unwrap().count(),
            0,
            "probe left behind"
        );
        assert!(prepare(&dir.join("a")).unwrap_err().contains("is a folder"));
        std::fs::remove_dir_all(&dir).unwrap();
        let e = prepare(Path::new("/proc/x.exr")).unwrap_err();
        assert!(e.contains("/proc/x.exr") && e.contains("cannot write"), "{e}");
    }
}
