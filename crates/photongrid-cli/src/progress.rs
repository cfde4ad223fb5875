//! Showing progress: bars on a terminal, JSON lines on stderr for programs that drive the
//! renderer (the Blender add-on, batch scripts), or nothing. Implements the library's
//! [`photongrid::progress::Observer`].

use indicatif::{ProgressBar, ProgressStyle};
use photongrid::progress::Observer;
use std::io::Write;
use std::sync::Mutex;
use std::time::Instant;

/// How progress is shown.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ProgressMode {
    /// Bars on stderr when it is a terminal, nothing otherwise.
    Auto,
    /// One JSON object per line on stderr: `{"event":"start"|"progress"|"end", "phase", ...}`.
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
        }
    }
}

impl Observer for Display {
    fn start(&self, phase: &'static str, total: u64) {
        match self.mode {
            ProgressMode::Auto if self.tty && total > 0 => {
                let b = ProgressBar::new(total);
                b.set_style(
                    ProgressStyle::with_template("{prefix:>10} [{bar:40}] {percent:>3}% {elapsed_precise} eta {eta}")
                        .unwrap_or_else(|_| ProgressStyle::default_bar())
                        .progress_chars("=> "),
                );
                b.set_prefix(phase);
                *self.bar.lock().unwrap_or_else(|e| e.into_inner()) = Some(b);
            }
            ProgressMode::Json => {
                *self.last_json.lock().unwrap_or_else(|e| e.into_inner()) = (Instant::now(), 0);
                emit_json(&serde_json::json!({"event": "start", "phase": phase, "total": total}));
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
                    emit_json(&serde_json::json!({
                        "event": "progress", "phase": phase, "done": done, "total": total,
                        "fraction": (done as f64 / total as f64).min(1.0),
                    }));
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
            emit_json(&serde_json::json!({"event": "end", "phase": phase, "seconds": seconds}));
        }
    }
}

/// Write one JSON event line to stderr (shared with the CLI's final and error events).
pub fn emit_json(v: &serde_json::Value) {
    let mut e = std::io::stderr().lock();
    let _ = writeln!(e, "{v}");
}
