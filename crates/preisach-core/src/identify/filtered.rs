//! Masses fitted behind linear dynamics (`docs/method/diagnosis.md`:
//! adding an effect means refitting the hysteresis with it).
//!
//! ```text
//!   minimise  Σ_t ω_t (z_t − (L h)_t)²
//!   over the masses w >= 0 and the offset c of the interpolated model, h = H_w[u],
//! ```
//!
//! where `L` is a cascade of linear blocks (creep, modes, low-pass filters: their
//! continuous descriptions, `blocks::lti`) sampled by the first-order hold, exact for an
//! input linear between samples (a chain's `predict`). `h` is linear in (Everett values, offset), so
//! this is a least-squares problem, but `L` mixes every sample with its past: the rows no
//! longer merge and the dense problem (samples × cells) is out of reach.
//!
//! The obvious shortcut, correcting the target with the previous masses
//! (`z − (L − 1) h_prev`) and refitting, is a fixed-point iteration that diverges for
//! lightly damped modes (`L − 1` has gain 1/(2ζ) at resonance and a phase beyond −90°
//! above it: a 633 Hz, ζ = 0.014 mode took the training RMSE from 0.07 to 0.25 in six
//! rounds). Instead:
//!
//! 1. the unconstrained optimum by conjugate gradients on the normal equations
//!    `Bᵀ Lᵀ Ω L B x = Bᵀ Lᵀ Ω z` in Everett coordinates (`B`: per-sample rows, applied
//!    through the groups of samples that share a staircase and a cell, or multiplied out
//!    on the averaged windows when that is smaller; `L`, `Lᵀ`: the
//!    block recursions forwards and backwards), preconditioned by the unfiltered Gram
//!    matrix `Bᵀ Ω B` (sparse, factored once): `L ≈ 1` where the hysteresis output lives,
//!    so only the few directions that see the dynamics' resonance or roll-off cost
//!    iterations (20–60 on the diagnoser's records);
//! 2. the masses >= 0: the NNLS fit of the model to that optimum's output `h*` (the
//!    projection onto non-negative masses in the unfiltered metric; see `projection`).

use std::sync::{Arc, Mutex};

use clarabel::algebra::CscMatrix;
use clarabel::qdldl::{QDLDLFactorisation, QDLDLSettingsBuilder};

use super::projection::{check_tie, Projection};
use super::qp::{csc_upper, key, Upper, DENSE_SUM_MAX};
use super::rows::{combine, emit_row, memory_after};
use super::FitReport;
use crate::blocks::lti::{Discretization, Filter, Lti};
use crate::error::{check_finite, check_scalar, check_signal, PreisachError, Result};
use crate::grid::Grid;
use crate::model::PreisachModel;

/// A sparse matrix compressed by rows: row r is entries `ptr[r]..ptr[r + 1]` of
/// (column, value). The values are numbers, or pairs (two rows with one pattern). The
/// kernels of the conjugate gradients read it row by row, summing in registers; a
/// product with the transpose reads [`Sparse::transpose`], built once, so no kernel
/// scatters.
#[derive(Debug, Clone)]
struct Sparse<V> {
    ptr: Vec<usize>,
    col: Vec<u32>,
    val: Vec<V>,
}

/// Entries holding the values of two rows.
type Pairs = Sparse<[f64; 2]>;

impl<V: Copy + Default> Sparse<V> {
    fn new() -> Self {
        Sparse { ptr: vec![0], col: Vec::new(), val: Vec::new() }
    }

    #[inline]
    fn n_rows(&self) -> usize {
        self.ptr.len() - 1
    }

    #[inline]
    fn nnz(&self) -> usize {
        self.col.len()
    }

    fn clear(&mut self) {
        self.ptr.truncate(1);
        self.col.clear();
        self.val.clear();
    }

    /// Close the current row (the entries pushed since the last call).
    fn end_row(&mut self) {
        self.ptr.push(self.col.len());
    }

    #[inline]
    fn row(&self, r: usize) -> (&[u32], &[V]) {
        let (s, e) = (self.ptr[r], self.ptr[r + 1]);
        (&self.col[s..e], &self.val[s..e])
    }

    /// The same entries compressed by columns (`n_cols` of them; rows in increasing
    /// order within each).
    fn transpose(&self, n_cols: usize, out: &mut Sparse<V>) {
        out.ptr.clear();
        out.ptr.resize(n_cols + 1, 0);
        for &c in &self.col {
            out.ptr[c as usize + 1] += 1;
        }
        for c in 0..n_cols {
            out.ptr[c + 1] += out.ptr[c];
        }
        let nnz = self.col.len();
        out.col.clear();
        out.col.resize(nnz, 0);
        out.val.clear();
        out.val.resize(nnz, V::default());
        let mut next = out.ptr[..n_cols].to_vec();
        for r in 0..self.n_rows() {
            let (cols, vals) = self.row(r);
            for (&c, &v) in cols.iter().zip(vals) {
                let k = &mut next[c as usize];
                out.col[*k] = r as u32;
                out.val[*k] = v;
                *k += 1;
            }
        }
    }
}

impl Sparse<f64> {
    /// `y = A x`.
    #[inline]
    fn mul(&self, x: &[f64], y: &mut [f64]) {
        for (r, o) in y.iter_mut().enumerate() {
            let (cols, vals) = self.row(r);
            *o = sum4(cols, vals, |&i, &v| v * x[i as usize]);
        }
    }
}

impl Pairs {
    /// `y = A x`, both rows of each pair.
    #[inline]
    fn mul(&self, x: &[f64], y: &mut [[f64; 2]]) {
        for (r, o) in y.iter_mut().enumerate() {
            let (cols, vals) = self.row(r);
            // Two partial sums per row (a row's sum waits on each addition otherwise).
            let (mut s, mut t) = ([0.0; 2], [0.0; 2]);
            let (c2, v2) = (cols.chunks_exact(2), vals.chunks_exact(2));
            let (cr, vr) = (c2.remainder(), v2.remainder());
            for (c, v) in c2.zip(v2) {
                let (xa, xb) = (x[c[0] as usize], x[c[1] as usize]);
                s[0] += v[0][0] * xa;
                s[1] += v[0][1] * xa;
                t[0] += v[1][0] * xb;
                t[1] += v[1][1] * xb;
            }
            for (&i, v) in cr.iter().zip(vr) {
                let xi = x[i as usize];
                s[0] += v[0] * xi;
                s[1] += v[1] * xi;
            }
            *o = [s[0] + t[0], s[1] + t[1]];
        }
    }
}

/// `Σ f(c_k, v_k)` over a sparse row in four partial sums: the additions of one row
/// overlap instead of each waiting on the last.
#[inline(always)]
fn sum4<V>(cols: &[u32], vals: &[V], f: impl Fn(&u32, &V) -> f64) -> f64 {
    let mut s = [0.0; 4];
    let (c4, v4) = (cols.chunks_exact(4), vals.chunks_exact(4));
    let (cr, vr) = (c4.remainder(), v4.remainder());
    for (c, v) in c4.zip(v4) {
        for k in 0..4 {
            s[k] += f(&c[k], &v[k]);
        }
    }
    for (c, v) in cr.iter().zip(vr) {
        s[0] += f(c, v);
    }
    (s[0] + s[1]) + (s[2] + s[3])
}

