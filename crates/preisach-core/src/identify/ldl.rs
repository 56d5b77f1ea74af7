//! Sparse LDLᵀ of a quasi-definite matrix (the up-looking algorithm of QDLDL / Davis'
//! LDL) with a fixed pattern, a fixed elimination order, and a varying set of live
//! couplings.
//!
//! The active-set solver factors the KKT matrix of the identification QP many times,
//! each time with a different subset of the constraint rows coupled (an inactive
//! constraint's row is `−ν_c = 0`, a 1 × 1 block). One fill-reducing ordering of the
//! full pattern serves all of them: the fill of a subgraph under the same order stays
//! within the full graph's, so the full factor's column layout holds every factor, and
//! each factorization only recomputes the elimination tree of its live pattern
//! (O(nnz A)). A factor with few constraints coupled costs what its own, much sparser,
//! system costs: no ordering or allocation per step.

const NONE: usize = usize::MAX;

/// Pivots whose sign is wrong or magnitude below this are replaced (QDLDL's dynamic
/// regularization; the caller's static regularization and refinement make it rare).
const REG_EPS: f64 = 1e-12;
const REG_DELTA: f64 = 1e-7;

/// A symmetric matrix pattern: upper triangle in CSC, diagonal present in every column.
pub struct Pattern<'a> {
    pub colptr: &'a [usize],
    pub rowval: &'a [usize],
}

#[derive(Default)]
pub struct Ldl {
    /// Original index of pivot k.
    order: Vec<usize>,
    /// Permuted upper triangle: per column its rows and source positions in the
    /// pattern's value array.
    ap: Vec<usize>,
    ai: Vec<u32>,
    src: Vec<usize>,
    /// Whether each permuted entry is live in the current factorization.
    live: Vec<bool>,
    etree: Vec<usize>,
    /// L by columns (column c fills `lp[c]..lend[c]`, room for the full pattern's
    /// count): the forward sweep scatters, the backward one gathers. (A row-wise copy
    /// for a gathering forward sweep measured no faster and doubled L's memory.)
    lp: Vec<usize>,
    lend: Vec<usize>,
    li: Vec<u32>,
    lx: Vec<f64>,
    d: Vec<f64>,
    dinv: Vec<f64>,
    signs: Vec<f64>,
    // Workspace.
    ax: Vec<f64>,
    anc: Vec<usize>,
    y_vals: Vec<f64>,
    y_used: Vec<bool>,
    y_idx: Vec<usize>,
    elim: Vec<usize>,
    work: Vec<f64>,
}

impl Ldl {
    /// Symbolic analysis of the full pattern eliminated in `order` (a permutation: pivot
    /// k is original index `order[k]`). `signs[i]` is the expected sign of pivot `i`
    /// (+1 primal, −1 dual).
    #[cfg(test)]
    pub fn new(pat: &Pattern, order: &[usize], signs: &[i8]) -> Self {
        let mut f = Ldl::default();
        f.analyze(pat, order, signs);
        f
    }

