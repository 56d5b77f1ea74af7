//! Regression rows in Everett coordinates (`docs/method/fast-paths.md`, "Identification without the dense
//! matrix").
//!
//! The output is `y = 2 S⁺ − E(n_h, 0) + offset`, and S⁺ is a signed sum of Everett
//! values at the staircase corners. So a row has O(depth) non-zeros in the Everett
//! coordinates `E(a, b)` (0 <= b < a <= n_h), where the mass coordinates would need
//! n_q. Samples that leave the staircase unchanged, and samples that revisit a state
//! seen before, merge into one weighted row (weight = count, target = mean): exact for
//! least squares, the within-row scatter is kept for the residual.

use std::collections::HashMap;

use crate::grid::Grid;
use crate::memory::Memory;

/// Index of the Everett value `E(a, b)`, 0 <= b < a <= n_h.
#[inline]
pub fn everett_var(a: usize, b: usize) -> usize {
    debug_assert!(b < a);
    a * (a - 1) / 2 + b
}

/// Merged regression rows, sparse in Everett coordinates. The offset column (all ones)
/// is implicit.
#[derive(Debug, Clone)]
pub struct Rows {
    pub n_h: usize,
    pub interpolated: bool,
    pub indptr: Vec<usize>,
    pub idx: Vec<u32>,
    pub val: Vec<f64>,
    /// Coefficient of the offset in each row (1 for plain rows; pseudo-rows scale it).
    pub offset_coef: Vec<f64>,
    /// Number of samples merged into each row (1 for pseudo-rows).
    pub weight: Vec<f64>,
    /// Mean target of each row.
    pub target: Vec<f64>,
    /// Sum of squared deviations from the row means (unexplainable by any model).
    pub within_ss: f64,
    pub n_samples: usize,
    /// The quantized input levels with consecutive repeats dropped (stepwise rows only;
    /// empty for interpolated ones): what the relays saw, for the excitation report.
    pub levels: Vec<u32>,
}

impl Rows {
    fn empty(n_h: usize, interpolated: bool, n_samples: usize) -> Self {
        Rows {
            n_h,
            interpolated,
            indptr: vec![0],
            idx: Vec::new(),
            val: Vec::new(),
            offset_coef: Vec::new(),
            weight: Vec::new(),
            target: Vec::new(),
            within_ss: 0.0,
            n_samples,
            levels: Vec::new(),
        }
    }

    /// Append a row (entries sorted, offset coefficient last in `entries` excluded).
    fn push(&mut self, entries: &[(u32, f64)], offset_coef: f64, weight: f64, target: f64) {
        for &(i, v) in entries {
            self.idx.push(i);
            self.val.push(v);
        }
        self.indptr.push(self.idx.len());
        self.offset_coef.push(offset_coef);
        self.weight.push(weight);
        self.target.push(target);
    }

    pub fn n_rows(&self) -> usize {
        self.weight.len()
    }
    pub fn row(&self, r: usize) -> (&[u32], &[f64]) {
        let (s, e) = (self.indptr[r], self.indptr[r + 1]);
        (&self.idx[s..e], &self.val[s..e])
    }
    /// Number of Everett variables n_q.
    pub fn n_vars(&self) -> usize {
        self.n_h * (self.n_h + 1) / 2
    }

    /// Row `r` in mass coordinates, added into `out` (n_q, packed like the masses):
    /// `E(a, b)` covers the cells with i >= b and j < a. The offset coefficient is
    /// `offset_coef[r]`.
    pub fn add_mass_row(&self, r: usize, scale: f64, out: &mut [f64]) {
        let (idx, val) = self.row(r);
        for (&k, &v) in idx.iter().zip(val) {
            let (a, b) = everett_coords(k as usize);
            // Packed rows are contiguous in j: for each i in b..a, cells j = i..a.
            for i in b..a {
                let base = crate::grid::cell_index(self.n_h, i, i);
                for c in &mut out[base..base + (a - i)] {
                    *c += scale * v;
                }
            }
        }
    }
}

