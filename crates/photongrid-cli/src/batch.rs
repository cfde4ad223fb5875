//! Batch rendering: a `JOBS.toml` of `[[job]]` tables is parsed ([`parse_jobs`]), expanded into
//! units of one scene, one camera and one output ([`expand`]), and the units are rendered
//! ([`run`]) in parallel, each finished output checked by a sidecar so a rerun skips it.
//!
//! A job table holds `scene` (relative to the TOML file, or absolute), `output` (likewise; a
//! path or a pattern with `{scene}`, `{camera}` and `{job}`), optional `camera` (name, index,
//! a list of them, or `"all"`, the default), optional `aovs`, and any field of [`Settings`]
//! under its name (`photons`, `neighbours`, `spp`, ...). An optional `[defaults]` table is
//! applied under every job. Settings are read by [`Settings`]' own serde code, so a new
//! option needs no change here.
//!
//! Resume: after an EXR is written (atomically) a sidecar `<output>.done.json` records a key
//! (hash of the scene file's bytes, the camera, the resolution, the settings and the version)
//! and the EXR's length and hash. A unit is skipped only if its sidecar has the same key, the
//! EXR has the recorded length and hash, and it reads back at the right size.

use photongrid::memory::SceneFootprint;
use photongrid::output::{self, output_for, AovSelection};
use photongrid::pipeline::{self, CameraReport, RenderRequest};
use photongrid::progress::Progress;
use photongrid::scene::gltf::{load_with, LoadOptions};
use photongrid::scene::{Camera, Scene};
use photongrid::settings::Settings;
use serde::Serialize;
use serde_json::{json, Value};
use std::collections::{HashMap, HashSet, VecDeque};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::Instant;

/// Keys of a job table that are not render settings.
pub const JOB_KEYS: [&str; 4] = ["scene", "output", "camera", "aovs"];

/// One `[[job]]` table, resolved and checked.
#[derive(Clone, Debug)]
pub struct Job {
    /// Position in the file, from 0.
    pub index: usize,
    /// Scene path (joined to the TOML file's folder when relative).
    pub scene: PathBuf,
    /// Output path or pattern (joined likewise).
    pub output: String,
    /// Camera keys; empty means all cameras.
    pub cameras: Vec<String>,
    /// Render settings (defaults, then `[defaults]`, then the job's keys).
    pub settings: Settings,
    /// Add the AOV layers to the EXR.
    pub aovs: bool,
}

/// A job that could not be read.
#[derive(Clone, Debug)]
pub struct JobError {
    /// Position in the file, from 0.
    pub index: usize,
    /// The scene, when the job named one.
    pub scene: Option<PathBuf>,
    /// What is wrong, naming the job.
    pub message: String,
}

/// One scene, one camera, one output: what a farm task or a shard counts.
#[derive(Clone, Debug, Serialize)]
pub struct Unit {
    /// Position after expansion, from 0 (stable: job order, then camera order).
    pub index: usize,
    /// The job it came from.
    pub job: usize,
    /// Scene path.
    pub scene: PathBuf,
    /// Camera name (none when the job failed before its cameras were known).
    pub camera: Option<String>,
    /// glTF camera index.
    pub camera_index: Option<usize>,
    /// Output EXR.
    pub output: Option<PathBuf>,
    /// Resolution.
    pub width: Option<u32>,
    /// Resolution.
    pub height: Option<u32>,
    /// Why the unit cannot run (bad job, missing scene, unknown camera...).
    pub error: Option<String>,
    /// Settings (one copy per job, shared by its units).
    #[serde(skip)]
    pub settings: Arc<Settings>,
    /// AOV layers.
    #[serde(skip)]
    pub aovs: bool,
    /// What the output depends on besides the camera and the resolution (the version, the
    /// scene file's hash, the settings, the AOVs), as compact JSON: kept as text (a tenth of a
    /// parsed document's size) and shared by the units of every job that has the same.
    #[serde(skip)]
    pub job_key: Arc<str>,
}

impl Unit {
    /// Everything the output depends on: [`Unit::job_key`] with the camera and resolution.
    pub fn key_source(&self) -> Value {
        let mut v: Value = serde_json::from_str(&self.job_key).unwrap_or(Value::Null);
        if let Value::Object(m) = &mut v {
            m.insert("camera".into(), json!(self.camera));
            m.insert("camera_index".into(), json!(self.camera_index));
            m.insert("width".into(), json!(self.width));
            m.insert("height".into(), json!(self.height));
        }
        v
    }

    /// The resume key: a hash of everything the output depends on.
    pub fn key(&self) -> String {
        format!("{:016x}", fnv1a64(self.key_source().to_string().as_bytes()))
    }
}

/// What happened to a unit.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Status {
    /// Rendered and written.
    Done,
    /// A checked output was already there.
    Skipped,
    /// Not rendered; see the error.
    Failed,
}

/// One line of the report.
#[derive(Clone, Debug, Serialize)]
pub struct UnitReport {
    /// Unit index.
    pub index: usize,
    /// Job index.
    pub job: usize,
    /// Scene path.
    pub scene: PathBuf,
    /// Camera name.
    pub camera: Option<String>,
    /// Output EXR.
    pub output: Option<PathBuf>,
    /// done, skipped or failed.
    pub status: Status,
    /// Why it failed.
    pub error: Option<String>,
    /// Seconds spent on this unit (a shared photon map's time is split between its units).
    pub seconds: f64,
    /// Phase seconds (`seconds`, of the shared preparation and this camera), photon counts,
    /// resolution; for a skipped unit, `null`.
    pub stats: Option<Value>,
}

impl UnitReport {
    fn of(u: &Unit, status: Status, error: Option<String>, seconds: f64, stats: Option<Value>) -> Self {
        UnitReport {
            index: u.index,
            job: u.job,
            scene: u.scene.clone(),
            camera: u.camera.clone(),
            output: u.output.clone(),
            status,
            error,
            seconds,
            stats,
        }
    }
}

