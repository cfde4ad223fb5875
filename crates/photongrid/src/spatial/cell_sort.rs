//! Sorts of items by cell: how the grid puts the items of a cell next to each other.
//!
//! The top level sorts the caller's vector in place, so that the items exist once: counts per
//! block of cells cut the cells into *buckets*, runs of consecutive cells holding about
//! [`BUCKET_ITEMS`] items; an in-place distribution (American flag sort) moves every item into
//! its bucket; then each bucket, small enough for the cache, is counting-sorted by cell, in
//! parallel. The distribution is serial, so the order inside a cell is the same whatever the
//! thread count (it is not the input order: carrying each item's input index through the
//! distribution to restore it cost 4 bytes per item and a sort per bucket). Child grids sort
//! their (small) sub-range stably through a copy.

use rayon::prelude::*;

/// Wanted items per bucket of the in-place distribution (a bucket's sort then works in the
/// cache).
const BUCKET_ITEMS: usize = 1 << 14;
/// At most this many blocks of cells map cells to buckets (a table of one entry per block).
const MAX_BLOCKS: usize = 1 << 16;
/// Below this many items the top level sorts through a copy (the copy is small).
const IN_PLACE_MIN: usize = 1 << 12;

/// Stable counting sort of `items` by `keys` (`keys[i] < ncells`), through a copy of the
/// slice. Returns the offsets (length `ncells + 1`, relative to the start of the slice).
pub(super) fn counting_sort<T: Clone>(items: &mut [T], keys: &[u32], ncells: usize) -> Vec<u32> {
    let n = items.len();
    let mut offsets = vec![0u32; ncells + 1];
    for &k in keys {
        offsets[k as usize] += 1;
    }
    // Inclusive prefix sums: offsets[c] = end of cell c.
    let mut sum = 0u32;
    for o in offsets[..ncells].iter_mut() {
        sum += *o;
        *o = sum;
    }
    offsets[ncells] = n as u32;
    let src = items.to_vec();
    // Reverse scatter with decrement keeps the sort stable and leaves offsets[c] = start of c.
    for i in (0..n).rev() {
        let k = keys[i] as usize;
        offsets[k] -= 1;
        items[offsets[k] as usize] = src[i].clone();
    }
    offsets
}

/// Sort of `items` by `key(item)` (< `ncells`), in place, in an order that depends on the
/// input only (see the module comment). Returns the offsets (length `ncells + 1`): cell `c` holds `offsets[c]..offsets[c + 1]`.
pub(super) fn sort_by_cell<T, K>(items: &mut [T], key: K, ncells: usize) -> Vec<u32>
where
    T: Clone + Send + Sync,
    K: Fn(&T) -> u32 + Sync,
{
    let n = items.len();
    if n < IN_PLACE_MIN {
        let keys: Vec<u32> = items.iter().map(&key).collect();
        return counting_sort(items, &keys, ncells);
    }
    let buckets = Buckets::new(items, &key, ncells);
    if buckets.len() > 1 {
        // The buckets looked up in parallel first: the serial distribution then reads two
        // bytes per item instead of computing a cell and a table look-up at every swap.
        let mut bucket: Vec<u16> = items.par_iter().map(|t| buckets.of_cell(key(t)) as u16).collect();
        distribute(items, &mut bucket, &buckets.starts);
    }
    // Disjoint sub-slices of items and offsets, one per bucket, sorted in parallel.
    let mut offsets = vec![0u32; ncells + 1];
    offsets[ncells] = n as u32;
    let mut parts = Vec::with_capacity(buckets.len());
    let (mut rest, mut rest_offsets) = (items, &mut offsets[..ncells]);
    for b in 0..buckets.len() {
        let len = buckets.starts[b + 1] - buckets.starts[b];
        let (a, r) = std::mem::take(&mut rest).split_at_mut(len);
        let (cells_lo, cells_hi) = buckets.cells(b, ncells);
        let (o, ro) = std::mem::take(&mut rest_offsets).split_at_mut(cells_hi - cells_lo);
        (rest, rest_offsets) = (r, ro);
        parts.push((a, o, cells_lo as u32, buckets.starts[b] as u32));
    }
    parts
        .into_par_iter()
        .for_each(|(items, offsets, cells_lo, base)| sort_bucket(items, &key, (offsets, cells_lo, base)));
    offsets
}