/// Inverse of [`everett_var`].
#[inline]
pub fn everett_coords(k: usize) -> (usize, usize) {
    // a(a-1)/2 <= k < a(a+1)/2
    let mut a = ((1.0 + (1.0 + 8.0 * k as f64).sqrt()) / 2.0) as usize;
    while a * (a - 1) / 2 > k {
        a -= 1;
    }
    while (a + 1) * a / 2 <= k {
        a += 1;
    }
    (a, k - a * (a - 1) / 2)
}

/// The rows' memory (grid positions) at a record's start: every relay at −1, then the
/// input through `extrema` (alternating extrema of a history nobody recorded, input
/// units), as the hysteresis block's `initial_extrema` sets it; the first sample then
/// moves on from there.
pub(super) fn memory_after(grid: &Grid, extrema: &[f64]) -> Memory<f64> {
    let mut mem: Memory<f64> = Memory::new(0.0, 4 * (grid.n_h() + 3));
    for &e in extrema {
        mem.apply(grid.position(e), &|_: f64, _: f64| 0.0);
    }
    mem
}

/// Build the merged rows of input `u` and target `y` (same length, finite).
/// `interpolated` selects the model whose masses are spread over their cells.
pub fn build_rows(grid: &Grid, u: &[f64], y: &[f64], interpolated: bool) -> Rows {
    if interpolated {
        return build_rows_interpolated(grid, &[], u, y);
    }
    let n_h = grid.n_h();
    let mut mem: Memory<f64> = Memory::new(0.0, n_h + 3);
    // The rows only need the extrema, not the running sums.
    let no_e = |_: f64, _: f64| 0.0;
    let mut rows = Rows::empty(n_h, false, u.len());
    let mut m2: Vec<f64> = Vec::new();
    let mut seen: HashMap<Vec<u64>, usize> = HashMap::new();
    let mut key: Vec<u64> = Vec::with_capacity(n_h + 3);
    let mut scratch: Vec<(u32, f64)> = Vec::new();
    let mut prev_p = f64::NAN;
    let mut row = 0usize;
    // The samples of one run (the level unchanged, so the same row) are summed as
    // deviations from the run's first sample, then merged into the row's mean and
    // scatter (Chan, Golub & LeVeque): one division per run, not a dependent one per
    // sample, and the shifted sums keep the scatter exact to rounding.
    let mut run = Run::default();
    // The current level's input interval [thr[k−1], thr[k]): a sample inside it keeps
    // the level without quantizing (most do; the bounds are exactly quantize's).
    let thr = grid.thresholds();
    let (mut below, mut above) = (f64::NAN, f64::NAN);
    for (&x, &yt) in u.iter().zip(y) {
        if x >= below && x < above {
            run.add(yt);
            continue;
        }
        let level = grid.quantize(x);
        let k = level as usize;
        below = if k == 0 { f64::NEG_INFINITY } else { thr[k - 1] };
        above = if k == n_h { f64::INFINITY } else { thr[k] };
        let p = level as f64;
        if p != prev_p {
            run.merge_into(&mut rows, &mut m2, row);
            rows.levels.push(level);
            mem.apply(p, &no_e);
            prev_p = p;
            key.clear();
            key.extend(mem.turns().iter().map(|t| t.to_bits()));
            key.push(mem.current().to_bits());
            row = match seen.get(&key) {
                Some(&r) => r,
                None => {
                    let r = rows.weight.len();
                    seen.insert(key.clone(), r);
                    emit_row(mem.turns(), mem.current(), n_h, &mut scratch);
                    rows.push(&scratch, 1.0, 0.0, 0.0);
                    m2.push(0.0);
                    r
                }
            };
        }
        run.add(yt);
    }
    run.merge_into(&mut rows, &mut m2, row);
    rows.within_ss = m2.iter().sum();
    rows
}