/// Append the union of two sorted sparse rows as pairs (a missing entry is 0).
fn push_pair_row(a: &[(u32, f64)], b: &[(u32, f64)], out: &mut Pairs) {
    let (mut i, mut j) = (0, 0);
    while i < a.len() || j < b.len() {
        let ka = a.get(i).map_or(u32::MAX, |e| e.0);
        let kb = b.get(j).map_or(u32::MAX, |e| e.0);
        let k = ka.min(kb);
        let mut v = [0.0; 2];
        if ka == k {
            v[0] = a[i].1;
            i += 1;
        }
        if kb == k {
            v[1] = b[j].1;
            j += 1;
        }
        out.col.push(k);
        out.val.push(v);
    }
    out.end_row();
}

/// The per-sample regression of the interpolated model in Everett coordinates: sample
/// t's row is `(1 − λ_t) r_a + λ_t r_b` (plus 1 for the offset), with `r_a`, `r_b` the
/// rows of its group (same stored extrema, current input in the same cell) at the cell's
/// two levels (see `rows::build_rows_interpolated`).
///
/// The fit may run on windows of `stride` samples averaged (an output sample is the mean
/// of its window, the last partial window dropped): the average commutes with the linear
/// blocks, so a chain fitted to the averaged record is the chain of the full-rate one,
/// and an averaged row keeps where in the window a step of the input happened (point
/// decimation moves it to a sample and biases every timing the dynamics carry).
/// The groups and each sample's group are the same for every session on the input
/// (shared: [`Behind::fork`]); the windows' mixtures depend on the delay of each solve,
/// and are shared too while two sessions are at the same delay ([`Mixture`]).
#[derive(Clone)]
struct SampleRows {
    n_q: usize,
    group: Arc<Vec<u32>>,
    lam: Arc<Vec<f64>>,
    /// Group g's rows (r_a, r_b) on the union of their Everett variables (row g), and
    /// the same by variable (row i: the groups that see variable i).
    rows: Arc<Pairs>,
    rows_t: Arc<Pairs>,
    stride: usize,
    /// The mixtures at the delay of the last solve, and at delay 0 (every session's
    /// start, and where a search over the delay returns).
    mixture: Arc<Mixture>,
    at_zero: Arc<Mixture>,
    spare: Spare,
    /// Scratch per group: the values of r_a and r_b.
    vab: Vec<[f64; 2]>,
}

/// A mixture's buffers kept for the next delay's build: a session's own (a copy starts
/// without, and allocates them at its first delay other than 0).
#[derive(Default)]
struct Spare(Option<Mixture>);

impl Clone for Spare {
    fn clone(&self) -> Self {
        Spare(None)
    }
}

/// The output samples (averaged windows) at one delay: read-only once built, so the
/// sessions at that delay share one copy (on an input recorded with noise, tens of MB
/// for every problem's sessions).
#[derive(Clone)]
struct Mixture {
    /// Delay (in input samples) the mixture holds.
    delay: f64,
    /// Output samples as mixtures of groups: row k holds (group, weights of r_a and
    /// r_b); and the same by group (row g: (output sample, weights)).
    mix: Pairs,
    mix_t: Pairs,
    /// `B` itself on the output samples (without the offset) and its transpose, when
    /// they take fewer bytes than the factors (windows of several samples: a window's
    /// groups share most of their variables); empty otherwise.
    direct: Sparse<f64>,
    direct_t: Sparse<f64>,
}

impl Mixture {
    fn empty() -> Self {
        Mixture {
            delay: f64::NAN,
            mix: Pairs::new(),
            mix_t: Pairs::new(),
            direct: Sparse::new(),
            direct_t: Sparse::new(),
        }
    }
}

impl SampleRows {
    fn new(grid: &Grid, extrema: &[f64], u: &[f64], stride: usize) -> Self {
        use std::collections::HashMap;
        let n_h = grid.n_h();
        let mut mem = memory_after(grid, extrema);
        let no_e = |_: f64, _: f64| 0.0;
        let mut seen: HashMap<Vec<u64>, u32> = HashMap::new();
        let mut key_buf: Vec<u64> = Vec::with_capacity(n_h + 3);
        let (mut r1, mut r2, mut ra, mut rb) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        let (mut group, mut lam_of) = (Vec::with_capacity(u.len()), Vec::with_capacity(u.len()));
        let mut rows = Pairs::new();
        let mut prev_p = f64::NAN;
        let (mut g, mut lam) = (0u32, 0.0);
        for &x in u {
            let p = grid.position(x);
            if p != prev_p {
                mem.apply(p, &no_e);
                prev_p = p;
                let cell = (p as usize).min(n_h - 1);
                lam = p - cell as f64;
                key_buf.clear();
                key_buf.extend(mem.turns().iter().map(|t| t.to_bits()));
                key_buf.push(cell as u64);
                g = match seen.get(&key_buf) {
                    Some(&k) => k,
                    None => {
                        let k = rows.n_rows() as u32;
                        seen.insert(key_buf.clone(), k);
                        // Affine in λ on the cell: evaluate inside and extrapolate.
                        emit_row(mem.turns(), cell as f64 + 1.0 / 3.0, n_h, &mut r1);
                        emit_row(mem.turns(), cell as f64 + 2.0 / 3.0, n_h, &mut r2);
                        combine(&r1, 2.0, &r2, -1.0, &mut ra);
                        combine(&r2, 2.0, &r1, -1.0, &mut rb);
                        push_pair_row(&ra, &rb, &mut rows);
                        k
                    }
                };
            }
            group.push(g);
            lam_of.push(lam);
        }
        let mut rows_t = Pairs::new();
        rows.transpose(grid.n_q(), &mut rows_t);
        let n_g = rows.n_rows();
        let mut sr = SampleRows {
            n_q: grid.n_q(),
            group: Arc::new(group),
            lam: Arc::new(lam_of),
            rows: Arc::new(rows),
            rows_t: Arc::new(rows_t),
            stride: stride.max(1),
            mixture: Arc::new(Mixture::empty()),
            at_zero: Arc::new(Mixture::empty()),
            spare: Spare::default(),
            vab: vec![[0.0; 2]; n_g],
        };
        let mut zero = Mixture::empty();
        sr.build_mixture(0.0, &mut zero);
        sr.at_zero = Arc::new(zero);
        sr.mixture = Arc::clone(&sr.at_zero);
        sr
    }

    /// Hold the output mixtures for the hysteresis output delayed by `delay` input
    /// samples (see [`SampleRows::build_mixture`]): delay 0's kept from the start, any
    /// other built anew, in the buffers of the last one this session held alone.
    fn set_delay(&mut self, delay: f64) {
        if delay == self.mixture.delay {
            return;
        }
        let last = std::mem::replace(&mut self.mixture, Arc::clone(&self.at_zero));
        if let Ok(m) = Arc::try_unwrap(last) {
            self.spare.0 = Some(m);
        }
        if delay == 0.0 {
            return;
        }
        let mut m = self.spare.0.take().unwrap_or_else(Mixture::empty);
        self.build_mixture(delay, &mut m);
        self.mixture = Arc::new(m);
    }