/// Runs of consecutive cells ("buckets") of about [`BUCKET_ITEMS`] items, made of whole blocks
/// of `2^shift` cells so that a cell's bucket is one table look-up.
struct Buckets {
    shift: u32,
    /// Bucket of each block of cells.
    of_block: Vec<u32>,
    /// First block of each bucket, then the block count.
    first_block: Vec<usize>,
    /// First item of each bucket, then the item count.
    starts: Vec<usize>,
}

impl Buckets {
    /// Count the items per block (in parallel, each thread into its own table) and cut the
    /// blocks into buckets.
    fn new<T: Sync, K: Fn(&T) -> u32 + Sync>(items: &[T], key: &K, ncells: usize) -> Self {
        let mut shift = 0;
        while ncells.div_ceil(1 << shift) > MAX_BLOCKS {
            shift += 1;
        }
        let blocks = ncells.div_ceil(1 << shift);
        // At most 2¹⁶ buckets, so that a bucket fits in a u16 (each closes at `per_bucket`).
        let per_bucket = BUCKET_ITEMS.max(items.len() / (u16::MAX as usize) + 1);
        let counts = items
            .par_chunks(1 << 16)
            .fold(
                || vec![0u32; blocks],
                |mut c, chunk| {
                    for t in chunk {
                        c[(key(t) >> shift) as usize] += 1;
                    }
                    c
                },
            )
            .reduce(
                || vec![0u32; blocks],
                |mut a, b| {
                    a.iter_mut().zip(&b).for_each(|(x, y)| *x += y);
                    a
                },
            );
        let mut of_block = Vec::with_capacity(blocks);
        let (mut first_block, mut starts) = (vec![0usize], vec![0usize]);
        let mut sum = 0usize;
        for (b, &c) in counts.iter().enumerate() {
            if sum - starts[starts.len() - 1] >= per_bucket {
                starts.push(sum);
                first_block.push(b);
            }
            of_block.push((starts.len() - 1) as u32);
            sum += c as usize;
        }
        starts.push(sum);
        first_block.push(blocks);
        Buckets {
            shift,
            of_block,
            first_block,
            starts,
        }
    }

    fn len(&self) -> usize {
        self.starts.len() - 1
    }

    /// The cells `lo..hi` of bucket `b`.
    fn cells(&self, b: usize, ncells: usize) -> (usize, usize) {
        let cell = |block: usize| (block << self.shift).min(ncells);
        (cell(self.first_block[b]), cell(self.first_block[b + 1]))
    }

    #[inline(always)]
    fn of_cell(&self, cell: u32) -> usize {
        self.of_block[(cell >> self.shift) as usize] as usize
    }
}

/// American flag sort: move every item (with its bucket) into its bucket, in place; `starts`
/// are the buckets' first items. Items are carried along their cycles (one read and one write
/// per move; swapping through the cycle's first slot cost a fifth more) and each move puts
/// one item where it belongs.
///
/// Each move depends on the one before (the item displaced decides where the next goes), so
/// the walk would wait for memory at every bucket's next cache line; reading the bucket
/// [`AHEAD`] places further on in the same bucket, whose result nothing waits for, fetches
/// that line early.
fn distribute<T: Clone>(items: &mut [T], bucket: &mut [u16], starts: &[usize]) {
    let mut next: Vec<usize> = starts[..starts.len() - 1].to_vec();
    let last = items.len() - 1;
    let mut fetched = 0u32;
    for b in 0..next.len() {
        let end = starts[b + 1];
        while next[b] < end {
            let i = next[b];
            let mut to = bucket[i] as usize;
            if to == b {
                next[b] += 1;
                continue;
            }
            // Carry the item out of place along its cycle: each step writes it where it
            // belongs and picks up the item it displaces, until one belongs at `i`.
            let mut carry = items[i].clone();
            loop {
                while bucket[next[to]] as usize == to {
                    next[to] += 1; // already in place (there is room: `carry` belongs here)
                }
                let j = next[to];
                next[to] += 1;
                let ahead = (j + AHEAD).min(last);
                fetched ^= bucket[ahead] as u32;
                std::mem::swap(&mut items[j], &mut carry);
                let displaced = bucket[j] as usize;
                bucket[j] = to as u16;
                to = displaced;
                if to == b {
                    items[i] = carry;
                    bucket[i] = b as u16;
                    next[b] += 1;
                    break;
                }
            }
        }
    }
    std::hint::black_box(fetched);
}