/// 64-bit FNV-1a: a small stable hash (not cryptographic) for resume checks.
pub fn fnv1a64(bytes: &[u8]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for &b in bytes {
        h ^= b as u64;
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    h
}

/// Length and [`fnv1a64`] of a regular file, read in blocks (never held whole).
fn fnv1a64_file(path: &Path) -> std::io::Result<(u64, u64)> {
    use std::io::Read;
    let mut f = open_regular(path)?;
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    let mut len = 0u64;
    let mut buf = vec![0u8; 1 << 16];
    loop {
        let n = f.read(&mut buf)?;
        if n == 0 {
            return Ok((len, h));
        }
        len += n as u64;
        for &b in &buf[..n] {
            h ^= b as u64;
            h = h.wrapping_mul(0x0000_0100_0000_01b3);
        }
    }
}

/// Open `path` for reading if it is a regular file (after links): a FIFO or device is never
/// opened (it could block or never end).
fn open_regular(path: &Path) -> std::io::Result<std::fs::File> {
    let meta = std::fs::metadata(path)?;
    if !meta.is_file() {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            "not a regular file",
        ));
    }
    std::fs::File::open(path)
}

/// The bytes of a regular file of at most `max` bytes.
fn read_regular(path: &Path, max: u64) -> std::io::Result<Vec<u8>> {
    use std::io::Read;
    let f = open_regular(path)?;
    let mut bytes = Vec::new();
    f.take(max + 1).read_to_end(&mut bytes)?;
    if bytes.len() as u64 > max {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            "larger than expected",
        ));
    }
    Ok(bytes)
}

/// `I/N` with 0 ≤ I < N.
pub fn parse_shard(s: &str) -> Result<(usize, usize), String> {
    let err = || format!("--shard {s}: expected I/N with 0 <= I < N, e.g. 0/4");
    let (i, n) = s.split_once('/').ok_or_else(err)?;
    let (i, n): (usize, usize) = (
        i.trim().parse().map_err(|_| err())?,
        n.trim().parse().map_err(|_| err())?,
    );
    if n == 0 || i >= n {
        return Err(err());
    }
    Ok((i, n))
}

fn normalize(t: &toml::Table) -> toml::Table {
    t.iter().map(|(k, v)| (k.replace('-', "_"), v.clone())).collect()
}

/// Read the settings part of a (merged) table with [`Settings`]' serde code.
fn settings_of(t: &toml::Table) -> Result<Settings, String> {
    let rest: toml::Table = t
        .iter()
        .filter(|(k, _)| !JOB_KEYS.contains(&k.as_str()))
        .map(|(k, v)| (k.clone(), v.clone()))
        .collect();
    let s: Settings = toml::Value::Table(rest)
        .try_into()
        .map_err(|e: toml::de::Error| e.to_string().trim().replace("unknown field", "unknown key"))?;
    Ok(s)
}

/// Parse a JOBS.toml. The outer error is for the whole file (bad TOML, bad `[defaults]`); each
/// job is read on its own, so one bad job does not stop the others.
pub fn parse_jobs(text: &str, base: &Path) -> Result<Vec<Result<Job, JobError>>, String> {
    let doc: toml::Table = text.parse().map_err(|e: toml::de::Error| e.to_string())?;
    for k in doc.keys() {
        if k != "job" && k != "defaults" {
            return Err(format!(
                "unknown top-level key `{k}`: a jobs file holds [[job]] tables and an optional [defaults] table"
            ));
        }
    }
    let defaults = match doc.get("defaults") {
        None => toml::Table::new(),
        Some(toml::Value::Table(t)) => normalize(t),
        Some(_) => return Err("`defaults` must be a table: write [defaults]".into()),
    };
    settings_of(&defaults).map_err(|e| format!("[defaults]: {e}"))?;
    let jobs = match doc.get("job") {
        None => return Err("no jobs: add [[job]] tables with scene = \"...\" and output = \"...\"".into()),
        Some(toml::Value::Array(a)) => a,
        Some(_) => return Err("`job` must be an array of tables: write [[job]], not [job]".into()),
    };
    Ok(jobs
        .iter()
        .enumerate()
        .map(|(index, v)| {
            let mut merged = defaults.clone();
            match v {
                toml::Value::Table(t) => merged.extend(normalize(t)),
                _ => {
                    return Err(JobError {
                        index,
                        scene: None,
                        message: format!("job {index}: not a table"),
                    })
                }
            }
            job_from_table(index, merged, base)
        })
        .collect())
}

fn job_from_table(index: usize, t: toml::Table, base: &Path) -> Result<Job, JobError> {
    let scene = match t.get("scene") {
        Some(toml::Value::String(s)) => Some(base.join(s)),
        _ => None,
    };
    let fail = |message: String| {
        let at = scene
            .as_ref()
            .map(|s| format!(" ({})", s.display()))
            .unwrap_or_default();
        JobError {
            index,
            scene: scene.clone(),
            message: format!("job {index}{at}: {message}"),
        }
    };
    let string = |key: &str| -> Result<Option<String>, JobError> {
        match t.get(key) {
            None => Ok(None),
            Some(toml::Value::String(s)) => Ok(Some(s.clone())),
            Some(v) => Err(fail(format!("`{key}` must be a string, not {}", v.type_str()))),
        }
    };
    let scene_s = string("scene")?.ok_or_else(|| fail("missing `scene` (the .glb/.gltf to render)".into()))?;
    let output = string("output")?
        .ok_or_else(|| fail("missing `output` (an EXR path, or a pattern with {scene} and {camera})".into()))?;
    crate::paths::check_extension(Path::new(&output), crate::paths::Format::Exr, "`output`").map_err(fail)?;
    let key = |v: &toml::Value| match v {
        toml::Value::String(s) => Ok(s.clone()),
        toml::Value::Integer(i) => Ok(i.to_string()),
        v => Err(fail(format!(
            "`camera` must be a name, an index or \"all\", not {}",
            v.type_str()
        ))),
    };
    let cameras = match t.get("camera") {
        None => vec![],
        Some(toml::Value::Array(a)) => a.iter().map(key).collect::<Result<Vec<_>, _>>()?,
        Some(v) => vec![key(v)?],
    };
    let cameras = if cameras.iter().any(|c| c == "all") {
        vec![]
    } else {
        cameras
    };
    let aovs = match t.get("aovs") {
        None => false,
        Some(toml::Value::Boolean(b)) => *b,
        Some(v) => return Err(fail(format!("`aovs` must be true or false, not {}", v.type_str()))),
    };
    let settings = settings_of(&t).map_err(fail)?;
    settings.validate().map_err(|e| fail(e.to_string()))?;
    Ok(Job {
        index,
        scene: tidy(&base.join(scene_s)),
        output: tidy(&base.join(output)).to_string_lossy().into_owned(),
        cameras,
        settings,
        aovs,
    })
}