/// A run of samples in one row: count, first sample, and the sums of the deviations
/// from it and of their squares.
#[derive(Default)]
struct Run {
    n: f64,
    y0: f64,
    s1: f64,
    s2: f64,
}

impl Run {
    #[inline]
    fn add(&mut self, y: f64) {
        if self.n == 0.0 {
            self.y0 = y;
        }
        let d = y - self.y0;
        self.n += 1.0;
        self.s1 += d;
        self.s2 += d * d;
    }

    /// Merge into row `r`'s count, mean and scatter, and start empty.
    fn merge_into(&mut self, rows: &mut Rows, m2: &mut [f64], r: usize) {
        if self.n == 0.0 {
            return;
        }
        let (na, nb) = (rows.weight[r], self.n);
        let mean_b = self.y0 + self.s1 / nb;
        let m2_b = (self.s2 - self.s1 * self.s1 / nb).max(0.0);
        let n = na + nb;
        let d = mean_b - rows.target[r];
        rows.weight[r] = n;
        rows.target[r] += d * nb / n;
        m2[r] += m2_b + d * d * na * nb / n;
        *self = Run::default();
    }
}

/// Moments of the samples sharing one interpolated group (same extrema, current input in
/// the same cell): the row is `(1 − λ) r_a + λ r_b` with λ the fractional position.
#[derive(Default, Clone, Copy)]
struct Moments {
    aa: f64,
    ab: f64,
    bb: f64,
    ay: f64,
    by: f64,
    yy: f64,
}

/// Interpolated rows, merged exactly. Within a group (same stored extrema, current input
/// in the same cell) every Everett value involving the current input is linear in its
/// fractional position λ, so each sample's row is `(1 − λ) r_a + λ r_b`. The group's
/// least-squares contribution is fixed by the 2×2 moment matrix M of (1 − λ, λ) and the
/// moments with y: with M = L Lᵀ, the two pseudo-rows `L₁₁ r_a + L₂₁ r_b` and `L₂₂ r_b`
/// with targets `L⁻¹ [Σ(1−λ)y, Σλy]` reproduce it to rounding.
/// The memory starts after `extrema` ([`memory_after`]).
pub(super) fn build_rows_interpolated(grid: &Grid, extrema: &[f64], u: &[f64], y: &[f64]) -> Rows {
    let n_h = grid.n_h();
    let mut mem = memory_after(grid, extrema);
    let no_e = |_: f64, _: f64| 0.0;
    let mut groups: Vec<(Vec<f64>, f64, usize)> = Vec::new(); // (turns, cur cell, count)
    let mut mom: Vec<Moments> = Vec::new();
    let mut seen: HashMap<Vec<u64>, usize> = HashMap::new();
    let mut key: Vec<u64> = Vec::with_capacity(n_h + 3);
    let mut prev_p = f64::NAN;
    let mut g = 0usize;
    let mut lam = 0.0;
    for (&x, &yt) in u.iter().zip(y) {
        let p = grid.position(x);
        if p != prev_p {
            mem.apply(p, &no_e);
            prev_p = p;
            let cell = (p as usize).min(n_h - 1);
            lam = p - cell as f64;
            key.clear();
            key.extend(mem.turns().iter().map(|t| t.to_bits()));
            key.push(cell as u64);
            g = match seen.get(&key) {
                Some(&k) => k,
                None => {
                    let k = groups.len();
                    seen.insert(key.clone(), k);
                    groups.push((mem.turns().to_vec(), cell as f64, 0));
                    mom.push(Moments::default());
                    k
                }
            };
        }
        let (a, b) = (1.0 - lam, lam);
        let m = &mut mom[g];
        m.aa += a * a;
        m.ab += a * b;
        m.bb += b * b;
        m.ay += a * yt;
        m.by += b * yt;
        m.yy += yt * yt;
        groups[g].2 += 1;
    }
    let mut rows = Rows::empty(n_h, true, u.len());
    let (mut ra, mut rb, mut row) = (Vec::new(), Vec::new(), Vec::new());
    let (mut r1, mut r2) = (Vec::new(), Vec::new());
    let mut explained = 0.0;
    let mut total_yy = 0.0;
    for ((turns, cell, count), m) in groups.iter().zip(&mom) {
        total_yy += m.yy;
        // The row is affine in λ on the whole cell, but at λ = 1 the current input would
        // be attributed to the next cell; so evaluate at two interior points and
        // extrapolate: r(0) = 2 r(1/3) − r(2/3), r(1) = 2 r(2/3) − r(1/3).
        emit_row(turns, *cell + 1.0 / 3.0, n_h, &mut r1);
        emit_row(turns, *cell + 2.0 / 3.0, n_h, &mut r2);
        combine(&r1, 2.0, &r2, -1.0, &mut ra);
        combine(&r2, 2.0, &r1, -1.0, &mut rb);
        // Cholesky of [[aa, ab], [ab, bb]].
        let l11 = m.aa.sqrt();
        let scale = (m.aa + m.bb).max(1e-300);
        if l11 > 1e-12 * scale.sqrt() {
            let l21 = m.ab / l11;
            let d = m.bb - l21 * l21;
            let z1 = m.ay / l11;
            combine(&ra, l11, &rb, l21, &mut row);
            rows.push(&row, l11 + l21, 1.0, z1);
            explained += z1 * z1;
            if d > 1e-12 * scale {
                let l22 = d.sqrt();
                let z2 = (m.by - l21 * z1) / l22;
                combine(&rb, l22, &[], 0.0, &mut row);
                rows.push(&row, l22, 1.0, z2);
                explained += z2 * z2;
            }
        } else {
            // Every sample at λ = 1 (the cell's upper level): one row r_b.
            let l = m.bb.sqrt();
            let z = m.by / l;
            combine(&rb, l, &[], 0.0, &mut row);
            rows.push(&row, l, 1.0, z);
            explained += z * z;
        }
        let _ = count;
    }
    rows.within_ss = (total_yy - explained).max(0.0);
    rows
}