    /// [`Ldl::new`] in this factorization's buffers (their memory reused).
    pub fn analyze(&mut self, pat: &Pattern, order: &[usize], signs: &[i8]) {
        let n = pat.colptr.len() - 1;
        assert!(order.len() == n && signs.len() == n && n < u32::MAX as usize);
        // `anc` serves as the inverse permutation here.
        let inv = refill(&mut self.anc, n, NONE);
        for (k, &i) in order.iter().enumerate() {
            inv[i] = k;
        }
        // Permuted upper triangle: entry (i, j) goes to column max(inv i, inv j).
        let ap = refill(&mut self.ap, n + 1, 0);
        for j in 0..n {
            for &i in &pat.rowval[pat.colptr[j]..pat.colptr[j + 1]] {
                ap[inv[i].max(inv[j]) + 1] += 1;
            }
        }
        for k in 0..n {
            ap[k + 1] += ap[k];
        }
        let nnz = ap[n];
        let ai = sized(&mut self.ai, nnz, 0);
        let src = sized(&mut self.src, nnz, 0);
        // `lend` serves as the fill pointers here.
        let fill = sized(&mut self.lend, n, 0);
        fill.copy_from_slice(&ap[..n]);
        for j in 0..n {
            for p in pat.colptr[j]..pat.colptr[j + 1] {
                let (a, b) = (inv[pat.rowval[p]], inv[j]);
                let c = a.max(b);
                ai[fill[c]] = a.min(b) as u32;
                src[fill[c]] = p;
                fill[c] += 1;
            }
        }
        // Column counts of the full factor (walking the elimination tree row by row):
        // the storage layout of every factor. (`lp` holds the counts, `y_idx` the marks.)
        let etree = refill(&mut self.etree, n, NONE);
        let lp = refill(&mut self.lp, n + 1, 0);
        let mark = refill(&mut self.y_idx, n, NONE);
        for j in 0..n {
            mark[j] = j;
            for &i0 in &ai[ap[j]..ap[j + 1]] {
                let mut i = i0 as usize;
                while mark[i] != j {
                    if etree[i] == NONE {
                        etree[i] = j;
                    }
                    lp[i + 1] += 1;
                    mark[i] = j;
                    i = etree[i];
                }
            }
        }
        for k in 0..n {
            lp[k + 1] += lp[k];
        }
        let l_nnz = lp[n];
        self.order.clear();
        self.order.extend_from_slice(order);
        self.signs.clear();
        self.signs.extend(order.iter().map(|&i| f64::from(signs[i])));
        sized(&mut self.live, nnz, true);
        self.lend.copy_from_slice(&self.lp[..n]);
        sized(&mut self.li, l_nnz, 0);
        sized(&mut self.lx, l_nnz, 0.0);
        sized(&mut self.d, n, 0.0);
        sized(&mut self.dinv, n, 0.0);
        sized(&mut self.ax, nnz, 0.0);
        refill(&mut self.anc, n, NONE);
        refill(&mut self.y_vals, n, 0.0);
        refill(&mut self.y_used, n, false);
        sized(&mut self.y_idx, n, 0);
        sized(&mut self.elim, n, 0);
        sized(&mut self.work, n, 0.0);
    }

    /// Bytes held by the buffers.
    pub fn capacity_bytes(&self) -> usize {
        8 * (self.order.capacity()
            + self.ap.capacity()
            + self.src.capacity()
            + self.etree.capacity()
            + self.lp.capacity()
            + self.lend.capacity()
            + self.lx.capacity()
            + self.d.capacity()
            + self.dinv.capacity()
            + self.signs.capacity()
            + self.ax.capacity()
            + self.anc.capacity()
            + self.y_vals.capacity()
            + self.y_idx.capacity()
            + self.elim.capacity()
            + self.work.capacity())
            + 4 * (self.ai.capacity() + self.li.capacity())
            + self.live.capacity()
            + self.y_used.capacity()
    }