/// `a/./b/../c` → `a/c`, without touching the file system (`..` at the start is kept).
fn tidy(p: &Path) -> PathBuf {
    use std::path::Component;
    let mut out: Vec<Component> = Vec::new();
    for c in p.components() {
        match c {
            Component::CurDir => {}
            Component::ParentDir if matches!(out.last(), Some(Component::Normal(_))) => {
                out.pop();
            }
            c => out.push(c),
        }
    }
    if out.is_empty() {
        return PathBuf::from(".");
    }
    out.iter().collect()
}

/// `{scene}`: the scene file's stem, made a safe file-name part ([`safe_component`]).
fn scene_stem(p: &Path) -> String {
    safe_component(
        &p.file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| "scene".into()),
    )
}

/// `s` made safe to substitute into an output path: separators and control characters become
/// `_`, and a name of dots only (`.`, `..` — a scene file named `...glb` has the stem `..`)
/// has its dots made `_`, so no substitution can leave the folder the pattern names.
pub fn safe_component(s: &str) -> String {
    let t: String = s
        .chars()
        .map(|c| {
            if c == '/' || c == '\\' || c.is_control() {
                '_'
            } else {
                c
            }
        })
        .collect();
    if t.is_empty() {
        "_".into()
    } else if t.chars().all(|c| c == '.') {
        t.replace('.', "_")
    } else {
        t
    }
}

/// What expansion keeps of a scene: a scene holding only its cameras (the triangles, materials
/// and textures are dropped as soon as the cameras are known), what the memory estimate needs
/// of the rest, and the file's hash.
struct Summary {
    cameras: Scene,
    footprint: SceneFootprint,
    file: Value,
}

/// Where an output or sidecar is, and whose it is.
struct Claim {
    unit: usize,
    job: usize,
    what: &'static str,
}

/// Paths as `output::resolved(path, false)` gives them (links and `..` resolved, the last
/// component kept as it is), each folder resolved once: resolving walks every component with
/// system calls, and the thousands of outputs of a jobs file share a few folders.
#[derive(Default)]
struct Resolver {
    dirs: HashMap<PathBuf, PathBuf>,
}

impl Resolver {
    fn resolved(&mut self, path: &Path) -> PathBuf {
        use std::path::Component;
        match (path.parent(), path.components().next_back()) {
            (Some(dir), Some(Component::Normal(name))) => self
                .dirs
                .entry(dir.to_path_buf())
                .or_insert_with(|| output::resolved(dir, true))
                .join(name),
            _ => output::resolved(path, false),
        }
    }
}

/// The state of [`expand`]: the scenes read so far, the units, and the paths they claim.
#[derive(Default)]
struct Expansion {
    scenes: HashMap<PathBuf, Result<Summary, String>>,
    units: Vec<Unit>,
    claims: HashMap<PathBuf, Claim>,
    resolver: Resolver,
    /// The distinct [`Unit::job_key`]s.
    keys: HashSet<Arc<str>>,
}

/// A unit of a job before it is numbered: its camera, its output and where the output and its
/// sidecar lead.
struct Planned<'a> {
    camera: &'a Camera,
    output: PathBuf,
    at: PathBuf,
    side: PathBuf,
}

/// What the units of one job share: the settings and the job's part of the resume key.
struct Shared {
    settings: Arc<Settings>,
    key: Arc<str>,
}

/// Expand jobs into units in a stable order: job order, then camera order. A job that cannot
/// be expanded (bad table, missing scene, unknown camera, clashing output) becomes one failed
/// unit carrying its error, so it is reported and counted in exactly one shard. A unit whose
/// render cannot fit the memory limit keeps its camera and output but fails with the estimate,
/// so it is refused before anything renders, in every run.
///
/// Scenes are loaded one at a time and dropped once their cameras are known, so memory stays
/// that of one scene however many the file names. Outputs and their sidecars are compared by
/// where they lead (relative or absolute spelling, links and `..` resolved), so two spellings
/// of one file clash; an output that is one of the scenes fails its unit. Every check is a
/// look-up in a map, so expansion takes time in proportion to the units.
pub fn expand(jobs: &[Result<Job, JobError>]) -> Vec<Unit> {
    let mut x = Expansion::default();
    for job in jobs {
        match job {
            Ok(j) => x.job(j),
            Err(e) => {
                let index = x.units.len();
                x.units
                    .push(failed_unit(index, e.index, e.scene.clone(), e.message.clone()));
            }
        }
    }
    let scene_paths: Vec<(String, PathBuf)> = jobs
        .iter()
        .filter_map(|j| j.as_ref().ok())
        .map(|j| (format!("the scene of job {}", j.index), j.scene.clone()))
        .collect();
    protect_with(&mut x.units, &scene_paths, &mut x.resolver);
    x.units
}