/// `out = ca·a + cb·b` for sparse rows sorted by index without repeats (the offset
/// column scales with them): one pass merging the two.
pub(crate) fn combine(a: &[(u32, f64)], ca: f64, b: &[(u32, f64)], cb: f64, out: &mut Vec<(u32, f64)>) {
    out.clear();
    let (mut i, mut j) = (0, 0);
    while i < a.len() && j < b.len() {
        let ((ia, va), (ib, vb)) = (a[i], b[j]);
        if ia == ib {
            out.push((ia, ca * va + cb * vb));
            (i, j) = (i + 1, j + 1);
        } else if ia < ib {
            out.push((ia, ca * va));
            i += 1;
        } else {
            out.push((ib, cb * vb));
            j += 1;
        }
    }
    out.extend(a[i..].iter().map(|&(k, v)| (k, ca * v)));
    out.extend(b[j..].iter().map(|&(k, v)| (k, cb * v)));
}

/// Everett-coordinate coefficients of a state (stored extrema `t`, current input `cur`):
/// `2 S⁺ − E(n_h, 0)`.
pub(crate) fn emit_row(t: &[f64], cur: f64, n_h: usize, out: &mut Vec<(u32, f64)>) {
    out.clear();
    let n = t.len();
    let closed = if n % 2 == 1 { (n - 1) / 2 } else { (n - 2) / 2 };
    for k in 1..=closed {
        let (big, m_prev, m) = (t[2 * k - 1], t[2 * k - 2], t[2 * k]);
        expand(big, m_prev, 2.0, n_h, out);
        expand(big, m, -2.0, n_h, out);
    }
    if n % 2 == 1 {
        expand(cur, t[n - 1], 2.0, n_h, out);
    } else {
        expand(t[n - 1], t[n - 2], 2.0, n_h, out);
        expand(t[n - 1], cur, -2.0, n_h, out);
    }
    out.push((everett_var(n_h, 0) as u32, -1.0));
    sort_and_merge(out);
    out.retain(|e| e.1 != 0.0);
}

