//! Showing progress: bars on a terminal, JSON lines on stderr for programs that drive the
//! renderer (the Blender add-on, batch scripts), or nothing. Implements the library's
//! [`photongrid::progress::Observer`], including its request to stop after the current pass
//! (set from a signal handler, see [`Display::with_stop`]).
//!
//! With `--progress json` stderr carries JSON lines only: the phase events, `camera` before
//! each camera's `render` phase (whose events also name the camera), `checkpoint`, `output`,
//! `warning` (the loader's approximations and every log warning), `log` (with `-v`), `done`
//! and `error`. [`JsonLog`] turns log records into such lines.

use indicatif::{ProgressBar, ProgressStyle};
use photongrid::progress::Observer;
use std::io::Write;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// How progress is shown.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ProgressMode {
    /// Bars on stderr when it is a terminal, nothing otherwise; a summary line at the end.
    Auto,
    /// One JSON object per line on stderr and nothing else, for programs: events start,
    /// progress, end, camera, checkpoint, stopping, output, warning, log, done and error.
    Json,
    /// Nothing.
    Quiet,
}

/// Shows phases as bars or JSON lines.
pub struct Display {
    mode: ProgressMode,
    tty: bool,
    bar: Mutex<Option<ProgressBar>>,
    /// Last JSON progress event: when, and how much was done.
    last_json: Mutex<(Instant, u64)>,
    /// The camera of the current `render` phase.
    camera: Mutex<Option<String>>,
    /// Set (by a signal handler) to stop after the current pass.
    stop: Option<Arc<AtomicBool>>,
    /// The stop has been announced (a JSON `stopping` event).
    announced: AtomicBool,
}

impl Display {
    /// A display in `mode`.
    pub fn new(mode: ProgressMode) -> Self {
        use std::io::IsTerminal;
        Display {
            mode,
            tty: std::io::stderr().is_terminal(),
            bar: Mutex::new(None),
            last_json: Mutex::new((Instant::now(), 0)),
            camera: Mutex::new(None),
            stop: None,
            announced: AtomicBool::new(false),
        }
    }

    /// Ask the render to stop after the current pass once `flag` is set.
    pub fn with_stop(mut self, flag: Arc<AtomicBool>) -> Self {
        self.stop = Some(flag);
        self
    }

    /// The mode.
    pub fn mode(&self) -> ProgressMode {
        self.mode
    }

    /// Tell the user something went approximately: a JSON `warning` event, else a log warning.
    pub fn warning(&self, message: &str) {
        if self.mode == ProgressMode::Json {
            emit_json(&serde_json::json!({"event": "warning", "message": message}));
        } else {
            tracing::warn!("{message}");
        }
    }

    /// The current camera, for `render` events.
    fn camera_of(&self, phase: &str) -> Option<String> {
        if phase == "render" {
            self.camera.lock().unwrap_or_else(|e| e.into_inner()).clone()
        } else {
            None
        }
    }
}

/// `v` with `"camera": camera` added when there is one.
fn with_camera(mut v: serde_json::Value, camera: Option<String>) -> serde_json::Value {
    if let Some(c) = camera {
        v["camera"] = serde_json::Value::String(c);
    }
    v
}

impl Observer for Display {
    fn start(&self, phase: &'static str, total: u64) {
        match self.mode {
            ProgressMode::Auto if self.tty => {
                let prefix = match self.camera_of(phase) {
                    Some(c) => format!("{phase} {c}"),
                    None => phase.to_string(),
                };
                let b = if total > 0 {
                    let b = ProgressBar::new(total);
                    b.set_style(
                        ProgressStyle::with_template(
                            "{prefix:>10} [{bar:40}] {percent:>3}% {elapsed_precise} eta {eta}",
                        )
                        .unwrap_or_else(|_| ProgressStyle::default_bar())
                        .progress_chars("=> "),
                    );
                    b
                } else {
                    // Work of unknown size (irradiance, grids, the index): a spinner and the time.
                    let b = ProgressBar::new_spinner();
                    b.set_style(
                        ProgressStyle::with_template("{prefix:>10} {spinner} {elapsed_precise}")
                            .unwrap_or_else(|_| ProgressStyle::default_spinner()),
                    );
                    b.enable_steady_tick(Duration::from_millis(120));
                    b
                };
                b.set_prefix(prefix);
                *self.bar.lock().unwrap_or_else(|e| e.into_inner()) = Some(b);
            }
            ProgressMode::Json => {
                *self.last_json.lock().unwrap_or_else(|e| e.into_inner()) = (Instant::now(), 0);
                emit_json(&with_camera(
                    serde_json::json!({"event": "start", "phase": phase, "total": total}),
                    self.camera_of(phase),
                ));
            }
            _ => {}
        }
    }