impl Expansion {
    /// Add `job`'s units, or one failed unit saying why it has none.
    fn job(&mut self, job: &Job) {
        if let Err(m) = self.try_job(job) {
            let index = self.units.len();
            let message = format!("job {} ({}): {m}", job.index, job.scene.display());
            self.units
                .push(failed_unit(index, job.index, Some(job.scene.clone()), message));
        }
    }

    fn try_job(&mut self, job: &Job) -> Result<(), String> {
        let Expansion {
            scenes,
            units,
            claims,
            resolver,
            keys,
        } = self;
        let summary = scenes
            .entry(job.scene.clone())
            .or_insert_with(|| load_for_expansion(&job.scene, job.settings.memory_limit))
            .as_ref()
            .map_err(|e| e.clone())?;
        let cameras = pipeline::select_cameras(&summary.cameras, &job.cameras).map_err(|e| e.to_string())?;
        let planned = plan_outputs(job, &cameras, claims, resolver)?;
        // The memory limit changes nothing in the image: it is not part of the key.
        let key_settings = Settings {
            memory_limit: None,
            ..job.settings.clone()
        };
        let key = json!({
            "version": env!("CARGO_PKG_VERSION"),
            "scene_file": summary.file,
            "settings": key_settings,
            "aovs": job.aovs,
        })
        .to_string();
        let key = match keys.get(key.as_str()) {
            Some(k) => k.clone(),
            None => {
                let k: Arc<str> = key.into();
                keys.insert(k.clone());
                k
            }
        };
        let shared = Shared {
            settings: Arc::new(job.settings.clone()),
            key,
        };
        for p in planned {
            let index = units.len();
            for (path, what) in [(&p.at, "output"), (&p.side, "sidecar")] {
                let claim = Claim {
                    unit: index,
                    job: job.index,
                    what,
                };
                claims.insert(path.clone(), claim);
            }
            units.push(unit_of(index, job, p, &shared, &summary.footprint));
        }
        Ok(())
    }
}

/// Each camera's output under `job`'s pattern; an error when two of the cameras would write
/// one file, or one would write where an earlier unit's output or sidecar is.
fn plan_outputs<'a>(
    job: &Job,
    cameras: &[&'a Camera],
    claims: &HashMap<PathBuf, Claim>,
    resolver: &mut Resolver,
) -> Result<Vec<Planned<'a>>, String> {
    let several = cameras.len() > 1;
    let pattern = job
        .output
        .replace("{scene}", &scene_stem(&job.scene))
        .replace("{job}", &job.index.to_string());
    let mut planned: Vec<Planned> = Vec::with_capacity(cameras.len());
    let mut mine: HashMap<PathBuf, usize> = HashMap::with_capacity(cameras.len());
    for &c in cameras {
        let output = output_for(Path::new(&pattern), &c.name, several);
        let at = resolver.resolved(&output);
        let side = resolver.resolved(&sidecar_path(&output));
        if let Some(&i) = mine.get(&at) {
            let other = planned[i].camera;
            return Err(if other.index == c.index && other.name == c.name {
                format!("camera {} '{}' is listed twice in `camera`", c.index, c.name)
            } else {
                format!(
                    "cameras {} '{}' and {} '{}' both write {} (their names make the same file name); put {{camera}} in `output` or select one of them",
                    other.index,
                    other.name,
                    c.index,
                    c.name,
                    output.display()
                )
            });
        }
        if let Some(Claim { unit, job, what }) = claims.get(&at).or_else(|| claims.get(&side)) {
            return Err(format!(
                "output {} is also the {what} of unit {unit} (job {job}); use {{camera}} or {{scene}} in `output`",
                output.display()
            ));
        }
        mine.insert(at.clone(), planned.len());
        planned.push(Planned {
            camera: c,
            output,
            at,
            side,
        });
    }
    Ok(planned)
}

/// The unit `index` of `job`; failed with the estimate and what to change when its render
/// cannot fit the memory limit.
fn unit_of(index: usize, job: &Job, p: Planned, shared: &Shared, footprint: &SceneFootprint) -> Unit {
    let c = p.camera;
    let (w, h) = pipeline::resolution(c, &job.settings);
    let error = photongrid::memory::check_footprint(footprint, &[c], &job.settings)
        .err()
        .map(|e| {
            format!(
                "job {} ({}), camera {} '{}': refused before rendering: {e} (in a jobs file, options are keys of the job or of [defaults], without `--`: `width = 640`, `spp = 4`, `memory_limit = \"8G\"`)",
                job.index,
                job.scene.display(),
                c.index,
                c.name
            )
        });
    Unit {
        index,
        job: job.index,
        scene: job.scene.clone(),
        camera: Some(c.name.clone()),
        camera_index: Some(c.index),
        output: Some(p.output),
        width: Some(w),
        height: Some(h),
        error,
        settings: shared.settings.clone(),
        aovs: job.aovs,
        job_key: shared.key.clone(),
    }
}

/// Fail every unit whose output or sidecar would replace one of `inputs` (`(what, path)`: the
/// scenes, the jobs file, the report, the journal), however the paths are spelt.
pub fn protect(units: &mut [Unit], inputs: &[(String, PathBuf)]) {
    protect_with(units, inputs, &mut Resolver::default())
}

