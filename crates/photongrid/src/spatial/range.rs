//! Fixed-radius queries on a [`PointGrid`]: visiting or counting every item within a radius.

use super::point_grid::{PointGrid, Positioned};
use super::traverse::{dist2, touch_items, Query, Sink, SCAN_CHUNK};
use glam::Vec3;

/// Calls a closure for every item within the radius.
struct EachSink<'a, T, F> {
    query: Query<'a, T>,
    r2: f32,
    f: F,
}

impl<T: Positioned, F: FnMut(&T, f32)> Sink for EachSink<'_, T, F> {
    #[inline(always)]
    fn radius2(&self) -> f32 {
        self.r2
    }

    #[inline(always)]
    fn touch(&self, start: usize, end: usize) -> u32 {
        touch_items(self.query.items, start, end)
    }

    #[inline(always)]
    fn scan(&mut self, start: usize, end: usize) {
        let q = self.query.q;
        let r2 = self.r2;
        let mut tmp = [(0u32, 0f32); SCAN_CHUNK];
        let mut base = start;
        for chunk in self.query.items[start..end].chunks(SCAN_CHUNK) {
            let mut n = 0usize;
            for (j, it) in chunk.iter().enumerate() {
                let d2 = dist2(it.position().to_array(), q);
                tmp[n & (SCAN_CHUNK - 1)] = ((base + j) as u32, d2);
                n += (d2 <= r2) as usize;
            }
            for &(i, d2) in &tmp[..n] {
                (self.f)(&self.query.items[i as usize], d2);
            }
            base += chunk.len();
        }
    }
}

/// Counts the items within the radius.
struct CountSink<'a, T> {
    query: Query<'a, T>,
    r2: f32,
    count: usize,
}

impl<T: Positioned> Sink for CountSink<'_, T> {
    #[inline(always)]
    fn radius2(&self) -> f32 {
        self.r2
    }

    #[inline(always)]
    fn touch(&self, start: usize, end: usize) -> u32 {
        touch_items(self.query.items, start, end)
    }

    #[inline(always)]
    fn scan(&mut self, start: usize, end: usize) {
        let q = self.query.q;
        let r2 = self.r2;
        self.count += self.query.items[start..end]
            .iter()
            .filter(|it| dist2(it.position().to_array(), q) <= r2)
            .count();
    }
}

impl<T: Positioned + Send + Sync + Clone> PointGrid<T> {
    /// Calls f(item, squared distance) for every item within radius r of p.
    ///
    /// Items at exactly `r` are included; nothing is reported for a NaN or negative `r`.
    pub fn for_each_within<F: FnMut(&T, f32)>(&self, p: Vec3, r: f32, f: F) {
        if self.is_empty() || !p.is_finite() || r.is_nan() || r < 0.0 {
            return;
        }
        let mut sink = EachSink {
            query: self.query(p),
            r2: r * r,
            f,
        };
        self.visit(0, p, self.pad_for(p), &mut sink);
    }

    /// Count of items within r (cheap helper).
    pub fn count_within(&self, p: Vec3, r: f32) -> usize {
        if self.is_empty() || !p.is_finite() || r.is_nan() || r < 0.0 {
            return 0;
        }
        let mut sink = CountSink {
            query: self.query(p),
            r2: r * r,
            count: 0,
        };
        self.visit(0, p, self.pad_for(p), &mut sink);
        sink.count
    }
}