    /// Build into `m` the output mixtures for the hysteresis output delayed by `delay`
    /// input samples (linear interpolation between samples, the value at rest before the
    /// start: what the chain's delay block does to its input, and a delay commutes with
    /// the linear blocks). O(samples); nothing else changes.
    fn build_mixture(&self, delay: f64, m: &mut Mixture) {
        m.delay = delay;
        let s = self.stride;
        let n = self.group.len();
        let inv = 1.0 / s as f64;
        let mix = &mut m.mix;
        mix.clear();
        let add = |mix: &mut Pairs, start: usize, j: usize, w: f64| {
            if w == 0.0 {
                return;
            }
            let (g, l) = (self.group[j], self.lam[j]);
            match mix.col[start..].iter().position(|&e| e == g) {
                Some(e) => {
                    let v = &mut mix.val[start + e];
                    v[0] += (1.0 - l) * w;
                    v[1] += l * w;
                }
                None => {
                    mix.col.push(g);
                    mix.val.push([(1.0 - l) * w, l * w]);
                }
            }
        };
        for k in 0..n / s {
            let start = mix.col.len();
            for i in k * s..(k + 1) * s {
                let x = i as f64 - delay;
                if x <= 0.0 {
                    add(mix, start, 0, inv);
                    continue;
                }
                let j0 = x.floor() as usize;
                let f = x - j0 as f64;
                add(mix, start, j0.min(n - 1), (1.0 - f) * inv);
                if f > 0.0 {
                    add(mix, start, (j0 + 1).min(n - 1), f * inv);
                }
            }
            mix.end_row();
        }
        m.mix.transpose(self.vab.len(), &mut m.mix_t);
        self.build_direct(m, (self.rows.nnz() + m.mix.nnz()) * 20 / 12);
    }

    /// Multiply the mixtures of `m` out into `B` when it is smaller than its factors (a
    /// value per entry against a pair, so 12 bytes against 20; the build stops once `B`
    /// outgrows that: `limit` entries).
    fn build_direct(&self, m: &mut Mixture, limit: usize) {
        let Mixture { mix, direct: d, direct_t, .. } = m;
        d.clear();
        direct_t.clear();
        // A window's row has at least the entries of its longest group's: give up early
        // when that already exceeds the limit (windows of one group, a smooth input).
        let rows = &self.rows;
        let longest = |k: usize| mix.row(k).0.iter().map(|&g| rows.row(g as usize).0.len()).max();
        if (0..mix.n_rows()).filter_map(longest).sum::<usize>() > limit {
            return;
        }
        let mut acc = vec![0.0; self.n_q];
        let mut seen = vec![false; self.n_q];
        let mut touched: Vec<u32> = Vec::new();
        for k in 0..mix.n_rows() {
            let (gs, ws) = mix.row(k);
            for (&g, w) in gs.iter().zip(ws) {
                let (cols, vals) = rows.row(g as usize);
                for (&i, v) in cols.iter().zip(vals) {
                    if !seen[i as usize] {
                        seen[i as usize] = true;
                        touched.push(i);
                    }
                    acc[i as usize] += w[0] * v[0] + w[1] * v[1];
                }
            }
            touched.sort_unstable();
            for &i in &touched {
                d.col.push(i);
                d.val.push(acc[i as usize]);
                acc[i as usize] = 0.0;
                seen[i as usize] = false;
            }
            touched.clear();
            d.end_row();
            if d.nnz() > limit {
                d.clear();
                return;
            }
        }
        d.transpose(self.n_q, direct_t);
    }

    /// Whether the products go through `B` itself (see [`SampleRows::build_direct`]).
    fn is_direct(&self) -> bool {
        self.mixture.direct.n_rows() > 0
    }

    fn n_groups(&self) -> usize {
        self.vab.len()
    }

    fn n_out(&self) -> usize {
        self.mixture.mix.n_rows()
    }

    /// The values of every group's rows r_a and r_b at `x`.
    fn group_values(&mut self, x: &[f64]) {
        self.rows.mul(x, &mut self.vab);
    }

    /// `h = B x` on the output samples (x: Everett values, then the offset).
    fn forward(&mut self, x: &[f64], h: &mut [f64]) {
        let c = x[self.n_q];
        if self.is_direct() {
            self.mixture.direct.mul(x, h);
            h.iter_mut().for_each(|o| *o += c);
            return;
        }
        self.group_values(x);
        for (k, o) in h.iter_mut().enumerate() {
            let (gs, ws) = self.mixture.mix.row(k);
            let mut v = c;
            for (&g, w) in gs.iter().zip(ws) {
                let a = self.vab[g as usize];
                v += w[0] * a[0] + w[1] * a[1];
            }
            *o = v;
        }
    }

    /// `h = B x` on every input sample.
    fn forward_fine(&mut self, x: &[f64], h: &mut [f64]) {
        self.group_values(x);
        let c = x[self.n_q];
        for ((o, &g), &l) in h.iter_mut().zip(self.group.iter()).zip(self.lam.iter()) {
            let [a, b] = self.vab[g as usize];
            *o = (1.0 - l) * a + l * b + c;
        }
    }

    /// `x = Bᵀ v` (v on the output samples).
    fn adjoint(&mut self, v: &[f64], x: &mut [f64]) {
        x[self.n_q] = v.iter().sum();
        if self.is_direct() {
            self.mixture.direct_t.mul(v, &mut x[..self.n_q]);
            return;
        }
        self.mixture.mix_t.mul(v, &mut self.vab);
        let vab = &self.vab;
        for (i, o) in x[..self.n_q].iter_mut().enumerate() {
            let (gs, vals) = self.rows_t.row(i);
            *o = sum4(gs, vals, |&g, c| {
                let a = vab[g as usize];
                c[0] * a[0] + c[1] * a[1]
            });
        }
    }

    /// Upper-triangular triplets of (nearly) `Bᵀ B` on the output samples (the offset is
    /// variable n_q): per group the entries are `wa ã + wb b̃` with ã = r_a + e_offset,
    /// and the 2×2 moment matrix of (wa, wb) gives the group's contribution. (Cross terms
    /// between groups sharing an averaged window are left out: a preconditioner only.)
    /// Summed in a packed triangle when it holds at most [`DENSE_SUM_MAX`] entries:
    /// a noisy input makes a group per sample, whose products (millions) would
    /// otherwise be sorted to be summed.
    fn gram(&self) -> Vec<(u64, f64)> {
        self.gram_with(DENSE_SUM_MAX)
    }

    fn gram_with(&self, dense_max: usize) -> Vec<(u64, f64)> {
        let mut sums = Upper::new(self.n_q + 1, dense_max, None);
        self.gram_products(|i, j, v| sums.add(i, j, v));
        sums.into_triplets()
    }