    /// Numeric factorization with the pattern's values `val`, coupling only indices
    /// `i` with `coupled[i]` (all when `None`): an off-diagonal entry with an uncoupled
    /// end is treated as a structural zero. Returns false on a zero or non-finite pivot.
    pub fn factor(&mut self, val: &[f64], coupled: Option<&[bool]>) -> bool {
        let n = self.order.len();
        // Live entries and the elimination tree of the live pattern (Liu's algorithm
        // with path compression).
        let pc = &mut self.y_used;
        for (f, &i) in pc.iter_mut().zip(&self.order) {
            *f = coupled.is_none_or(|c| c[i]);
        }
        for (a, &s) in self.ax.iter_mut().zip(&self.src) {
            *a = val[s];
        }
        for k in 0..n {
            self.etree[k] = NONE;
            self.anc[k] = NONE;
            let ck = pc[k];
            for p in self.ap[k]..self.ap[k + 1] {
                let i0 = self.ai[p] as usize;
                let live = ck && pc[i0] && i0 != k;
                self.live[p] = live || i0 == k;
                if !live {
                    continue;
                }
                let mut i = i0;
                while i != NONE && i < k {
                    let next = self.anc[i];
                    self.anc[i] = k;
                    if next == NONE {
                        self.etree[i] = k;
                    }
                    i = next;
                }
            }
        }
        pc.iter_mut().for_each(|f| *f = false);
        let (ap, ai, ax, live) = (&self.ap, &self.ai, &self.ax, &self.live);
        let (lp, lend, li, lx) = (&self.lp, &mut self.lend, &mut self.li, &mut self.lx);
        let (d, dinv, etree) = (&mut self.d, &mut self.dinv, &self.etree);
        let (y_vals, y_used, y_idx, elim) = (&mut self.y_vals, &mut self.y_used, &mut self.y_idx, &mut self.elim);
        lend.copy_from_slice(&lp[..n]);
        for k in 0..n {
            // Row k of L: solve L(0:k, 0:k) y = A(0:k, k), pattern from the etree.
            let mut nnz_y = 0;
            let mut dk = 0.0;
            for p in ap[k]..ap[k + 1] {
                if !live[p] {
                    continue;
                }
                let b = ai[p] as usize;
                if b == k {
                    dk = ax[p];
                    continue;
                }
                y_vals[b] = ax[p];
                if y_used[b] {
                    continue;
                }
                y_used[b] = true;
                elim[0] = b;
                let mut ne = 1;
                let mut i = etree[b];
                while i != NONE && i < k && !y_used[i] {
                    y_used[i] = true;
                    elim[ne] = i;
                    ne += 1;
                    i = etree[i];
                }
                while ne > 0 {
                    ne -= 1;
                    y_idx[nnz_y] = elim[ne];
                    nnz_y += 1;
                }
            }
            for t in (0..nnz_y).rev() {
                let c = y_idx[t];
                let end = lend[c];
                let yc = y_vals[c];
                for (&r, &l) in li[lp[c]..end].iter().zip(&lx[lp[c]..end]) {
                    y_vals[r as usize] -= l * yc;
                }
                let lkc = yc * dinv[c];
                li[end] = k as u32;
                lx[end] = lkc;
                dk -= yc * lkc;
                lend[c] = end + 1;
                y_vals[c] = 0.0;
                y_used[c] = false;
            }
            let s = self.signs[k];
            if dk * s < REG_EPS {
                dk = REG_DELTA * s;
            }
            if !dk.is_finite() {
                return false;
            }
            d[k] = dk;
            dinv[k] = 1.0 / dk;
        }
        true
    }

    /// Cost of the last factorization in triangular solves (its Σ (column count)² over
    /// twice its entries: the up-looking factorization and the two sweeps of a solve
    /// run at about the same speed per entry touched).
    pub fn refactor_in_solves(&self) -> f64 {
        let n = self.order.len();
        let (mut sq, mut nnz) = (0.0, 0.0);
        for c in 0..n {
            let k = (self.lend[c] - self.lp[c]) as f64;
            sq += k * k;
            nnz += k;
        }
        sq / (2.0 * nnz).max(1.0)
    }

    /// Solve in place with the last factorization (`x` indexed like the pattern).
    pub fn solve(&mut self, x: &mut [f64]) {
        let n = self.order.len();
        let w = &mut self.work;
        for (wk, &i) in w.iter_mut().zip(&self.order) {
            *wk = x[i];
        }
        let (lp, lend, li, lx) = (&self.lp, &self.lend, &self.li, &self.lx);
        for j in 0..n {
            let wj = w[j];
            // (Right-hand sides of bordered and refinement solves are often sparse.)
            if wj != 0.0 {
                for (&r, &l) in li[lp[j]..lend[j]].iter().zip(&lx[lp[j]..lend[j]]) {
                    w[r as usize] -= l * wj;
                }
            }
        }
        for (wk, &di) in w.iter_mut().zip(&self.dinv) {
            *wk *= di;
        }
        for j in (0..n).rev() {
            w[j] -= dot(&li[lp[j]..lend[j]], &lx[lp[j]..lend[j]], w);
        }
        for (wk, &i) in w.iter().zip(&self.order) {
            x[i] = *wk;
        }
    }
}

