//! Progress of long phases. The library names its phases and counts their work; a front end
//! (bars on a terminal, JSON lines for the Blender add-on) decides how to show it by
//! implementing [`Observer`].

use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

/// Receives phase events. Every method has an empty default, so an observer implements only
/// what it shows. Called from worker threads.
pub trait Observer: Sync {
    /// A phase of `total` units of work starts (0: unknown).
    fn start(&self, _phase: &'static str, _total: u64) {}
    /// `done` of `total` units are finished.
    fn advance(&self, _phase: &'static str, _done: u64, _total: u64) {}
    /// The phase ended after `seconds`.
    fn end(&self, _phase: &'static str, _seconds: f64) {}
    /// The phases that follow (the next `render` phase) work on the camera `name`.
    fn camera(&self, _name: &str) {}
    /// Whether the front end asks to stop after the current pass (Esc, Ctrl+C). Polled between
    /// passes; the passes done so far are kept.
    fn should_stop(&self) -> bool {
        false
    }
}

/// An observer that shows nothing.
pub struct Silent;

impl Observer for Silent {}

/// Starts phases and forwards their events to an [`Observer`].
#[derive(Clone, Copy)]
pub struct Progress<'a> {
    observer: &'a dyn Observer,
}

impl std::fmt::Debug for Progress<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Progress")
    }
}

impl<'a> Progress<'a> {
    /// Report to `observer`.
    pub fn new(observer: &'a dyn Observer) -> Self {
        Progress { observer }
    }

    /// Report nothing.
    pub fn quiet() -> Progress<'static> {
        Progress { observer: &Silent }
    }

    /// Say which camera the next phases work on.
    pub fn camera(&self, name: &str) {
        self.observer.camera(name);
    }

    /// Whether the front end asks to stop after the current pass.
    pub fn should_stop(&self) -> bool {
        self.observer.should_stop()
    }

    /// Start a phase of `total` units of work (0 if unknown).
    pub fn phase(&self, name: &'static str, total: u64) -> Phase<'a> {
        self.observer.start(name, total);
        tracing::debug!(phase = name, total, "phase start");
        Phase {
            name,
            total,
            done: AtomicU64::new(0),
            start: Instant::now(),
            observer: self.observer,
        }
    }
}

/// One running phase; [`Phase::inc`] may be called from any thread.
pub struct Phase<'a> {
    name: &'static str,
    total: u64,
    done: AtomicU64,
    start: Instant,
    observer: &'a dyn Observer,
}

impl Phase<'_> {
    /// Record `n` more units done. A phase that does more than its total (a camera pass's
    /// spare sweeps) shows as complete.
    pub fn inc(&self, n: u64) {
        let done = self.done.fetch_add(n, Ordering::Relaxed) + n;
        let shown = if self.total > 0 { done.min(self.total) } else { done };
        self.observer.advance(self.name, shown, self.total);
    }

    /// End the phase; returns its seconds.
    pub fn finish(self) -> f64 {
        let s = self.start.elapsed().as_secs_f64();
        self.observer.end(self.name, s);
        tracing::info!(phase = self.name, seconds = format!("{s:.3}"), "done");
        s
    }
}