    /// Every product of the Gram matrix's upper triangle, as (variable, variable, value).
    fn gram_products(&self, mut emit: impl FnMut(usize, usize, f64)) {
        let n_g = self.n_groups();
        let mut mom = vec![[0.0f64; 3]; n_g];
        let mix = &self.mixture.mix;
        for (&g, w) in mix.col.iter().zip(&mix.val) {
            let m = &mut mom[g as usize];
            m[0] += w[0] * w[0];
            m[1] += w[0] * w[1];
            m[2] += w[1] * w[1];
        }
        let off = self.n_q as u32;
        let (mut a, mut b, mut p) = (Vec::new(), Vec::new(), Vec::new());
        for (g, m) in mom.iter().enumerate() {
            let (cols, vals) = self.rows.row(g);
            a.clear();
            a.extend(cols.iter().zip(vals).map(|(&i, v)| (i, v[0])));
            a.push((off, 1.0));
            b.clear();
            b.extend(cols.iter().zip(vals).map(|(&i, v)| (i, v[1])));
            b.push((off, 1.0));
            let scale = (m[0] + m[2]).max(1e-300);
            let l11 = m[0].sqrt();
            let mut pseudo: [(f64, f64); 2] = [(0.0, 0.0); 2];
            if l11 > 1e-12 * scale.sqrt() {
                let l21 = m[1] / l11;
                let d = m[2] - l21 * l21;
                pseudo[0] = (l11, l21);
                if d > 1e-12 * scale {
                    pseudo[1] = (0.0, d.sqrt());
                }
            } else {
                pseudo[0] = (0.0, m[2].sqrt());
            }
            for &(ca, cb) in &pseudo {
                if ca == 0.0 && cb == 0.0 {
                    continue;
                }
                combine(&a, ca, &b, cb, &mut p);
                for (k, &(i, vi)) in p.iter().enumerate() {
                    for &(j, vj) in &p[k..] {
                        emit(i as usize, j as usize, vi * vj);
                    }
                }
            }
        }
    }
}

/// `M⁻¹` for the conjugate gradients: sparse LDLᵀ of the Gram matrix plus a ridge.
/// Variables no sample observes (empty rows) are masked out: the ridge alone would
/// blow rounding errors in them up by its inverse.
struct Precond {
    fact: QDLDLFactorisation<f64>,
    dead: Vec<usize>,
    /// The factored matrix (upper triangle, ridge added), for [`Precond::refactored`]
    /// (shared by the copies).
    mat: Arc<CscMatrix<f64>>,
}

impl Precond {
    fn new(dim: usize, trip: Vec<(u64, f64)>) -> Result<Self> {
        let CscMatrix { colptr, rowval, nzval: mut val, .. } = csc_upper(dim, trip)?;
        // The diagonal is the last entry of each column (upper triangle, sorted rows).
        let dmax = (0..dim).map(|c| val[colptr[c + 1] - 1]).fold(0.0f64, f64::max).max(1e-300);
        let dead: Vec<usize> = (0..dim).filter(|&c| val[colptr[c + 1] - 1] <= 1e-14 * dmax).collect();
        for c in 0..dim {
            val[colptr[c + 1] - 1] += 1e-10 * dmax;
        }
        Self::factored(Arc::new(CscMatrix::new(dim, dim, colptr, rowval, val)), dead)
    }

    fn factored(mat: Arc<CscMatrix<f64>>, dead: Vec<usize>) -> Result<Self> {
        let settings = QDLDLSettingsBuilder::default()
            .Dsigns(vec![1i8; mat.n])
            .build()
            .map_err(|e| PreisachError::Solver(format!("qdldl settings: {e}")))?;
        let fact = QDLDLFactorisation::new(&mat, Some(settings))
            .map_err(|e| PreisachError::Solver(format!("qdldl: {e:?}")))?;
        Ok(Precond { fact, dead, mat })
    }

    /// The same preconditioner with a workspace of its own (the kept matrix factored
    /// again: the Gram matrix's products over every sample are not summed again).
    fn refactored(&self) -> Result<Self> {
        Self::factored(Arc::clone(&self.mat), self.dead.clone())
    }

    fn solve(&mut self, b: &[f64], x: &mut [f64]) {
        x.copy_from_slice(b);
        for &i in &self.dead {
            x[i] = 0.0;
        }
        self.fact.solve(x);
        for &i in &self.dead {
            x[i] = 0.0;
        }
    }
}

/// A fit problem on one input: the per-sample rows and the preconditioner are built
/// once, then [`Behind::solve`] fits any target behind any cascade (a profile over an
/// effect's parameters costs conjugate-gradient iterations only, warm-started from the
/// previous solution). Extra linear terms with free coefficients: `pre` columns pass
/// through the dynamics with the hysteresis output (a rate branch), `post` columns are
/// added after them (drift offsets).
pub struct Behind {
    rows: SampleRows,
    pre: Precond,
    /// Last unconstrained solution (Everett values, offset, extra coefficients), for warm
    /// starts (used when the number of extra terms matches).
    last: Option<Vec<f64>>,
    /// The input, its grid and the masses' projection on it (see [`ProjectionHandle`]).
    input: ProjectionHandle,
}

/// What the sessions on one input share: the input, the grid, the projection's
/// smoothness weight ([`Projection::new`]) and the projection itself, built once, by the
/// first [`Behind::project`] of any of them (the others wait for it rather than build
/// their own), then only read.
#[derive(Clone)]
pub struct ProjectionHandle {
    grid: Grid,
    /// The memory at the input's start ([`Behind::after`]).
    extrema: Arc<Vec<f64>>,
    u: Arc<Vec<f64>>,
    tie: f64,
    slot: Arc<Mutex<Option<Arc<Projection>>>>,
}

/// Unconstrained optimum of [`Behind::solve`].
#[derive(Debug, Clone)]
pub struct BehindSolution {
    /// Everett values then the offset (the hysteresis part).
    pub x: Vec<f64>,
    /// Coefficients of the `pre` then the `post` columns.
    pub extra: Vec<f64>,
    pub iterations: usize,
    /// Final relative (preconditioned) residual of the normal equations.
    pub residual: f64,
    /// Weighted RMSE of the chain output against the target.
    pub rmse: f64,
    /// The fit gave up above [`Stop::above`]: `rmse` is where it stopped, above the
    /// optimum's.
    pub gave_up: bool,
}

/// When [`Behind::solve`] stops.
#[derive(Debug, Clone, Copy)]
pub struct Stop {
    /// Stop when two iterations in a row lower the sum of squares by less than this
    /// fraction of it.
    pub tol: f64,
    pub max_iter: usize,
    /// Give up a fit that cannot get below this weighted RMSE: once its last ten
    /// iterations' average decrease, kept up for every iteration
    /// left, would still leave it above (the conjugate gradients' decrease slows, so
    /// the extrapolation overstates what is left). A search that compares chains with
    /// the chain without its effect needs no more of a fit that stays worse.
    pub above: Option<f64>,
}

impl Stop {
    pub fn new(tol: f64, max_iter: usize) -> Self {
        Stop { tol, max_iter, above: None }
    }
}

/// The give-up rule of [`Stop::above`] on the running weighted sum of squares.
struct Ceiling {
    sse: f64,
    past: [f64; Ceiling::WINDOW],
}

