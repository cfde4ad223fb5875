//! Stable counting sorts of item positions by cell: how the grid puts the items of a cell
//! next to each other, serially for child grids and in parallel for the top level.

use rayon::prelude::*;

/// Stable counting sort of `pos` / `perm` by `keys` (`keys[i] < ncells`). Returns the
/// offsets (length `ncells + 1`, relative to the start of the slices).
pub(super) fn counting_sort(pos: &mut [[f32; 3]], perm: &mut [u32], keys: &[u32], ncells: usize) -> Vec<u32> {
    let n = pos.len();
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
    let mut new_pos = vec![[0.0f32; 3]; n];
    let mut new_perm = vec![0u32; n];
    // Reverse scatter with decrement keeps the sort stable and leaves offsets[c] = start of c.
    for i in (0..n).rev() {
        let k = keys[i] as usize;
        offsets[k] -= 1;
        let d = offsets[k] as usize;
        new_pos[d] = pos[i];
        new_perm[d] = perm[i];
    }
    pos.copy_from_slice(&new_pos);
    perm.copy_from_slice(&new_perm);
    offsets
}

/// Parallel stable counting sort of `pos` by `keys` for the top level. Returns the offsets
/// (length `ncells + 1`), the sorted positions and the permutation (sorted slot -> input index).
///
/// Each of `parts` workers owns a range of cells: it scans all keys and handles only those in
/// its range, so histogram and scatter write disjoint slices (no atomics, no unsafe).
pub(super) fn counting_sort_par(pos: &[[f32; 3]], keys: &[u32], ncells: usize) -> (Vec<u32>, Vec<[f32; 3]>, Vec<u32>) {
    let n = keys.len();
    let parts = rayon::current_num_threads().clamp(1, 64);
    if parts == 1 || n < 1 << 12 {
        let mut pos = pos.to_vec();
        let mut perm: Vec<u32> = (0..n as u32).collect();
        let offsets = counting_sort(&mut pos, &mut perm, keys, ncells);
        return (offsets, pos, perm);
    }
    let mut offsets = vec![0u32; ncells + 1];
    let chunk = ncells.div_ceil(parts);
    offsets[..ncells].par_chunks_mut(chunk).enumerate().for_each(|(j, h)| {
        let lo = j * chunk;
        for &k in keys {
            let d = (k as usize).wrapping_sub(lo);
            if d < h.len() {
                h[d] += 1;
            }
        }
    });
    // Exclusive prefix sums: offsets[c] = start of cell c.
    let mut sum = 0u32;
    for o in offsets.iter_mut() {
        let c = *o;
        *o = sum;
        sum += c;
    }
    // Split the cells into ranges holding about n / parts items each.
    let mut bounds: Vec<usize> = (0..=parts)
        .map(|j| offsets[..ncells].partition_point(|&o| (o as usize) < n * j / parts))
        .collect();
    bounds[0] = 0;
    bounds[parts] = ncells;
    bounds.dedup();
    let mut new_pos = vec![[0.0f32; 3]; n];
    let mut perm = vec![0u32; n];
    let mut tasks = Vec::with_capacity(bounds.len());
    {
        let mut rest_pos: &mut [[f32; 3]] = &mut new_pos;
        let mut rest_perm: &mut [u32] = &mut perm;
        for w in bounds.windows(2) {
            let (c0, c1) = (w[0], w[1]);
            let len = (offsets[c1] - offsets[c0]) as usize;
            let (a, b) = std::mem::take(&mut rest_pos).split_at_mut(len);
            rest_pos = b;
            let (c, d) = std::mem::take(&mut rest_perm).split_at_mut(len);
            rest_perm = d;
            tasks.push((c0, c1, a, c));
        }
    }
    let offsets_ref = &offsets;
    tasks.into_par_iter().for_each(|(c0, c1, out_pos, out_perm)| {
        let base = offsets_ref[c0];
        let mut cursor: Vec<u32> = offsets_ref[c0..c1].iter().map(|&o| o - base).collect();
        for (i, &k) in keys.iter().enumerate() {
            let d = (k as usize).wrapping_sub(c0);
            if d < cursor.len() {
                let dst = cursor[d] as usize;
                cursor[d] += 1;
                out_pos[dst] = pos[i];
                out_perm[dst] = i as u32;
            }
        }
    });
    (offsets, new_pos, perm)
}
