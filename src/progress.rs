//! Progress and phase timing for long phases: bars on a terminal, JSON lines for callers
//! (the Blender add-on, batch scripts), or nothing.

use indicatif::{ProgressBar, ProgressStyle};
use std::io::Write;
use std::sync::atomic::{AtomicU64, Ordering};
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

/// Reports phases.
#[derive(Debug)]
pub struct Progress {
    mode: ProgressMode,
    tty: bool,
}

impl Progress {
    /// A reporter in `mode`.
    pub fn new(mode: ProgressMode) -> Self {
        use std::io::IsTerminal;
        Progress {
            mode,
            tty: std::io::stderr().is_terminal(),
        }
    }

    /// A reporter that shows nothing.
    pub fn quiet() -> Self {
        Progress {
            mode: ProgressMode::Quiet,
            tty: false,
        }
    }

    /// Start a phase of `total` units of work (0 if unknown).
    pub fn phase(&self, name: &'static str, total: u64) -> Phase {
        let bar = (self.mode == ProgressMode::Auto && self.tty && total > 0).then(|| {
            let b = ProgressBar::new(total);
            b.set_style(
                ProgressStyle::with_template("{prefix:>8} [{bar:40}] {percent:>3}% {elapsed_precise} eta {eta}")
                    .unwrap_or_else(|_| ProgressStyle::default_bar())
                    .progress_chars("=> "),
            );
            b.set_prefix(name);
            b
        });
        let json = self.mode == ProgressMode::Json;
        if json {
            emit_json(&serde_json::json!({"event": "start", "phase": name, "total": total}));
        }
        tracing::debug!(phase = name, total, "phase start");
        Phase {
            name,
            total,
            done: AtomicU64::new(0),
            start: Instant::now(),
            bar,
            json,
            last_json: Mutex::new((Instant::now(), 0)),
        }
    }
}

/// One running phase; `inc` may be called from any thread.
#[derive(Debug)]
pub struct Phase {
    name: &'static str,
    total: u64,
    done: AtomicU64,
    start: Instant,
    bar: Option<ProgressBar>,
    json: bool,
    last_json: Mutex<(Instant, u64)>,
}

impl Phase {
    /// Record `n` more units done.
    pub fn inc(&self, n: u64) {
        let done = self.done.fetch_add(n, Ordering::Relaxed) + n;
        if let Some(b) = &self.bar {
            b.set_position(done);
        }
        if self.json && self.total > 0 {
            // Throttle: at most every 0.2 s or each 1 %.
            let mut last = self.last_json.lock().unwrap_or_else(|e| e.into_inner());
            let step = (self.total / 100).max(1);
            if last.0.elapsed().as_secs_f32() >= 0.2 || done >= last.1 + step || done >= self.total {
                *last = (Instant::now(), done);
                emit_json(&serde_json::json!({
                    "event": "progress", "phase": self.name, "done": done, "total": self.total,
                    "fraction": (done as f64 / self.total as f64).min(1.0),
                }));
            }
        }
    }

    /// End the phase; returns its seconds.
    pub fn finish(self) -> f64 {
        let s = self.start.elapsed().as_secs_f64();
        if let Some(b) = &self.bar {
            b.finish_and_clear();
        }
        if self.json {
            emit_json(&serde_json::json!({"event": "end", "phase": self.name, "seconds": s}));
        }
        tracing::info!(phase = self.name, seconds = format!("{s:.3}"), "done");
        s
    }
}

/// Write one JSON event line to stderr (shared with the CLI's final and error events).
pub fn emit_json(v: &serde_json::Value) {
    let mut e = std::io::stderr().lock();
    let _ = writeln!(e, "{v}");
}