/// Sort sparse entries by index and sum duplicates, in place.
fn sort_and_merge(out: &mut Vec<(u32, f64)>) {
    out.sort_unstable_by_key(|e| e.0);
    let mut w = 0usize;
    for r in 0..out.len() {
        if w > 0 && out[w - 1].0 == out[r].0 {
            out[w - 1].1 += out[r].1;
        } else {
            out[w] = out[r];
            w += 1;
        }
    }
    out.truncate(w);
}

/// Add `c · E(a, b)` at continuous positions: bilinear weights on the four surrounding
/// Everett values; values with a <= b are identically zero and dropped.
#[inline]
fn expand(a: f64, b: f64, c: f64, n_h: usize, out: &mut Vec<(u32, f64)>) {
    let ia = (a as usize).min(n_h - 1);
    let ib = (b as usize).min(n_h - 1);
    let fa = a - ia as f64;
    let fb = b - ib as f64;
    for (da, wa) in [(0usize, 1.0 - fa), (1, fa)] {
        if wa == 0.0 {
            continue;
        }
        for (db, wb) in [(0usize, 1.0 - fb), (1, fb)] {
            if wb == 0.0 {
                continue;
            }
            let (aa, bb) = (ia + da, ib + db);
            if aa > bb {
                out.push((everett_var(aa, bb) as u32, c * wa * wb));
            }
        }
    }
    // Diagonal mass along the diagonal, not over the square (see `Everett::bilinear`):
    // w_kk = E(k + 1, k).
    if ia == ib && fb != 0.0 && fa != 1.0 {
        out.push((everett_var(ia + 1, ia) as u32, c * fb * (fa - 1.0)));
    }
}

/// Coefficients of the mass of cell (i, j) in Everett coordinates:
/// `w = E(j+1, i) − E(j, i) − E(j+1, i+1) + E(j, i+1)`, zero terms dropped.
pub fn mass_from_everett(i: usize, j: usize, out: &mut Vec<(usize, f64)>) {
    out.clear();
    out.push((everett_var(j + 1, i), 1.0));
    if j > i {
        out.push((everett_var(j, i), -1.0));
        out.push((everett_var(j + 1, i + 1), -1.0));
    }
    if j > i + 1 {
        out.push((everett_var(j, i + 1), 1.0));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::identify::testing::Rng;

    /// A sparse row sorted by index without repeats, about a third of `n` indices.
    fn row(rng: &mut Rng, n: u32) -> Vec<(u32, f64)> {
        let mut out = Vec::new();
        for i in 0..n {
            if rng.uniform() < 0.3 {
                out.push((i, rng.range(-1.0, 1.0)));
            }
        }
        out
    }

    #[test]
    fn combine_sums_two_sorted_rows_as_dense_vectors_do() {
        // Oracle: both rows scattered into dense vectors and summed; rows of any overlap,
        // either empty, the entries of each side's tail beyond the other's last index.
        let mut rng = Rng(0x5DEE_CE66_D1CE_4E5B);
        let mut out = Vec::new();
        for case in 0..200 {
            let n = 1 + (rng.uniform() * 40.0) as u32;
            let (a, b) = (row(&mut rng, n), if case % 7 == 0 { Vec::new() } else { row(&mut rng, n) });
            let (ca, cb) = (rng.range(-2.0, 2.0), rng.range(-2.0, 2.0));
            combine(&a, ca, &b, cb, &mut out);
            let mut dense = vec![None::<f64>; n as usize];
            for &(i, v) in &a {
                dense[i as usize] = Some(ca * v);
            }
            for &(i, v) in &b {
                dense[i as usize] = Some(dense[i as usize].map_or(cb * v, |s| s + cb * v));
            }
            let want: Vec<(u32, f64)> =
                dense.iter().enumerate().filter_map(|(i, v)| v.map(|v| (i as u32, v))).collect();
            assert_eq!(out, want, "case {case}");
        }
    }
}