impl Ceiling {
    const WINDOW: usize = 10;

    /// Records the sum of squares after iteration `it` (from 1; `past` starts filled
    /// with the starting point's); true when the fit cannot get below the ceiling in
    /// the `left` iterations that remain.
    fn hopeless(&mut self, it: usize, sse: f64, left: usize) -> bool {
        let slot = it % Self::WINDOW;
        let out = it >= Self::WINDOW && {
            let rate = (self.past[slot] - sse) / Self::WINDOW as f64;
            sse - rate.max(0.0) * left as f64 > self.sse
        };
        self.past[slot] = sse;
        out
    }
}

/// Extra columns, weights and delay of one solve.
#[derive(Debug, Clone, Copy, Default)]
pub struct Terms<'a> {
    pub omega: Option<&'a [f64]>,
    /// Columns added to the hysteresis output before the dynamics (given per output
    /// sample, already delayed like it).
    pub pre: &'a [&'a [f64]],
    /// Columns added after the dynamics.
    pub post: &'a [&'a [f64]],
    /// Delay of the hysteresis output, in input samples (>= 0).
    pub delay: f64,
}

impl Behind {
    /// Rows of the interpolated model on `grid` for input `u`; the fit runs on windows
    /// of `stride` samples averaged (targets, weights and columns are then given per
    /// window, `u.len() / stride` of them; see [`SampleRows`]).
    pub fn new(u: &[f64], n_h: usize, u_range: (f64, f64), stride: usize) -> Result<Self> {
        Behind::after(&[], u, n_h, u_range, stride)
    }

    /// [`Behind::new`] for a record that starts after a history nobody recorded: the
    /// hysteresis memory at its start is the one after the input went through `extrema`
    /// (alternating extrema, input units; as the hysteresis block's `initial_extrema`).
    /// The masses' projection counts from the same memory.
    pub fn after(extrema: &[f64], u: &[f64], n_h: usize, u_range: (f64, f64), stride: usize) -> Result<Self> {
        check_signal("u", u)?;
        check_finite("initial_extrema", extrema)?;
        if stride < 1 || stride > u.len() {
            return Err(PreisachError::invalid("stride", format!("must be in 1..={}, got {stride}", u.len())));
        }
        let grid = Grid::new(u_range.0, u_range.1, n_h)?;
        let rows = SampleRows::new(&grid, extrema, u, stride);
        let dim = grid.n_q() + 1;
        // Preconditioner: the unfiltered, unweighted Gram matrix (a small ridge covers
        // Everett values no sample observes).
        let mut trip = rows.gram();
        trip.extend((0..dim).map(|i| (key(i, i), 0.0)));
        let pre = Precond::new(dim, trip)?;
        let input = ProjectionHandle {
            grid,
            extrema: Arc::new(extrema.to_vec()),
            u: Arc::new(u.to_vec()),
            tie: 0.0,
            slot: Arc::default(),
        };
        Ok(Behind { rows, pre, last: None, input })
    }

    /// A session of the same problem for another thread: the staircase groups and rows
    /// shared, the windows' mixtures shared until either session moves to another delay,
    /// the preconditioner's factorization its own, a cold start, the projection shared.
    /// It solves bit for bit as a session from [`Behind::new`] does, without the rows and
    /// Gram matrix built again.
    pub fn fork(&self) -> Result<Self> {
        Ok(Behind { rows: self.rows.clone(), pre: self.pre.refactored()?, last: None, input: self.input.clone() })
    }

    /// The smoothness weight of the masses' projection ([`Projection::new`]; 0 by
    /// default: the plain projection, polished).
    pub fn set_tie(&mut self, tie: f64) -> Result<()> {
        check_tie(tie)?;
        if tie != self.input.tie {
            self.input.tie = tie;
            self.input.slot = Arc::default();
        }
        Ok(())
    }

    /// What another session needs to share this one's projection
    /// ([`Behind::share_projection`]).
    pub fn projection_handle(&self) -> ProjectionHandle {
        self.input.clone()
    }

    /// Share the projection of the session `other` came from (one input, grid and
    /// smoothness weight: its rows and Hessian are built once for every session on the
    /// input, whatever their stride).
    pub fn share_projection(&mut self, other: &ProjectionHandle) -> Result<()> {
        let me = &self.input;
        if me.grid != other.grid
            || me.tie != other.tie
            || me.extrema != other.extrema
            || !(Arc::ptr_eq(&me.u, &other.u) || me.u == other.u)
        {
            return Err(PreisachError::invalid(
                "share",
                "another input, start, grid or smoothness weight: its projection is not this session's",
            ));
        }
        self.input = other.clone();
        Ok(())
    }

    /// The shared projection, built here if no session has built it yet.
    fn projection(&self) -> Result<Arc<Projection>> {
        let mut slot = self.input.slot.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(p) = slot.as_ref() {
            return Ok(Arc::clone(p));
        }
        let h = &self.input;
        let p = Arc::new(Projection::after(&h.grid, &h.extrema, &h.u, h.tie)?);
        *slot = Some(Arc::clone(&p));
        Ok(p)
    }

    /// Input samples per output sample (the averaging window).
    pub fn stride(&self) -> usize {
        self.rows.stride
    }

    /// Number of output samples (averaged windows): the length of targets and columns.
    pub fn n_samples(&self) -> usize {
        self.rows.n_out()
    }

    fn check_terms(&mut self, z: &[f64], t: &Terms) -> Result<()> {
        check_scalar("delay", t.delay)?;
        if t.delay < 0.0 {
            return Err(PreisachError::invalid("delay", format!("must be >= 0, got {}", t.delay)));
        }
        self.rows.set_delay(t.delay);
        let n = self.rows.n_out();
        check_signal("z", z)?;
        if z.len() != n {
            return Err(PreisachError::invalid("z", format!("length {} does not match u (length {n})", z.len())));
        }
        if let Some(w) = t.omega {
            if w.len() != n {
                return Err(PreisachError::invalid(
                    "weights",
                    format!("length {} does not match u (length {n})", w.len()),
                ));
            }
            check_signal("weights", w)?;
            if let Some(i) = w.iter().position(|&v| v < 0.0) {
                return Err(PreisachError::invalid("weights", format!("negative weight {} at index {i}", w[i])));
            }
        }
        for (name, cols) in [("pre", t.pre), ("post", t.post)] {
            for c in cols {
                if c.len() != n {
                    return Err(PreisachError::invalid(
                        name,
                        format!("column length {} does not match u (length {n})", c.len()),
                    ));
                }
                check_signal(name, c)?;
            }
        }
        Ok(())
    }