fn protect_with(units: &mut [Unit], inputs: &[(String, PathBuf)], resolver: &mut Resolver) {
    let mut by: HashMap<PathBuf, (&str, &Path)> = HashMap::new();
    let mut ids: HashMap<(u64, u64), (&str, &Path)> = HashMap::new();
    let mut seen: HashSet<&Path> = HashSet::new();
    // Many jobs name one scene: each path is resolved once.
    for (what, path) in inputs.iter().filter(|(_, p)| seen.insert(p.as_path())) {
        for follow in [false, true] {
            by.entry(output::resolved(path, follow))
                .or_insert((what.as_str(), path.as_path()));
        }
        if let Some(id) = file_id(path) {
            ids.entry(id).or_insert((what.as_str(), path.as_path()));
        }
    }
    for u in units.iter_mut().filter(|u| u.error.is_none()) {
        let Some(out) = u.output.clone() else { continue };
        for (path, what) in [(out.clone(), "output"), (sidecar_path(&out), "sidecar")] {
            let hit = by
                .get(&resolver.resolved(&path))
                .or_else(|| file_id(&path).and_then(|id| ids.get(&id)));
            if let Some((input, given)) = hit {
                u.error = Some(format!(
                    "job {} ({}): the {what} {} is {input} ({}): writing it would replace an input; change `output`",
                    u.job,
                    u.scene.display(),
                    path.display(),
                    given.display()
                ));
                break;
            }
        }
    }
}

/// Device and inode of the file `path` leads to, if it exists.
fn file_id(path: &Path) -> Option<(u64, u64)> {
    use std::os::unix::fs::MetadataExt;
    std::fs::metadata(path).ok().map(|m| (m.dev(), m.ino()))
}

fn failed_unit(index: usize, job: usize, scene: Option<PathBuf>, error: String) -> Unit {
    Unit {
        index,
        job,
        scene: scene.unwrap_or_default(),
        camera: None,
        camera_index: None,
        output: None,
        width: None,
        height: None,
        error: Some(error),
        settings: Arc::new(Settings::default()),
        aovs: false,
        job_key: "null".into(),
    }
}

fn load_for_expansion(path: &Path, memory_limit: Option<u64>) -> Result<Summary, String> {
    if !path.exists() {
        return Err(format!("scene file {} does not exist", path.display()));
    }
    // The loader first: it refuses what is not a regular file, or too large, before reading.
    let options = LoadOptions {
        memory_budget_bytes: memory_limit,
        ..LoadOptions::default()
    };
    let scene = load_with(path, &options).map_err(|e| e.to_string())?;
    let (len, hash) = fnv1a64_file(path).map_err(|e| format!("{}: cannot read: {e}", path.display()))?;
    let file = json!({"bytes": len, "fnv64": format!("{hash:016x}")});
    let footprint = SceneFootprint::of(&scene);
    // Keep the cameras only: the rest of the scene is dropped here.
    let cameras = Scene {
        source: scene.source,
        cameras: scene.cameras,
        triangles: Vec::new(),
        materials: Vec::new(),
        textures: Vec::new(),
        tangents: Vec::new(),
        glossy_roughness: scene.glossy_roughness,
        lights: Vec::new(),
        bounds: photongrid::scene::Bounds::empty(),
        report: Default::default(),
    };
    Ok(Summary {
        cameras,
        footprint,
        file,
    })
}

/// Keep the units of shard `i` of `n`: those whose index % n == i.
pub fn shard(units: Vec<Unit>, i: usize, n: usize) -> Vec<Unit> {
    units.into_iter().filter(|u| u.index % n == i).collect()
}

/// The sidecar that marks `output` as finished.
pub fn sidecar_path(output: &Path) -> PathBuf {
    let mut s = output.as_os_str().to_owned();
    s.push(".done.json");
    PathBuf::from(s)
}

/// Why `u`'s output cannot be trusted (so it must be rendered), or `Ok` if it is finished.
pub fn check_done(u: &Unit) -> Result<(), String> {
    let out = u.output.as_deref().ok_or("no output")?;
    let side = sidecar_path(out);
    let text = read_regular(&side, 64 << 20).map_err(|_| "no sidecar".to_string())?;
    let v: Value = serde_json::from_slice(&text).map_err(|e| format!("{}: unreadable: {e}", side.display()))?;
    if v["key"].as_str() != Some(u.key().as_str()) {
        return Err("scene, camera or settings changed".into());
    }
    let expected = v["exr"]["bytes"].as_u64().unwrap_or(0);
    let bytes = read_regular(out, expected).map_err(|e| format!("{}: {e}", out.display()))?;
    if v["exr"]["bytes"].as_u64() != Some(bytes.len() as u64)
        || v["exr"]["fnv64"].as_str() != Some(format!("{:016x}", fnv1a64(&bytes)).as_str())
    {
        return Err(format!(
            "{} differs from the one recorded in its sidecar",
            out.display()
        ));
    }
    let img = crate::metrics::read_exr_rgb(out).map_err(|e| e.to_string())?;
    if (Some(img.width as u32), Some(img.height as u32)) != (u.width, u.height) {
        return Err(format!("{} is {}×{}", out.display(), img.width, img.height));
    }
    Ok(())
}

/// How to run.
#[derive(Clone, Debug)]
pub struct RunOptions {
    /// Groups rendered at once.
    pub jobs: usize,
    /// Threads in all (each of the `jobs` pools gets `threads / jobs`).
    pub threads: usize,
    /// Render even when a checked output exists.
    pub force: bool,
    /// Append one JSON line per unit event (start, done, skipped, failed) here.
    pub journal: Option<PathBuf>,
    /// Print one line per finished unit on stderr.
    pub verbose: bool,
}

impl Default for RunOptions {
    fn default() -> Self {
        RunOptions {
            jobs: 1,
            threads: std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1),
            force: false,
            journal: None,
            verbose: false,
        }
    }
}

impl RunOptions {
    /// Concurrent jobs and threads per job, never more threads than `threads` in all.
    pub fn layout(&self) -> (usize, usize) {
        let threads = self.threads.max(1);
        let jobs = self.jobs.clamp(1, threads);
        (jobs, threads / jobs)
    }
}

