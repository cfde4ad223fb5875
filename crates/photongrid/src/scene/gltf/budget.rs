//! The memory budget of a load: before anything large is allocated, the loader adds up what the
//! scene will need (the file, its buffers, the triangles after instancing, the largest primitive
//! while it is read, the decoded textures) and refuses the scene, with the estimate, the limit
//! and what to change, when the sum is over the budget.
//!
//! The budget is [`LoadOptions::memory_budget_bytes`](super::LoadOptions) if set, else half of
//! the machine's RAM (`MemTotal` of `/proc/meminfo`), else 8 GiB.

use super::{LoadError, LoadOptions};
use crate::scene::Triangle;
use std::path::Path;

/// Bytes a triangle costs: the [`Triangle`] itself (100 bytes), the load's transient copies
/// and the ray-tracing BVH built over it. Measured: a 2M-triangle mesh peaks at 0.66 GB in
/// `photongrid info` and at 0.81 GB in a render with few photons, about 400 bytes a triangle.
pub(super) const BYTES_PER_TRIANGLE: u64 = std::mem::size_of::<Triangle>() as u64 + 300;
/// Bytes a texel costs in a [`Texture`](crate::scene::Texture) (linear RGB, f32).
pub(super) const BYTES_PER_TEXEL: u64 = 12;
/// The budget when the RAM cannot be read.
const FALLBACK_BYTES: u64 = 8 << 30;

/// The estimate of a load, item by item, against its limit.
pub(super) struct Budget {
    limit: u64,
    /// Where the limit comes from, for the message.
    origin: String,
    items: Vec<(String, u64)>,
}

impl Budget {
    pub(super) fn new(options: &LoadOptions) -> Self {
        let (limit, origin) = match options.memory_budget_bytes {
            Some(b) => (b, "set in the load options".to_string()),
            None => match physical_ram() {
                Some(ram) => (ram / 2, format!("half of the {} of RAM", human(ram))),
                None => (FALLBACK_BYTES, "the default when the RAM size is unknown".to_string()),
            },
        };
        Budget {
            limit,
            origin,
            items: Vec::new(),
        }
    }

    /// Add `bytes` for `what`.
    pub(super) fn add(&mut self, what: impl Into<String>, bytes: u64) {
        self.items.push((what.into(), bytes));
    }

    /// Sum of the items so far.
    pub(super) fn total(&self) -> u64 {
        self.items.iter().fold(0u64, |s, (_, b)| s.saturating_add(*b))
    }

    /// What is left of the limit.
    pub(super) fn left(&self) -> u64 {
        self.limit.saturating_sub(self.total())
    }

    /// The limit itself.
    pub(super) fn limit(&self) -> u64 {
        self.limit
    }

    /// Most vertex attributes and indices a load may read after instancing: 2³⁰, or one per 8
    /// bytes of the budget if that is more (the work a load does, hence its time, is
    /// proportional to them; a legitimate scene reads about 6 per triangle).
    pub(super) fn max_reads(&self) -> u64 {
        (1u64 << 30).max(self.limit / 8)
    }

    /// An error if the items add up to more than the limit.
    pub(super) fn check(&self, path: &Path) -> Result<(), LoadError> {
        let needed = self.total();
        if needed <= self.limit {
            return Ok(());
        }
        let items: Vec<String> = self
            .items
            .iter()
            .filter(|(_, b)| *b > 0)
            .map(|(what, b)| format!("{what}: {}", human(*b)))
            .collect();
        Err(LoadError::OverBudget {
            path: path.to_path_buf(),
            needed,
            budget: self.limit,
            message: format!(
                "loading the scene would need about {} ({}), more than the memory budget of {} ({}); make the scene smaller (fewer or smaller meshes, fewer instances, smaller textures) or raise the budget (LoadOptions::memory_budget_bytes)",
                human(needed),
                items.join("; "),
                human(self.limit),
                self.origin
            ),
        })
    }
}

/// `MemTotal` of `/proc/meminfo`, in bytes.
fn physical_ram() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("MemTotal:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    kib.checked_mul(1024)
}

/// Bytes for people: `3.2 GiB`, `640 MiB`, `12 KiB`, `100 bytes`.
pub(super) fn human(bytes: u64) -> String {
    const UNITS: [(&str, u64); 4] = [("TiB", 1 << 40), ("GiB", 1 << 30), ("MiB", 1 << 20), ("KiB", 1 << 10)];
    for (unit, size) in UNITS {
        if bytes >= size {
            return format!("{:.1} {unit}", bytes as f64 / size as f64);
        }
    }
    format!("{bytes} bytes")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn over_budget_names_the_items_and_the_limit() {
        let options = LoadOptions {
            memory_budget_bytes: Some(1 << 20),
            ..Default::default()
        };
        let mut b = Budget::new(&options);
        b.add("the file", 1000);
        assert!(b.check(Path::new("s.glb")).is_ok());
        b.add("64000000 triangles after instancing", 64_000_000 * BYTES_PER_TRIANGLE);
        let e = b.check(Path::new("s.glb")).unwrap_err().to_string();
        assert!(
            e.contains("s.glb") && e.contains("triangles") && e.contains("1.0 MiB"),
            "{e}"
        );
        assert!(e.contains("memory_budget_bytes"), "{e}");
        assert_eq!(human(3 << 29), "1.5 GiB");
    }

    #[test]
    fn default_budget_is_half_the_ram() {
        let b = Budget::new(&LoadOptions::default());
        match physical_ram() {
            Some(ram) => assert_eq!(b.limit(), ram / 2),
            None => assert_eq!(b.limit(), FALLBACK_BYTES),
        }
    }
}