    /// The unconstrained least-squares optimum of `Σ ω (z − L(B x + Σ a_k pre_k) − Σ b_k post_k)²`
    /// by preconditioned conjugate gradients (see the module documentation), stopped by
    /// `stop`.
    pub fn solve(
        &mut self,
        z: &[f64],
        lti: &mut Filter,
        terms: &Terms,
        stop: &Stop,
        warm: bool,
    ) -> Result<BehindSolution> {
        self.check_terms(z, terms)?;
        let Stop { tol, max_iter, above } = *stop;
        check_scalar("tol", tol)?;
        if let Some(a) = above {
            check_scalar("above", a)?;
            if a < 0.0 {
                return Err(PreisachError::invalid("above", format!("must be >= 0, got {a}")));
            }
        }
        let n = self.rows.n_out();
        let nh = self.input.grid.n_q() + 1;
        let (kp, kq) = (terms.pre.len(), terms.post.len());
        let dim = nh + kp + kq;
        let omega = terms.omega;
        let weigh = |v: &mut [f64]| {
            if let Some(w) = omega {
                v.iter_mut().zip(w).for_each(|(x, &w)| *x *= w);
            }
        };
        let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
        // Diagonal preconditioner of the extra columns (their own norms).
        let mut ediag: Vec<f64> = Vec::with_capacity(kp + kq);
        let mut tmp = vec![0.0; n];
        let mut tmp2 = vec![0.0; n];
        for c in terms.pre {
            lti.apply(c, &mut tmp);
            tmp2.copy_from_slice(&tmp);
            weigh(&mut tmp2);
            ediag.push(dot(&tmp, &tmp2).max(1e-300));
        }
        for c in terms.post {
            tmp.copy_from_slice(c);
            weigh(&mut tmp);
            ediag.push(dot(c, &tmp).max(1e-300));
        }
        let rows = &mut self.rows;
        let pre = &mut self.pre;
        let precond = |r: &[f64], out: &mut [f64], pre: &mut Precond| {
            pre.solve(&r[..nh], &mut out[..nh]);
            for k in 0..kp + kq {
                out[nh + k] = r[nh + k] / ediag[k];
            }
        };
        // y = L(B x + Σ a pre) + Σ b post
        let forward = |x: &[f64], rows: &mut SampleRows, lti: &mut Filter, s1: &mut [f64], y: &mut [f64]| {
            rows.forward(&x[..nh], s1);
            for (k, c) in terms.pre.iter().enumerate() {
                let a = x[nh + k];
                s1.iter_mut().zip(c.iter()).for_each(|(o, &v)| *o += a * v);
            }
            lti.apply(s1, y);
            for (k, c) in terms.post.iter().enumerate() {
                let b = x[nh + kp + k];
                y.iter_mut().zip(c.iter()).for_each(|(o, &v)| *o += b * v);
            }
        };
        // g = adjoint of the forward map applied to v (already weighted)
        let adjoint = |v: &[f64], rows: &mut SampleRows, lti: &mut Filter, s1: &mut [f64], g: &mut [f64]| {
            for (k, c) in terms.post.iter().enumerate() {
                g[nh + kp + k] = dot(c, v);
            }
            lti.adjoint(v, s1);
            for (k, c) in terms.pre.iter().enumerate() {
                g[nh + k] = dot(c, s1);
            }
            rows.adjoint(s1, &mut g[..nh]);
        };
        let (mut s1, mut s2) = (vec![0.0; n], vec![0.0; n]);
        let mut b = vec![0.0; dim];
        s2.copy_from_slice(z);
        weigh(&mut s2);
        adjoint(&s2, rows, lti, &mut s1, &mut b);
        let normal =
            |x: &[f64], out: &mut [f64], rows: &mut SampleRows, lti: &mut Filter, s1: &mut [f64], s2: &mut [f64]| {
                forward(x, rows, lti, s1, s2);
                weigh(s2);
                adjoint(s2, rows, lti, s1, out);
            };
        // The cold start: the fit that ignores the dynamics and the extra terms (B x ≈ z).
        // The tolerance is relative to its residual, the part of the problem that is not
        // plain hysteresis fitting (relative to the right-hand side, the mean level of the
        // output would dominate and a trend's coefficient be left unsolved).
        let mut x = vec![0.0; dim];
        {
            let mut bz = vec![0.0; nh];
            rows.adjoint(&s2, &mut bz);
            pre.solve(&bz, &mut x[..nh]);
        }
        let mut r = vec![0.0; dim];
        let mut ap = vec![0.0; dim];
        let mut zv = vec![0.0; dim];
        let residual = |x: &[f64],
                        r: &mut [f64],
                        ap: &mut [f64],
                        rows: &mut SampleRows,
                        lti: &mut Filter,
                        s1: &mut [f64],
                        s2: &mut [f64]| {
            normal(x, ap, rows, lti, s1, s2);
            for i in 0..dim {
                r[i] = b[i] - ap[i];
            }
        };
        residual(&x, &mut r, &mut ap, rows, lti, &mut s1, &mut s2);
        precond(&r, &mut zv, pre);
        let rz0 = dot(&r, &zv).max(1e-300);
        let mut rz = rz0;
        if let (Some(l), true) = (&self.last, warm) {
            // The previous solution, when it is the better start (the last problem may
            // have been another chain's).
            if l.len() == dim {
                let (mut r2, mut zv2) = (vec![0.0; dim], vec![0.0; dim]);
                residual(l, &mut r2, &mut ap, rows, lti, &mut s1, &mut s2);
                precond(&r2, &mut zv2, pre);
                let rz2 = dot(&r2, &zv2);
                if rz2 < rz {
                    x.copy_from_slice(l);
                    r = r2;
                    zv = zv2;
                    rz = rz2;
                }
            }
        }
        let mut p = zv.clone();
        let mut it = 0;
        // Stopping rule on what the caller compares, the weighted sum of squares: each step
        // lowers it by α·rᵀz exactly; stop when two steps in a row lower it by less than
        // `tol` of its value. (A residual norm relative to the start can look converged
        // while a direction the data barely separates from the masses, a drift's trend,
        // is not.) Near rounding the iteration can break down (the residual blows up): the
        // iterate with the smallest residual is kept.
        forward(&x, rows, lti, &mut s1, &mut s2);
        let mut sse: f64 = match omega {
            Some(w) => s2.iter().zip(z).zip(w).map(|((a, b), w)| w * (a - b) * (a - b)).sum(),
            None => s2.iter().zip(z).map(|(a, b)| (a - b) * (a - b)).sum(),
        };
        let (mut best_x, mut best_rz) = (x.clone(), rz);
        let mut quiet = 0;
        let weight = omega.map_or(n as f64, |w| w.iter().sum());
        let mut ceiling = above.map(|a| Ceiling { sse: a * a * weight, past: [sse; Ceiling::WINDOW] });
        let mut gave_up = false;
        while it < max_iter && quiet < 2 && rz > 1e-24 * rz0 {
            normal(&p, &mut ap, rows, lti, &mut s1, &mut s2);
            let pap = dot(&p, &ap);
            if pap.is_nan() || pap <= 0.0 {
                break;
            }
            let alpha = rz / pap;
            for i in 0..dim {
                x[i] += alpha * p[i];
                r[i] -= alpha * ap[i];
            }
            let drop = alpha * rz;
            sse -= drop;
            quiet = if drop <= tol * sse.max(1e-300) { quiet + 1 } else { 0 };
            precond(&r, &mut zv, pre);
            let rz_new = dot(&r, &zv);
            it += 1;
            if let Some(c) = ceiling.as_mut() {
                if c.hopeless(it, sse, max_iter - it) {
                    gave_up = true;
                    break;
                }
            }
            if rz_new.is_nan() || rz_new > 1e4 * rz0 {
                break;
            }
            if rz_new < best_rz {
                best_rz = rz_new;
                best_x.copy_from_slice(&x);
            }
            let beta = rz_new / rz;
            rz = rz_new;
            for i in 0..dim {
                p[i] = zv[i] + beta * p[i];
            }
        }
        let (mut x, rz) = if best_rz < rz { (best_x, best_rz) } else { (x, rz) };
        if x.iter().any(|v| !v.is_finite()) {
            return Err(PreisachError::Solver("fit behind dynamics: conjugate gradients diverged".into()));
        }
        forward(&x, rows, lti, &mut s1, &mut s2);
        let rmse = weighted_rmse(&s2, z, omega);
        self.last = Some(x.clone());
        Ok(BehindSolution {
            extra: x[nh..].to_vec(),
            x: {
                x.truncate(nh);
                x
            },
            iterations: it,
            residual: (rz / rz0).max(0.0).sqrt(),
            rmse,
            gave_up,
        })
    }