fn journal(opts: &RunOptions, event: &str, u: &Unit, extra: Value) {
    let Some(path) = &opts.journal else { return };
    let mut v = json!({
        "event": event, "unit": u.index, "job": u.job, "output": u.output,
        "pid": std::process::id(), "ppid": std::os::unix::process::parent_id(),
        "time": std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_secs_f64()).unwrap_or(0.0),
    });
    if let (Value::Object(m), Value::Object(e)) = (&mut v, extra) {
        m.extend(e);
    }
    // One write of one line in append mode: lines from concurrent processes do not interleave.
    let line = format!("{v}\n");
    let r = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(path)
        .and_then(|mut f| f.write_all(line.as_bytes()));
    if let Err(e) = r {
        tracing::warn!("{}: cannot append to the journal: {e}", path.display());
    }
}

/// Render `units` (already sharded/filtered); returns one report per unit, in unit order.
/// Units with the same scene and settings share one photon map.
pub fn run(units: &[Unit], opts: &RunOptions) -> Vec<UnitReport> {
    let (jobs, threads) = opts.layout();
    let mut reports: Vec<UnitReport> = Vec::new();
    let mut groups: Vec<Vec<&Unit>> = Vec::new();
    let mut by_key: HashMap<(PathBuf, String), usize> = HashMap::new();
    for u in units {
        if let Some(e) = &u.error {
            journal(opts, "failed", u, json!({"error": e}));
            reports.push(UnitReport::of(u, Status::Failed, Some(e.clone()), 0.0, None));
            continue;
        }
        let key = (u.scene.clone(), serde_json::to_string(&*u.settings).unwrap_or_default());
        let g = *by_key.entry(key).or_insert_with(|| {
            groups.push(Vec::new());
            groups.len() - 1
        });
        groups[g].push(u);
    }
    let queue = Mutex::new(groups.into_iter().collect::<VecDeque<_>>());
    let results = Mutex::new(reports);
    std::thread::scope(|s| {
        for _ in 0..jobs {
            s.spawn(|| {
                let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build();
                loop {
                    let Some(group) = queue.lock().unwrap_or_else(|e| e.into_inner()).pop_front() else {
                        break;
                    };
                    let r = match &pool {
                        Ok(pool) => run_group(&group, pool, opts),
                        Err(e) => group
                            .iter()
                            .map(|u| UnitReport::of(u, Status::Failed, Some(format!("thread pool: {e}")), 0.0, None))
                            .collect(),
                    };
                    results.lock().unwrap_or_else(|e| e.into_inner()).extend(r);
                }
            });
        }
    });
    let mut reports = results.into_inner().unwrap_or_else(|e| e.into_inner());
    reports.sort_by_key(|r| r.index);
    reports
}

fn run_group(group: &[&Unit], pool: &rayon::ThreadPool, opts: &RunOptions) -> Vec<UnitReport> {
    let mut reports = Vec::new();
    let mut todo = Vec::new();
    for &u in group {
        match (opts.force, check_done(u)) {
            (false, Ok(())) => {
                journal(opts, "skipped", u, json!({}));
                if opts.verbose {
                    eprintln!("skipped unit {}: {} is done", u.index, show(&u.output));
                }
                reports.push(UnitReport::of(u, Status::Skipped, None, 0.0, None));
            }
            (_, r) => {
                if let (Err(why), true) = (r, u.output.as_ref().is_some_and(|o| o.exists())) {
                    tracing::warn!("unit {}: rendering again: {why}", u.index);
                }
                todo.push(u);
            }
        }
    }
    if todo.is_empty() {
        return reports;
    }
    for u in &todo {
        journal(opts, "start", u, json!({}));
    }
    let start = Instant::now();
    let rendered = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        pool.install(|| render_group(&todo, opts))
    }));
    let rendered = match rendered {
        Ok(Ok(r)) => r,
        Ok(Err(e)) => fail_all(&todo, e, start),
        Err(p) => {
            let m = p
                .downcast_ref::<String>()
                .cloned()
                .or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()))
                .unwrap_or_else(|| "unknown panic".into());
            fail_all(&todo, format!("internal error (panic): {m}"), start)
        }
    };
    let by_index: HashMap<usize, &Unit> = todo.iter().map(|u| (u.index, *u)).collect();
    for r in &rendered {
        let u = by_index[&r.index];
        match r.status {
            Status::Done => journal(opts, "done", u, json!({"seconds": r.seconds})),
            _ => journal(opts, "failed", u, json!({"error": r.error})),
        }
        if opts.verbose {
            match r.status {
                Status::Done => eprintln!("done unit {}: {} ({:.2} s)", u.index, show(&u.output), r.seconds),
                _ => eprintln!("FAILED unit {}: {}", u.index, r.error.as_deref().unwrap_or("")),
            }
        }
    }
    reports.extend(rendered);
    reports
}

fn show(p: &Option<PathBuf>) -> String {
    p.as_ref().map(|p| p.display().to_string()).unwrap_or_default()
}

fn fail_all(units: &[&Unit], e: String, start: Instant) -> Vec<UnitReport> {
    let s = start.elapsed().as_secs_f64() / units.len() as f64;
    units
        .iter()
        .map(|u| UnitReport::of(u, Status::Failed, Some(e.clone()), s, None))
        .collect()
}