    fn advance(&self, phase: &'static str, done: u64, total: u64) {
        match self.mode {
            ProgressMode::Auto => {
                if let Some(b) = self.bar.lock().unwrap_or_else(|e| e.into_inner()).as_ref() {
                    b.set_position(done);
                }
            }
            ProgressMode::Json if total > 0 => {
                // Throttle: at most every 0.2 s or each 1 %.
                let mut last = self.last_json.lock().unwrap_or_else(|e| e.into_inner());
                let step = (total / 100).max(1);
                if last.0.elapsed().as_secs_f32() >= 0.2 || done >= last.1 + step || done >= total {
                    *last = (Instant::now(), done);
                    emit_json(&with_camera(
                        serde_json::json!({
                            "event": "progress", "phase": phase, "done": done, "total": total,
                            "fraction": (done as f64 / total as f64).min(1.0),
                        }),
                        self.camera_of(phase),
                    ));
                }
            }
            _ => {}
        }
    }

    fn end(&self, phase: &'static str, seconds: f64) {
        if let Some(b) = self.bar.lock().unwrap_or_else(|e| e.into_inner()).take() {
            b.finish_and_clear();
        }
        if self.mode == ProgressMode::Json {
            emit_json(&with_camera(
                serde_json::json!({"event": "end", "phase": phase, "seconds": seconds}),
                self.camera_of(phase),
            ));
        }
    }

    fn camera(&self, name: &str) {
        *self.camera.lock().unwrap_or_else(|e| e.into_inner()) = Some(name.to_string());
        if self.mode == ProgressMode::Json {
            emit_json(&serde_json::json!({"event": "camera", "camera": name}));
        }
    }

    fn should_stop(&self) -> bool {
        let stop = self.stop.as_ref().is_some_and(|f| f.load(Ordering::Relaxed));
        if stop && self.mode == ProgressMode::Json && !self.announced.swap(true, Ordering::Relaxed) {
            emit_json(&serde_json::json!({"event": "stopping"}));
        }
        stop
    }
}

/// Write one JSON event line to stderr (shared with the CLI's final and error events).
pub fn emit_json(v: &serde_json::Value) {
    let mut e = std::io::stderr().lock();
    let _ = writeln!(e, "{v}");
}

/// Log records as JSON lines on stderr (for `--progress json`): warnings and errors as
/// `{"event":"warning","message":...}`, the rest (with `-v`) as
/// `{"event":"log","level":"info","message":...}`; a record's other fields follow its message as
/// `key=value`.
pub struct JsonLog;

#[derive(Default)]
struct Fields {
    message: String,
    rest: Vec<String>,
}

impl tracing::field::Visit for Fields {
    fn record_str(&mut self, field: &tracing::field::Field, value: &str) {
        if field.name() == "message" {
            self.message = value.to_string();
        } else {
            self.rest.push(format!("{}={value}", field.name()));
        }
    }

    fn record_debug(&mut self, field: &tracing::field::Field, value: &dyn std::fmt::Debug) {
        if field.name() == "message" {
            self.message = format!("{value:?}");
        } else {
            self.rest.push(format!("{}={value:?}", field.name()));
        }
    }
}

impl<S: tracing::Subscriber> tracing_subscriber::Layer<S> for JsonLog {
    fn on_event(&self, event: &tracing::Event<'_>, _ctx: tracing_subscriber::layer::Context<'_, S>) {
        let mut f = Fields::default();
        event.record(&mut f);
        let mut message = f.message;
        for r in f.rest {
            if !message.is_empty() {
                message.push(' ');
            }
            message.push_str(&r);
        }
        let level = *event.metadata().level();
        if level <= tracing::Level::WARN {
            emit_json(&serde_json::json!({"event": "warning", "message": message}));
        } else {
            emit_json(&serde_json::json!({
                "event": "log", "level": level.as_str().to_lowercase(), "message": message,
            }));
        }
    }
}