/// How far ahead in a bucket [`distribute`] reads (items).
const AHEAD: usize = 16;

/// Counting sort of one bucket by cell, stable (keeps the distribution's order inside a cell).
/// `offsets` are the bucket's cells' (the first is `cells_lo`), filled with absolute starts
/// (the bucket's first item is `base`).
fn sort_bucket<T: Clone, K: Fn(&T) -> u32>(items: &mut [T], key: &K, at: (&mut [u32], u32, u32)) {
    let (offsets, cells_lo, base) = at;
    for t in items.iter() {
        offsets[(key(t) - cells_lo) as usize] += 1;
    }
    let mut sum = 0u32;
    for o in offsets.iter_mut() {
        let c = *o;
        *o = sum;
        sum += c;
    }
    let src = items.to_vec();
    for t in &src {
        let slot = &mut offsets[(key(t) - cells_lo) as usize];
        items[*slot as usize] = t.clone();
        *slot += 1;
    }
    // Each cell's cursor ended at the next cell's start: shift back and make absolute.
    let mut start = base;
    for o in offsets.iter_mut() {
        let end = *o + base;
        *o = start;
        start = end;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::Rng;

    /// `sort_by_cell`: sorted by cell, the same items, the offsets right, and the same order on
    /// one thread as on all of them.
    fn check(keys: Vec<u32>, ncells: usize) {
        let items: Vec<(u32, u32)> = keys.iter().enumerate().map(|(i, &k)| (k, i as u32)).collect();
        let mut expected = items.clone();
        expected.sort_by_key(|t| t.0);
        let mut sorted = items.clone();
        let offsets = sort_by_cell(&mut sorted, |t| t.0, ncells);
        assert!(sorted.windows(2).all(|w| w[0].0 <= w[1].0), "not sorted by cell");
        let mut same = sorted.clone();
        same.sort();
        assert!(same == expected, "not the same items ({} items)", keys.len());
        let one_thread = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .expect("a thread");
        let mut alone = items;
        let alone_offsets = one_thread.install(|| sort_by_cell(&mut alone, |t| t.0, ncells));
        assert!(
            alone == sorted && alone_offsets == offsets,
            "the order depends on the threads"
        );
        assert_eq!(offsets.len(), ncells + 1);
        for c in 0..ncells {
            let run = &sorted[offsets[c] as usize..offsets[c + 1] as usize];
            assert!(run.iter().all(|t| t.0 == c as u32), "cell {c}");
        }
        assert_eq!(offsets[ncells] as usize, keys.len());
    }

    #[test]
    fn in_place_sort_groups_cells_whatever_the_threads() {
        let mut rng = Rng::keyed(15, 0, 0);
        // Uniform keys over many cells (many buckets), over few cells (runs of equal keys),
        // and skewed: half of the items in one cell, the rest spread.
        let n = 200_000;
        check((0..n).map(|_| rng.next_u32() % 300_000).collect(), 300_000);
        check((0..n).map(|_| rng.next_u32() % 7).collect(), 7);
        let skewed = (0..n)
            .map(|i| if i % 2 == 0 { 4_321 } else { rng.next_u32() % (1 << 20) })
            .collect();
        check(skewed, 1 << 20);
        // Below the in-place threshold, and empty.
        check((0..100).map(|_| rng.next_u32() % 10).collect(), 10);
        check(Vec::new(), 3);
    }
}