/// Load once and run the passes for every camera of the group together (each pass's photons
/// serve all of them), in as few renders as the memory limit allows: when the cameras' images
/// do not fit together ([`photongrid::memory`]), they are rendered in consecutive chunks that
/// do, each with its own photons. An error loading the scene fails the whole group; an error
/// rendering a chunk fails that chunk's units; an error writing one output fails that unit only.
fn render_group(units: &[&Unit], _opts: &RunOptions) -> Result<Vec<UnitReport>, String> {
    let first = units[0];
    let settings = &first.settings;
    let t = Instant::now();
    let options = LoadOptions {
        memory_budget_bytes: settings.memory_limit,
        ..LoadOptions::default()
    };
    let scene = load_with(&first.scene, &options).map_err(|e| e.to_string())?;
    let load_seconds = t.elapsed().as_secs_f64();
    // Units whose camera is missing fail alone; the others share every pass's photons.
    let mut reports = Vec::new();
    let by_index: HashMap<usize, &Camera> = scene.cameras.iter().map(|c| (c.index, c)).collect();
    let mut ok: Vec<(&Unit, &Camera)> = Vec::new();
    for &u in units {
        let camera = match (u.camera_index.and_then(|i| by_index.get(&i)), u.camera.as_deref()) {
            (Some(c), Some(name)) if c.name == name => Ok(*c),
            (_, Some(name)) => scene.camera(name),
            (_, None) => Err("no camera".to_string()),
        };
        match camera {
            Ok(c) => ok.push((u, c)),
            Err(e) => reports.push(UnitReport::of(u, Status::Failed, Some(e), 0.0, None)),
        }
    }
    let mut rest = &ok[..];
    while !rest.is_empty() {
        let cameras: Vec<&Camera> = rest.iter().map(|(_, c)| *c).collect();
        let n = photongrid::memory::cameras_that_fit(&scene, &cameras, settings).clamp(1, rest.len());
        if n < rest.len() && rest.len() == ok.len() {
            tracing::info!(
                "{}: {} cameras do not fit in memory together; rendering them {n} at a time",
                first.scene.display(),
                ok.len()
            );
        }
        let (chunk, more) = rest.split_at(n);
        let tc = Instant::now();
        match render_chunk(&scene, chunk, settings, load_seconds) {
            Ok(r) => reports.extend(r),
            Err(e) => reports.extend(fail_all(&chunk.iter().map(|(u, _)| *u).collect::<Vec<_>>(), e, tc)),
        }
        rest = more;
    }
    Ok(reports)
}

/// Render `chunk`'s cameras together and write each unit's EXR and sidecar.
fn render_chunk(
    scene: &Scene,
    chunk: &[(&Unit, &Camera)],
    settings: &Settings,
    load_seconds: f64,
) -> Result<Vec<UnitReport>, String> {
    let progress = Progress::quiet();
    let t = Instant::now();
    let cameras: Vec<&Camera> = chunk.iter().map(|(_, c)| *c).collect();
    let request = RenderRequest {
        scene,
        cameras: &cameras,
        settings,
        start: t,
    };
    let rendered = pipeline::render(&request, &progress, None).map_err(|e| e.to_string())?;
    // Time before the writes (photons, all passes) is split between the units.
    let shared = t.elapsed().as_secs_f64();
    let mut reports = Vec::new();
    for (((u, _), film), camera) in chunk.iter().zip(&rendered.films).zip(&rendered.report.cameras) {
        let tw = Instant::now();
        let result_unit = (|| -> Result<Value, String> {
            let out = u.output.as_deref().ok_or("no output")?;
            if let Some(dir) = out.parent().filter(|d| !d.as_os_str().is_empty()) {
                std::fs::create_dir_all(dir)
                    .map_err(|e| format!("{}: cannot create the folder: {e}", dir.display()))?;
            }
            let aovs = if u.aovs {
                AovSelection::all()
            } else {
                AovSelection::default()
            };
            // Refuse a folder, device or FIFO at the output (or its sidecar) before encoding.
            output::check_output_kind(out).map_err(|e| e.to_string())?;
            output::check_output_kind(&sidecar_path(out)).map_err(|e| e.to_string())?;
            let bytes = output::encode_exr(film, aovs).map_err(|m| format!("{}: EXR error: {m}", out.display()))?;
            output::write_atomic(out, &bytes).map_err(|e| e.to_string())?;
            if camera.nonfinite_pixels > 0 {
                tracing::warn!(
                    "{}: {} pixels were not finite (NaN or infinite) and were written as 0",
                    out.display(),
                    camera.nonfinite_pixels
                );
            }
            // The unit's report: the render's, with this camera only and its own write time.
            let mut report = rendered.report.clone();
            report.seconds.load = load_seconds;
            report.seconds.write = tw.elapsed().as_secs_f64();
            report.cameras = vec![CameraReport {
                output: Some(out.to_path_buf()),
                ..camera.clone()
            }];
            let mut stats = serde_json::to_value(&report).map_err(|e| e.to_string())?;
            stats["photon_map_shared_by"] = json!(chunk.len());
            let side = json!({
                "key": u.key(),
                "key_source": u.key_source(),
                "exr": {"bytes": bytes.len(), "fnv64": format!("{:016x}", fnv1a64(&bytes))},
                "unit": u.index, "job": u.job, "scene": u.scene, "camera": u.camera,
                "written_at": std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_secs()).unwrap_or(0),
                "stats": stats,
            });
            let side_bytes = serde_json::to_vec_pretty(&side).map_err(|e| e.to_string())?;
            output::write_atomic(&sidecar_path(out), &side_bytes).map_err(|e| e.to_string())?;
            Ok(stats)
        })();
        let own = tw.elapsed().as_secs_f64() + shared / chunk.len() as f64;
        reports.push(match result_unit {
            Ok(stats) => UnitReport::of(u, Status::Done, None, own, Some(stats)),
            Err(e) => UnitReport::of(u, Status::Failed, Some(e), own, None),
        });
    }
    Ok(reports)
}

/// Totals of a report: counts per status and seconds.
pub fn totals(reports: &[UnitReport], wall_seconds: f64) -> Value {
    let count = |s: Status| reports.iter().filter(|r| r.status == s).count();
    json!({
        "units": reports.len(),
        "done": count(Status::Done),
        "skipped": count(Status::Skipped),
        "failed": count(Status::Failed),
        "seconds": wall_seconds,
        "unit_seconds": reports.iter().map(|r| r.seconds).sum::<f64>(),
    })
}