    /// Masses >= 0 for a solution: the NNLS fit of the model to the optimum's hysteresis
    /// output (the projection in the unfiltered metric; exact, or with the session's
    /// smoothness term, [`Behind::set_tie`]), then the extra
    /// columns' coefficients refitted by least squares with those masses. Returns the
    /// model, the coefficients and the weighted RMSE of the chain.
    pub fn project(
        &mut self,
        sol: &BehindSolution,
        z: &[f64],
        lti: &mut Filter,
        terms: &Terms,
    ) -> Result<(PreisachModel, Vec<f64>, f64, FitReport)> {
        self.check_terms(z, terms)?;
        let nf = self.input.u.len();
        let n = self.rows.n_out();
        let mut h_star = vec![0.0; nf];
        self.rows.forward_fine(&sol.x, &mut h_star);
        let (model, rep) = self.projection()?.project(&sol.x, &h_star)?;
        // The model's output on the output samples, through the dynamics.
        let mut x = model.everett_values();
        x.push(model.offset());
        let mut h = vec![0.0; n];
        self.rows.forward(&x, &mut h);
        let mut y = vec![0.0; n];
        lti.apply(&h, &mut y);
        // Columns of the extra terms as they reach the output.
        let mut cols: Vec<Vec<f64>> = Vec::with_capacity(terms.pre.len() + terms.post.len());
        for c in terms.pre {
            let mut o = vec![0.0; n];
            lti.apply(c, &mut o);
            cols.push(o);
        }
        for c in terms.post {
            cols.push(c.to_vec());
        }
        let resid: Vec<f64> = z.iter().zip(&y).map(|(a, b)| a - b).collect();
        let coef = small_lstsq(&cols, &resid, terms.omega);
        for (c, k) in cols.iter().zip(&coef) {
            y.iter_mut().zip(c).for_each(|(o, &v)| *o += k * v);
        }
        let rmse = weighted_rmse(&y, z, terms.omega);
        Ok((model, coef, rmse, rep))
    }
}

fn weighted_rmse(y: &[f64], z: &[f64], omega: Option<&[f64]>) -> f64 {
    let (sse, ws) = match omega {
        Some(w) => y.iter().zip(z).zip(w).fold((0.0, 0.0), |(s, t), ((a, b), w)| (s + w * (a - b) * (a - b), t + w)),
        None => (y.iter().zip(z).map(|(a, b)| (a - b) * (a - b)).sum(), y.len() as f64),
    };
    (sse / ws.max(1e-300)).sqrt()
}

/// Weighted least squares with a handful of columns (normal equations, Cholesky with a
/// tiny ridge; columns that are all zero get 0).
fn small_lstsq(cols: &[Vec<f64>], r: &[f64], omega: Option<&[f64]>) -> Vec<f64> {
    let k = cols.len();
    if k == 0 {
        return Vec::new();
    }
    let w = |t: usize| omega.map_or(1.0, |o| o[t]);
    let mut g = nalgebra::DMatrix::<f64>::zeros(k, k);
    let mut rhs = nalgebra::DVector::<f64>::zeros(k);
    for t in 0..r.len() {
        let wt = w(t);
        for a in 0..k {
            rhs[a] += wt * cols[a][t] * r[t];
            for b in 0..=a {
                g[(a, b)] += wt * cols[a][t] * cols[b][t];
            }
        }
    }
    for a in 0..k {
        for b in 0..a {
            g[(b, a)] = g[(a, b)];
        }
    }
    let dmax = (0..k).map(|a| g[(a, a)]).fold(0.0f64, f64::max).max(1e-300);
    for a in 0..k {
        g[(a, a)] += 1e-12 * dmax;
    }
    match g.cholesky() {
        Some(ch) => ch.solve(&rhs).iter().copied().collect(),
        None => vec![0.0; k],
    }
}

/// Options of [`fit_behind`].
#[derive(Debug, Clone)]
pub struct BehindOptions {
    pub n_h: usize,
    pub u_range: (f64, f64),
    /// Sample period of `u` and `z` (s).
    pub dt: f64,
    /// Stop when two iterations in a row lower the sum of squares by less than this
    /// fraction of it.
    pub tol: f64,
    pub max_iter: usize,
}

/// What [`fit_behind`] did.
#[derive(Debug, Clone)]
pub struct BehindReport {
    /// Conjugate-gradient iterations and the final relative (preconditioned) residual.
    pub iterations: usize,
    pub residual: f64,
    /// Weighted RMSE of the chain output `L h` against `z`: of the unconstrained
    /// optimum, and of the fitted (non-negative) model.
    pub rmse_unconstrained: f64,
    pub rmse: f64,
    /// The NNLS projection's own report (its RMSE is against the optimum's output).
    pub projection: FitReport,
}

