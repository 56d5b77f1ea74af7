//! Regression rows in Everett coordinates (MATH.md, "Identification without the dense
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
    /// Number of samples merged into each row.
    pub weight: Vec<f64>,
    /// Mean target of each row.
    pub target: Vec<f64>,
    /// Sum of squared deviations from the row means (unexplainable by any model).
    pub within_ss: f64,
    pub n_samples: usize,
}

impl Rows {
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
    /// `E(a, b)` covers the cells with i >= b and j < a. The offset column is implicit.
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

/// Build the merged rows of input `u` and target `y` (same length, finite).
/// `interpolated` selects the model whose masses are spread over their cells.
pub fn build_rows(grid: &Grid, u: &[f64], y: &[f64], interpolated: bool) -> Rows {
    let n_h = grid.n_h();
    let mut mem: Memory<f64> = Memory::new(0.0, n_h + 3);
    // The rows only need the extrema, not the running sums.
    let no_e = |_: f64, _: f64| 0.0;
    let mut rows = Rows {
        n_h,
        interpolated,
        indptr: vec![0],
        idx: Vec::new(),
        val: Vec::new(),
        weight: Vec::new(),
        target: Vec::new(),
        within_ss: 0.0,
        n_samples: u.len(),
    };
    let mut m2: Vec<f64> = Vec::new();
    let mut seen: HashMap<Vec<u64>, usize> = HashMap::new();
    let mut key: Vec<u64> = Vec::with_capacity(n_h + 3);
    let mut scratch: Vec<(u32, f64)> = Vec::new();
    let mut prev_p = f64::NAN;
    let mut row = 0usize;
    for (&x, &yt) in u.iter().zip(y) {
        let p = if interpolated { grid.position(x) } else { grid.quantize(x) as f64 };
        if p != prev_p {
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
                    emit_row(&mem, n_h, &mut scratch);
                    for &(i, v) in &scratch {
                        rows.idx.push(i);
                        rows.val.push(v);
                    }
                    rows.indptr.push(rows.idx.len());
                    rows.weight.push(0.0);
                    rows.target.push(0.0);
                    m2.push(0.0);
                    r
                }
            };
        }
        // Welford update of the row's mean and scatter.
        let w = rows.weight[row] + 1.0;
        let d = yt - rows.target[row];
        rows.weight[row] = w;
        rows.target[row] += d / w;
        m2[row] += d * (yt - rows.target[row]);
    }
    rows.within_ss = m2.iter().sum();
    rows
}

/// Everett-coordinate coefficients of the current state: `2 S⁺ − E(n_h, 0)`.
fn emit_row(mem: &Memory<f64>, n_h: usize, out: &mut Vec<(u32, f64)>) {
    out.clear();
    let t = mem.turns();
    let n = t.len();
    let cur = mem.current();
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
    out.sort_unstable_by_key(|e| e.0);
    // Merge duplicates in place.
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
    out.retain(|e| e.1 != 0.0);
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