impl Ldl {
    /// Solve in place for `k` right-hand sides at once: `x` holds them row-interleaved
    /// (entry i of right-hand side j at `x[i * k + j]`). Four at a time, so every entry
    /// of L read is applied to four values: about half a single solve's time each.
    pub fn solve_many(&mut self, x: &mut [f64], k: usize) {
        let n = self.order.len();
        let mut w = vec![[0.0f64; 4]; n];
        for g in (0..k).step_by(4) {
            let kk = (k - g).min(4);
            for (t, &i) in self.order.iter().enumerate() {
                let mut v = [0.0; 4];
                v[..kk].copy_from_slice(&x[i * k + g..i * k + g + kk]);
                w[t] = v;
            }
            // Forward sweep by columns, skipping zero ones: the callers' right-hand sides
            // are sparse (a constraint's four coefficients or a unit vector), and their
            // solution is nonzero only along the elimination-tree paths above them.
            let (lp, lend, li, lx) = (&self.lp, &self.lend, &self.li, &self.lx);
            for j in 0..n {
                let wj = w[j];
                if wj == [0.0; 4] {
                    continue;
                }
                for (&r, &l) in li[lp[j]..lend[j]].iter().zip(&lx[lp[j]..lend[j]]) {
                    let wr = &mut w[r as usize];
                    for t in 0..4 {
                        wr[t] -= l * wj[t];
                    }
                }
            }
            for (wt, &di) in w.iter_mut().zip(&self.dinv) {
                for v in wt.iter_mut() {
                    *v *= di;
                }
            }
            for j in (0..n).rev() {
                let a = dot4(&li[lp[j]..lend[j]], &lx[lp[j]..lend[j]], &w);
                let wj = &mut w[j];
                for t in 0..4 {
                    wj[t] -= a[t];
                }
            }
            for (t, &i) in self.order.iter().enumerate() {
                x[i * k + g..i * k + g + kk].copy_from_slice(&w[t][..kk]);
            }
        }
    }
}

/// `v` resized to `n` entries, old values kept (its memory reused, no pass over it), as
/// a slice: for buffers that are written before they are read.
fn sized<T: Copy>(v: &mut Vec<T>, n: usize, x: T) -> &mut [T] {
    v.truncate(n);
    v.resize(n, x);
    v
}

/// `v` resized to `n` entries all equal to `x` (its memory reused), as a slice.
fn refill<T: Copy>(v: &mut Vec<T>, n: usize, x: T) -> &mut [T] {
    v.clear();
    v.resize(n, x);
    v
}

/// `Σ val[t] · w[idx[t]]` for four right-hand sides, two partial sums each.
#[inline(always)]
fn dot4(idx: &[u32], val: &[f64], w: &[[f64; 4]]) -> [f64; 4] {
    let mut a = [0.0f64; 4];
    let mut b = [0.0f64; 4];
    let (ci, cv) = (idx.chunks_exact(2), val.chunks_exact(2));
    let (ti, tv) = (ci.remainder(), cv.remainder());
    for (i, v) in ci.zip(cv) {
        let (p, q) = (w[i[0] as usize], w[i[1] as usize]);
        for t in 0..4 {
            a[t] += v[0] * p[t];
            b[t] += v[1] * q[t];
        }
    }
    for (&i, &v) in ti.iter().zip(tv) {
        let p = w[i as usize];
        for t in 0..4 {
            a[t] += v * p[t];
        }
    }
    for t in 0..4 {
        a[t] += b[t];
    }
    a
}

/// `Σ val[t] · w[idx[t]]` with four partial sums: a triangular solve is a chain of such
/// short dot products, and one accumulator would serialize on the add latency.
#[inline(always)]
fn dot(idx: &[u32], val: &[f64], w: &[f64]) -> f64 {
    let mut a = [0.0f64; 4];
    let (ci, cv) = (idx.chunks_exact(4), val.chunks_exact(4));
    let (ti, tv) = (ci.remainder(), cv.remainder());
    for (i, v) in ci.zip(cv) {
        a[0] += v[0] * w[i[0] as usize];
        a[1] += v[1] * w[i[1] as usize];
        a[2] += v[2] * w[i[2] as usize];
        a[3] += v[3] * w[i[3] as usize];
    }
    let mut s = (a[0] + a[1]) + (a[2] + a[3]);
    for (&i, &v) in ti.iter().zip(tv) {
        s += v * w[i as usize];
    }
    s
}