/// Fit the interpolated model's masses (>= 0) and offset so that the cascade `blocks`
/// applied to its output matches `z` in weighted least squares (weights `omega`, default
/// 1). `u`, `z` sampled every `opts.dt`; see the module documentation.
pub fn fit_behind(
    u: &[f64],
    z: &[f64],
    omega: Option<&[f64]>,
    blocks: &[Lti],
    opts: &BehindOptions,
) -> Result<(PreisachModel, BehindReport)> {
    check_signal("u", u)?;
    check_scalar("dt", opts.dt)?;
    if opts.dt <= 0.0 {
        return Err(PreisachError::invalid("dt", format!("must be > 0, got {}", opts.dt)));
    }
    let mut lti = Filter::cascade(blocks, opts.dt, Discretization::Foh);
    let mut b = Behind::new(u, opts.n_h, opts.u_range, 1)?;
    // A delay commutes with the other blocks: it delays the hysteresis output.
    let delay = blocks.iter().map(|b| b.delay_s).sum::<f64>() / opts.dt;
    let terms = Terms { omega, pre: &[], post: &[], delay };
    let sol = b.solve(z, &mut lti, &terms, &Stop::new(opts.tol, opts.max_iter), false)?;
    let (model, _, rmse, projection) = b.project(&sol, z, &mut lti, &terms)?;
    let report = BehindReport {
        iterations: sol.iterations,
        residual: sol.residual,
        rmse_unconstrained: sol.rmse,
        rmse,
        projection,
    };
    Ok((model, report))
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::identify::testing::{input, signed, Rng};

    /// `h` delayed by `delay` samples (linear between samples, `h[0]` before the start),
    /// then averaged over windows of `stride` (the last partial one dropped).
    fn windows(h: &[f64], stride: usize, delay: f64) -> Vec<f64> {
        let at = |i: usize| {
            let t = i as f64 - delay;
            if t <= 0.0 {
                return h[0];
            }
            let j = t.floor() as usize;
            let f = t - j as f64;
            if f == 0.0 {
                h[j]
            } else {
                (1.0 - f) * h[j] + f * h[j + 1]
            }
        };
        (0..h.len() / stride).map(|k| (k * stride..(k + 1) * stride).map(at).sum::<f64>() / stride as f64).collect()
    }

    fn dot(a: &[f64], b: &[f64]) -> f64 {
        a.iter().zip(b).map(|(x, y)| x * y).sum()
    }

    fn max_diff(a: &[f64], b: &[f64]) -> f64 {
        a.iter().zip(b).fold(0.0f64, |e, (x, y)| e.max((x - y).abs()))
    }

    #[test]
    fn sample_rows_give_the_model_output_and_their_exact_adjoint() {
        // Both ways of applying `B` (through the groups, and multiplied out), on random
        // inputs, grids, windows and delays, against the model's own output; the adjoint
        // by <B y, v> = <y, Bᵀ v> on random vectors.
        let mut rng = Rng(0x9E3779B97F4A7C15);
        for case in 0..12 {
            let n_h = 3 + case % 7;
            let stride = [1, 2, 3, 8][case % 4];
            let delay = if case % 3 == 0 { 0.0 } else { rng.range(0.0, 20.0) };
            let grid = Grid::new(0.0, 1.0, n_h).unwrap();
            let u = input(&mut rng, 2000 + 37 * case);
            let (x, h) = signed(&mut rng, &grid, &u);
            let mut rows = SampleRows::new(&grid, &[], &u, stride);
            rows.set_delay(delay);
            let want = windows(&h, stride, delay);
            let scale = h.iter().fold(1.0f64, |a, v| a.max(v.abs()));
            let m = rows.n_out();
            let y: Vec<f64> = (0..x.len()).map(|_| rng.range(-1.0, 1.0)).collect();
            let v: Vec<f64> = (0..m).map(|_| rng.range(-1.0, 1.0)).collect();
            let mut outs = Vec::new();
            for direct in [false, true] {
                let mut mixture = (*rows.mixture).clone();
                rows.build_direct(&mut mixture, if direct { usize::MAX } else { 0 });
                rows.mixture = Arc::new(mixture);
                assert_eq!(rows.is_direct(), direct);
                let mut got = vec![0.0; m];
                rows.forward(&x, &mut got);
                let d = max_diff(&got, &want);
                assert!(d <= 1e-12 * scale, "case {case} direct {direct}: B x off the model by {d}");
                let (mut by, mut btv) = (vec![0.0; m], vec![0.0; x.len()]);
                rows.forward(&y, &mut by);
                rows.adjoint(&v, &mut btv);
                let (a, b) = (dot(&by, &v), dot(&y, &btv));
                let size = by.iter().zip(&v).map(|(p, q)| (p * q).abs()).sum::<f64>();
                assert!((a - b).abs() <= 1e-13 * size, "case {case} direct {direct}: <By, v> = {a}, <y, B'v> = {b}");
                outs.push((by, btv));
            }
            assert!(max_diff(&outs[0].0, &outs[1].0) <= 1e-13 * m as f64);
            assert!(max_diff(&outs[0].1, &outs[1].1) <= 1e-13 * m as f64);
            let mut fine = vec![0.0; u.len()];
            rows.forward_fine(&x, &mut fine);
            assert!(max_diff(&fine, &h) <= 1e-12 * scale, "case {case}: the rows per sample are off the model");
        }
    }

    #[test]
    fn sessions_share_a_delay_s_mixture_and_each_moves_alone() {
        // Two sessions at one delay hold one mixture; one moving to another delay leaves
        // the other's products as they were, and any return to delay 0 gives, bit for
        // bit, what a session that never moved gives.
        let mut rng = Rng(4242);
        let grid = Grid::new(0.0, 1.0, 6).unwrap();
        let u = input(&mut rng, 3000);
        let (x, _) = signed(&mut rng, &grid, &u);
        let out = |rows: &mut SampleRows| {
            let mut h = vec![0.0; rows.n_out()];
            rows.forward(&x, &mut h);
            h
        };
        let mut fresh = SampleRows::new(&grid, &[], &u, 4);
        let at_zero = out(&mut fresh);
        let mut a = fresh.clone();
        a.set_delay(7.5);
        let at_delay = out(&mut a);
        assert!(max_diff(&at_delay, &at_zero) > 0.0);
        let mut b = a.clone();
        assert!(Arc::ptr_eq(&a.mixture, &b.mixture));
        b.set_delay(2.25);
        assert!(!Arc::ptr_eq(&a.mixture, &b.mixture));
        assert_eq!(out(&mut a), at_delay);
        for rows in [&mut a, &mut b] {
            rows.set_delay(0.0);
            assert_eq!(out(rows), at_zero);
            rows.set_delay(7.5);
            assert_eq!(out(rows), at_delay);
        }
        assert_eq!(out(&mut fresh), at_zero);
    }

    #[test]
    fn gram_is_the_normal_matrix_of_single_samples() {
        // Windows of one sample, no delay: every output sample is one group's row, so the
        // preconditioner's matrix is exactly Bᵀ B (built here from B's columns).
        let mut rng = Rng(77);
        for n_h in [4, 7] {
            let grid = Grid::new(0.0, 1.0, n_h).unwrap();
            let u = input(&mut rng, 1500);
            let mut rows = SampleRows::new(&grid, &[], &u, 1);
            let (dim, m) = (grid.n_q() + 1, rows.n_out());
            let cols: Vec<Vec<f64>> = (0..dim)
                .map(|i| {
                    let mut e = vec![0.0; dim];
                    e[i] = 1.0;
                    let mut c = vec![0.0; m];
                    rows.forward(&e, &mut c);
                    c
                })
                .collect();
            // Summed in a packed triangle, and as sorted products.
            for dense_max in [usize::MAX, 0] {
                let mut gram = vec![0.0; dim * dim];
                for (k, w) in rows.gram_with(dense_max) {
                    let (i, j) = ((k >> 32) as usize, (k & 0xffff_ffff) as usize);
                    gram[i * dim + j] += w;
                }
                for i in 0..dim {
                    for j in i..dim {
                        let want = dot(&cols[i], &cols[j]);
                        let got = gram[i * dim + j] + if i == j { 0.0 } else { gram[j * dim + i] };
                        assert!((got - want).abs() <= 1e-9 * (1.0 + want.abs()), "({i}, {j}): {got} vs {want}");
                    }
                }
            }
        }
    }
}