/// The whole report document.
pub fn report(jobs_file: &Path, reports: &[UnitReport], run: Value, wall_seconds: f64) -> Value {
    json!({
        "photongrid": env!("CARGO_PKG_VERSION"),
        "jobs_file": jobs_file,
        "run": run,
        "units": reports,
        "totals": totals(reports, wall_seconds),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tidy_paths() {
        assert_eq!(tidy(Path::new("samples/../out/a.exr")), Path::new("out/a.exr"));
        assert_eq!(tidy(Path::new("./a/./b")), Path::new("a/b"));
        assert_eq!(tidy(Path::new("../a")), Path::new("../a"));
        assert_eq!(tidy(Path::new("/x/../y")), Path::new("/y"));
    }

    #[test]
    fn resolver_agrees_with_output_resolved() {
        let dir = std::env::temp_dir().join(format!("pg-resolver-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(dir.join("out")).unwrap();
        std::fs::write(dir.join("out/a.exr"), b"x").unwrap();
        std::os::unix::fs::symlink("out", dir.join("alias")).unwrap();
        std::os::unix::fs::symlink(dir.join("out/a.exr"), dir.join("out/link.exr")).unwrap();
        let mut r = Resolver::default();
        let names = [
            "out/a.exr",
            "alias/a.exr",
            "alias/./a.exr",
            "alias/../out/a.exr",
            "out/link.exr",
            "missing/../out/a.exr",
            "missing/x/../y.exr",
            "out/.",
            "out/..",
            "a.exr",
        ];
        // Twice: the second round answers from the cache.
        for _ in 0..2 {
            for name in names {
                for path in [dir.join(name), PathBuf::from(name)] {
                    assert_eq!(r.resolved(&path), output::resolved(&path, false), "{}", path.display());
                }
            }
        }
        assert_eq!(r.resolved(&dir.join("alias/a.exr")), r.resolved(&dir.join("out/a.exr")));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn resume_key_is_the_job_key_with_the_camera() {
        let settings = Settings {
            max_radius: 0.1,
            ..Settings::default()
        };
        let job = json!({"version": "v", "scene_file": {"bytes": 1, "fnv64": "f"}, "settings": settings, "aovs": true});
        let mut u = failed_unit(0, 0, None, String::new());
        (u.camera, u.camera_index, u.width, u.height) = (Some("Cam".into()), Some(2), Some(64), Some(48));
        u.job_key = job.to_string().into();
        // The key is read back from the job key's text, whose floats serde_json parses to
        // within an ulp (its exact parser would also refuse the out-of-range numbers the
        // glTF loader reports by element), so the expected value is read back the same way.
        let mut whole: Value = serde_json::from_str(&u.job_key).expect("the job key is JSON");
        for (k, v) in [
            ("camera", json!("Cam")),
            ("camera_index", json!(2)),
            ("width", json!(64)),
            ("height", json!(48)),
        ] {
            whole[k] = v;
        }
        assert_eq!(u.key_source(), whole);
        assert_eq!(u.key(), format!("{:016x}", fnv1a64(whole.to_string().as_bytes())));
        let other = u.key();
        u.camera_index = Some(3);
        assert_ne!(u.key(), other);
    }

    #[test]
    fn shard_parsing() {
        assert_eq!(parse_shard("1/3"), Ok((1, 3)));
        assert!(parse_shard("3/3").is_err());
        assert!(parse_shard("0/0").is_err());
        assert!(parse_shard("x").is_err());
    }

    #[test]
    fn defaults_and_job_keys_merge_into_settings() {
        let text = r#"
            [defaults]
            photons = 1000
            spp = 2
            [[job]]
            scene = "a.glb"
            output = "out/{scene}.exr"
            spp = 3
            light-samples = 2
            max_radius = 0.1
            [[job]]
            scene = "b.glb"
            output = "b.exr"
            camera = [0, "Cam"]
            [[job]]
            scene = "c.glb"
            output = "c.exr"
            photon = 5
        "#;
        let jobs = parse_jobs(text, Path::new("/base")).unwrap();
        let a = jobs[0].as_ref().unwrap();
        assert_eq!(a.scene, Path::new("/base/a.glb"));
        assert_eq!(a.output, "/base/out/{scene}.exr");
        assert_eq!(
            (a.settings.photons, a.settings.spp, a.settings.light_samples),
            (1000, 3, 2)
        );
        assert_eq!(a.settings.max_radius, 0.1);
        assert!(a.cameras.is_empty());
        let b = jobs[1].as_ref().unwrap();
        assert_eq!(b.cameras, vec!["0".to_string(), "Cam".into()]);
        assert_eq!(b.settings.spp, 2);
        let e = jobs[2].as_ref().unwrap_err();
        assert!(
            e.message.contains("job 2") && e.message.contains("`photon`"),
            "{}",
            e.message
        );
    }

    #[test]
    fn whole_file_errors() {
        assert!(parse_jobs("[job]\nscene='a'", Path::new(".")).is_err());
        assert!(parse_jobs("jobs = 1", Path::new(".")).is_err());
        let e = parse_jobs("[defaults]\nbogus = 1\n[[job]]\nscene='a'\noutput='b'", Path::new(".")).unwrap_err();
        assert!(e.contains("[defaults]") && e.contains("bogus"), "{e}");
    }

    #[test]
    fn layout_never_oversubscribes() {
        let o = |jobs, threads| RunOptions {
            jobs,
            threads,
            ..RunOptions::default()
        };
        assert_eq!(o(1, 2).layout(), (1, 2));
        assert_eq!(o(2, 2).layout(), (2, 1));
        assert_eq!(o(4, 2).layout(), (2, 1));
        assert_eq!(o(3, 8).layout(), (3, 2));
    }
}