/// Approximate minimum degree ordering of a symmetric pattern (faer's AMD).
pub fn amd_order(pat: &Pattern) -> crate::error::Result<Vec<usize>> {
    use faer::dyn_stack::{MemBuffer, MemStack};
    use faer::sparse::linalg::amd;
    use faer::sparse::SymbolicSparseColMatRef;
    let n = pat.colptr.len() - 1;
    let mut perm = vec![0usize; n];
    let mut inv = vec![0usize; n];
    let sym = SymbolicSparseColMatRef::new_checked(n, n, pat.colptr, None, pat.rowval);
    let mut mem = MemBuffer::new(amd::order_scratch::<usize>(n, pat.rowval.len()));
    amd::order(&mut perm, &mut inv, sym, amd::Control { dense: 3.0, aggressive: true }, MemStack::new(&mut mem))
        .map_err(|e| crate::error::PreisachError::Solver(format!("ordering: {e:?}")))?;
    Ok(perm)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A random quasi-definite matrix `[H, Bᵀ; B, −C]` (H, C positive definite) in upper
    /// CSC with every diagonal present, as (colptr, rowval, val).
    fn quasi_definite(n: usize, m: usize, seed: u64) -> (Vec<usize>, Vec<usize>, Vec<f64>) {
        let mut s = seed;
        let mut rnd = move || {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (s >> 11) as f64 / (1u64 << 53) as f64
        };
        let dim = n + m;
        let mut dense = vec![0.0; dim * dim];
        for j in 0..dim {
            for i in 0..j {
                let dual_block = i >= n;
                if !dual_block && rnd() < 0.15 {
                    let v = rnd() - 0.5;
                    dense[i * dim + j] = v;
                    dense[j * dim + i] = v;
                }
            }
        }
        for i in 0..dim {
            let off: f64 = (0..dim).filter(|&j| j != i).map(|j| dense[i * dim + j].abs()).sum();
            dense[i * dim + i] = if i < n { off + 1.0 } else { -(0.1 + rnd()) };
        }
        let (mut colptr, mut rowval, mut val) = (vec![0], Vec::new(), Vec::new());
        for j in 0..dim {
            for i in 0..=j {
                if i == j || dense[i * dim + j] != 0.0 {
                    rowval.push(i);
                    val.push(dense[i * dim + j]);
                }
            }
            colptr.push(rowval.len());
        }
        (colptr, rowval, val)
    }

    #[test]
    fn factor_of_a_live_subpattern_solves_the_decoupled_system() {
        let (n, m) = (40, 25);
        let dim = n + m;
        let (colptr, rowval, val) = quasi_definite(n, m, 7);
        let pat = Pattern { colptr: &colptr, rowval: &rowval };
        let order = amd_order(&pat).unwrap();
        let signs: Vec<i8> = (0..dim).map(|i| if i < n { 1 } else { -1 }).collect();
        let mut f = Ldl::new(&pat, &order, &signs);
        let b: Vec<f64> = (0..dim).map(|i| (i as f64 * 0.7).sin()).collect();
        // Every other dual index uncoupled: its row and column reduce to the diagonal.
        let coupled: Vec<bool> = (0..dim).map(|i| i < n || i % 2 == 0).collect();
        for live in [None, Some(&coupled[..])] {
            assert!(f.factor(&val, live));
            let mut x = b.clone();
            f.solve(&mut x);
            let on = |i: usize| live.is_none_or(|c| c[i]);
            let mut r = b.clone();
            for j in 0..dim {
                for p in colptr[j]..colptr[j + 1] {
                    let i = rowval[p];
                    if i != j && !(on(i) && on(j)) {
                        continue;
                    }
                    r[i] -= val[p] * x[j];
                    if i != j {
                        r[j] -= val[p] * x[i];
                    }
                }
            }
            let err = r.iter().fold(0.0f64, |a, v| a.max(v.abs()));
            assert!(err < 1e-12, "residual {err}");
        }
    }
}
