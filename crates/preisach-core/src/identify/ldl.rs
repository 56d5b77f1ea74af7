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
//!
//! When the order puts two uncoupled halves first (a nested dissection's top level,
//! [`Ldl::set_split`]), a factorization runs them on two threads ([`crate::pair::join`]):
//! each half's own rows, then each half's part of every separator row (the triangular
//! solve of that row through the half's columns, whose updates to the separator's
//! entries are kept per row as dense deltas), then the separator's rows alone with both
//! halves' deltas added. A solve sweeps the halves at once the same way. No fill and no
//! result changes, only the order of summation: at n_h = 40 the ADMM warm start's full
//! factorization takes 0.44 instead of 0.61 ms, its 20 solves 0.51 instead of 0.70 ms.

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
    /// Pivots `0..split[0]` and `split[0]..split[1]` are uncoupled (both halves of a
    /// nested dissection, see [`Ldl::set_split`]); `[0, 0]`: no split.
    split: [usize; 2],
    /// Whether the last factorization used the split.
    split_now: bool,
    /// Split whether or not a second thread is at hand (tests of the split algorithm).
    #[cfg(test)]
    force_split: bool,
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
    /// End of each column's entries above the separator's rows (its rows in its own
    /// half; with no split, all of them): the solves' halves stop there.
    lmid: Vec<usize>,
    /// Whether each pivot is coupled in the current factorization.
    pc: Vec<bool>,
    // Workspace.
    ax: Vec<f64>,
    anc: Vec<usize>,
    /// One per thread (caller, helper).
    w: [Work; 2],
    work: Vec<f64>,
    /// The separator's part of each half's forward sweep.
    acc: [Vec<f64>; 2],
}

/// Workspace of one thread of the factorization.
#[derive(Default)]
struct Work {
    y_vals: Vec<f64>,
    y_used: Vec<bool>,
    y_idx: Vec<usize>,
    elim: Vec<usize>,
    /// A half's part of the separator's rows: of row `s1 + t`, its deltas to the
    /// separator's entries `s1..s1 + t` (dense, at `tri[t(t − 1)/2..]`), to its pivot
    /// (`sd[t]`), and the separator rows where the half's elimination-tree paths enter
    /// the separator (`eidx[eptr[t]..eptr[t + 1]]`: with row k's own entries there, they
    /// give its pattern in the separator).
    tri: Vec<f64>,
    sd: Vec<f64>,
    eptr: Vec<usize>,
    eidx: Vec<u32>,
}

impl Work {
    fn size(&mut self, n: usize) {
        refill(&mut self.y_vals, n, 0.0);
        refill(&mut self.y_used, n, false);
        sized(&mut self.y_idx, n, 0);
        sized(&mut self.elim, n, 0);
    }

    fn bytes(&self) -> usize {
        8 * (self.y_vals.capacity() + self.y_idx.capacity() + self.elim.capacity())
            + 8 * (self.tri.capacity() + self.sd.capacity() + self.eptr.capacity())
            + 4 * self.eidx.capacity()
            + self.y_used.capacity()
    }

    /// Add `b` and its elimination-tree path below `k` to row k's pattern (`y_idx`, in
    /// topological order), unless already there. `etree[i − off]` is i's parent.
    #[inline]
    fn reach(&mut self, b: usize, k: usize, etree: &[usize], off: usize, nnz_y: &mut usize) {
        if self.y_used[b] {
            return;
        }
        self.y_used[b] = true;
        self.elim[0] = b;
        let mut ne = 1;
        let mut i = etree[b - off];
        while i != NONE && i < k && !self.y_used[i] {
            self.y_used[i] = true;
            self.elim[ne] = i;
            ne += 1;
            i = etree[i - off];
        }
        while ne > 0 {
            ne -= 1;
            self.y_idx[*nnz_y] = self.elim[ne];
            *nnz_y += 1;
        }
    }
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
        // the storage layout of every factor. (`lp` holds the counts, `lmid` the marks.)
        let etree = refill(&mut self.etree, n, NONE);
        let lp = refill(&mut self.lp, n + 1, 0);
        let mark = refill(&mut self.lmid, n, NONE);
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
        self.w[0].size(n);
        self.w[1].size(n);
        sized(&mut self.lmid, n, 0);
        sized(&mut self.pc, n, false);
        sized(&mut self.work, n, 0.0);
        self.split = [0, 0];
        self.split_now = false;
    }

    /// Entries below the diagonal in the full pattern's factor.
    #[cfg(test)]
    pub fn full_nnz(&self) -> usize {
        self.lp[self.order.len()]
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
            + self.lmid.capacity()
            + self.work.capacity()
            + self.acc[0].capacity()
            + self.acc[1].capacity())
            + 4 * (self.ai.capacity() + self.li.capacity())
            + self.live.capacity()
            + self.pc.capacity()
            + self.w[0].bytes()
            + self.w[1].bytes()
    }

    /// Declare pivots `0..split[0]` and `split[0]..split[1]` uncoupled (the two halves of
    /// a nested dissection, the separator after them): factorizations and solves then
    /// run the halves on two threads ([`crate::pair::join`]). `[0, 0]`: no split.
    pub fn set_split(&mut self, split: [usize; 2]) {
        let n = self.order.len();
        // (The separator's deltas are kept dense: at most a few MB.)
        let ok = 0 < split[0] && split[0] < split[1] && split[1] < n && n - split[1] <= 1024;
        self.split = if ok { split } else { [0, 0] };
        if ok {
            for a in &mut self.acc {
                refill(a, n - split[1], 0.0);
            }
        }
    }

    /// Numeric factorization with the pattern's values `val`, coupling only indices
    /// `i` with `coupled[i]` (all when `None`): an off-diagonal entry with an uncoupled
    /// end is treated as a structural zero. Returns false on a zero or non-finite pivot.
    ///
    /// Up-looking, row by row. With a split, each half's rows are factored on its own
    /// thread, and so is the half's part of every separator row (the solve of row k
    /// through the half's columns, whose results scatter into the separator's entries
    /// of row k: kept as per-row deltas). The separator's rows are then finished alone.
    pub fn factor(&mut self, val: &[f64], coupled: Option<&[bool]>) -> bool {
        let n = self.order.len();
        for (f, &i) in self.pc.iter_mut().zip(&self.order) {
            *f = coupled.is_none_or(|c| c[i]);
        }
        // Split only while a second thread is at hand: alone, the split costs about a
        // tenth more than the plain up-looking order (its separator pass and deltas).
        self.split_now = self.split != [0, 0] && crate::pair::available();
        #[cfg(test)]
        {
            self.split_now |= self.force_split && self.split != [0, 0];
        }
        let [s0, s1] = if self.split_now { self.split } else { [0, 0] };
        let Ldl { ap, ai, src, lp, signs, pc, lend, lmid, li, lx, d, dinv, etree, anc, live, ax, w, .. } = self;
        let sh = Shared { ap, ai, src, lp, signs, pc, val, n, s1 };
        lend.copy_from_slice(&lp[..n]);
        let mut all = Half { lo: 0, hi: n, lend, lmid, li, lx, d, dinv, etree, anc, live, ax };
        let [w0, w1] = w;
        if s1 == 0 {
            return all.rows(&sh, w0);
        }
        // Both halves at once: rows, then their parts of the separator's rows.
        let (mut h0, mut h1) = all.split_at(s0, &sh);
        h1.hi = s1;
        let (mut ok0, mut ok1) = (false, false);
        crate::pair::join(
            || {
                ok1 = h1.rows(&sh, w1);
                h1.separator(&sh, w1);
            },
            || {
                ok0 = h0.rows(&sh, w0);
                h0.separator(&sh, w0);
            },
        );
        if !(ok0 && ok1) {
            return false;
        }
        // The separator's rows: their elimination tree (Liu's algorithm, through the
        // ancestors the halves left), then the rest of each row with the halves' deltas
        // and their paths into the separator.
        all.etree_rows(&sh, s1..n);
        for k in s1..n {
            let t = k - s1;
            let mut nnz_y = 0;
            let mut dk = all.load_row(&sh, k, s1, w0, &mut nnz_y);
            let off = t * (t + 1) / 2 - t;
            for ((y, a), b) in w0.y_vals[s1..k].iter_mut().zip(&w0.tri[off..off + t]).zip(&w1.tri[off..off + t]) {
                *y += a + b;
            }
            for e in w0.eptr[t]..w0.eptr[t + 1] {
                let r = w0.eidx[e] as usize;
                w0.reach(r, k, all.etree, 0, &mut nnz_y);
            }
            for e in w1.eptr[t]..w1.eptr[t + 1] {
                w0.reach(w1.eidx[e] as usize, k, all.etree, 0, &mut nnz_y);
            }
            dk += w0.sd[t] + w1.sd[t];
            let dk = all.eliminate::<false>(&sh, k, nnz_y, dk, w0);
            if !all.set_pivot(&sh, k, dk) {
                return false;
            }
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
        let split = self.split_used();
        let w = &mut self.work;
        for (wk, &i) in w.iter_mut().zip(&self.order) {
            *wk = x[i];
        }
        let f =
            Factor { lp: &self.lp, lmid: &self.lmid, lend: &self.lend, li: &self.li, lx: &self.lx, dinv: &self.dinv };
        f.solve(split, w, &mut self.acc);
        for (wk, &i) in w.iter().zip(&self.order) {
            x[i] = *wk;
        }
    }

    /// The split of the last factorization (`[0, 0]` if it was not split: only a split
    /// factorization marks `lmid` at the halves' ends).
    fn split_used(&self) -> [usize; 2] {
        if self.split_now {
            self.split
        } else {
            [0, 0]
        }
    }
}

/// The factor as the solves read it.
struct Factor<'a> {
    lp: &'a [usize],
    lmid: &'a [usize],
    lend: &'a [usize],
    li: &'a [u32],
    lx: &'a [f64],
    dinv: &'a [f64],
}

impl Factor<'_> {
    /// `w ← (L D Lᵀ)⁻¹ w` in pivot order. With a split, the halves' forward sweeps run at
    /// once, each collecting its updates to the separator's rows in its own `acc` (zero
    /// on entry and on return), then the separator's; backwards the separator first, then
    /// the halves at once.
    fn solve<T: Lane>(&self, [s0, s1]: [usize; 2], w: &mut [T], acc: &mut [Vec<T>; 2]) {
        let n = w.len();
        if s1 == 0 {
            self.forward(0, n, w, &mut []);
        } else {
            let (wh, ws) = w.split_at_mut(s1);
            let (w0, w1) = wh.split_at_mut(s0);
            let [a0, a1] = acc;
            crate::pair::join(|| self.forward(s0, s1, w1, a1), || self.forward(0, s0, w0, a0));
            for ((v, a), b) in ws.iter_mut().zip(a0.iter_mut()).zip(a1.iter_mut()) {
                v.add(*a);
                v.add(*b);
                *a = T::ZERO;
                *b = T::ZERO;
            }
            self.forward(s1, n, ws, &mut []);
        }
        for (wk, &di) in w.iter_mut().zip(self.dinv) {
            wk.scale(di);
        }
        if s1 == 0 {
            self.backward(0, n, w, &[]);
        } else {
            let (wh, ws) = w.split_at_mut(s1);
            self.backward(s1, n, ws, &[]);
            let ws = &*ws;
            let (w0, w1) = wh.split_at_mut(s0);
            crate::pair::join(|| self.backward(s0, s1, w1, ws), || self.backward(0, s0, w0, ws));
        }
    }

    /// Forward sweep `w ← L⁻¹ w` over columns `lo..hi`, whose entries lie in rows
    /// `lo..hi` (held by `w`) and, past `lmid`, in the separator's rows (the last
    /// `acc.len()`, whose updates `acc` collects). With `acc` empty every entry lies in
    /// `lo..hi`.
    #[inline]
    fn forward<T: Lane>(&self, lo: usize, hi: usize, w: &mut [T], acc: &mut [T]) {
        let Factor { lp, lmid, lend, li, lx, .. } = *self;
        let s1 = lend.len() - acc.len();
        for j in lo..hi {
            let wj = w[j - lo];
            // (Right-hand sides of bordered and refinement solves are often sparse: a
            // constraint's four coefficients or a unit vector, whose solution is nonzero
            // only along the elimination-tree paths above them.)
            if wj.is_zero() {
                continue;
            }
            let (m, e) = if acc.is_empty() { (lend[j], lend[j]) } else { (lmid[j], lend[j]) };
            for (&r, &l) in li[lp[j]..m].iter().zip(&lx[lp[j]..m]) {
                w[r as usize - lo].sub_scaled(l, wj);
            }
            for (&r, &l) in li[m..e].iter().zip(&lx[m..e]) {
                acc[r as usize - s1].sub_scaled(l, wj);
            }
        }
    }

    /// Backward sweep `w ← L⁻ᵀ w` over columns `lo..hi` (`w`: rows `lo..hi`; `ws`: the
    /// separator's rows, already final, or empty when no entry lies past `lmid`).
    #[inline]
    fn backward<T: Lane>(&self, lo: usize, hi: usize, w: &mut [T], ws: &[T]) {
        let Factor { lp, lmid, lend, li, lx, .. } = *self;
        let s1 = lend.len() - ws.len();
        for j in (lo..hi).rev() {
            let m = if ws.is_empty() { lend[j] } else { lmid[j] };
            let mut v = T::dot(&li[lp[j]..m], &lx[lp[j]..m], w, lo);
            if !ws.is_empty() {
                v.add(T::dot(&li[m..lend[j]], &lx[m..lend[j]], ws, s1));
            }
            w[j - lo].sub_scaled(1.0, v);
        }
    }
}

/// What a triangular sweep carries per row: one right-hand side (`f64`) or four.
trait Lane: Copy + Send + Sync {
    const ZERO: Self;
    fn is_zero(&self) -> bool;
    /// `self −= l · x`.
    fn sub_scaled(&mut self, l: f64, x: Self);
    fn add(&mut self, x: Self);
    fn scale(&mut self, d: f64);
    /// `Σ val[t] · w[idx[t] − off]`.
    fn dot(idx: &[u32], val: &[f64], w: &[Self], off: usize) -> Self;
}

impl Lane for f64 {
    const ZERO: f64 = 0.0;
    #[inline(always)]
    fn is_zero(&self) -> bool {
        *self == 0.0
    }
    #[inline(always)]
    fn sub_scaled(&mut self, l: f64, x: f64) {
        *self -= l * x;
    }
    #[inline(always)]
    fn add(&mut self, x: f64) {
        *self += x;
    }
    #[inline(always)]
    fn scale(&mut self, d: f64) {
        *self *= d;
    }
    #[inline(always)]
    fn dot(idx: &[u32], val: &[f64], w: &[f64], off: usize) -> f64 {
        dot(idx, val, w, off)
    }
}

impl Lane for [f64; 4] {
    const ZERO: [f64; 4] = [0.0; 4];
    #[inline(always)]
    fn is_zero(&self) -> bool {
        *self == [0.0; 4]
    }
    #[inline(always)]
    fn sub_scaled(&mut self, l: f64, x: [f64; 4]) {
        for t in 0..4 {
            self[t] -= l * x[t];
        }
    }
    #[inline(always)]
    fn add(&mut self, x: [f64; 4]) {
        for t in 0..4 {
            self[t] += x[t];
        }
    }
    #[inline(always)]
    fn scale(&mut self, d: f64) {
        for v in self.iter_mut() {
            *v *= d;
        }
    }
    #[inline(always)]
    fn dot(idx: &[u32], val: &[f64], w: &[[f64; 4]], off: usize) -> [f64; 4] {
        dot4(idx, val, w, off)
    }
}

/// The pivot `dk` with QDLDL's dynamic regularization (wrong sign or tiny: replaced by
/// ±[`REG_DELTA`]); `None` if not finite.
#[inline]
fn pivot(dk: f64, sign: f64) -> Option<f64> {
    let v = if dk * sign < REG_EPS { REG_DELTA * sign } else { dk };
    v.is_finite().then_some(v)
}

/// What both threads of a factorization read.
struct Shared<'a> {
    ap: &'a [usize],
    ai: &'a [u32],
    src: &'a [usize],
    lp: &'a [usize],
    signs: &'a [f64],
    pc: &'a [bool],
    val: &'a [f64],
    n: usize,
    /// First row of the separator (0: no split).
    s1: usize,
}

/// The rows and columns `lo..hi` of a factorization (a half, or all of them): slices of
/// the factor and of the permuted matrix starting at column `lo` (the factor's storage
/// at `lp[lo]`, the matrix's entries at `ap[lo]`).
struct Half<'a> {
    lo: usize,
    hi: usize,
    lend: &'a mut [usize],
    lmid: &'a mut [usize],
    li: &'a mut [u32],
    lx: &'a mut [f64],
    d: &'a mut [f64],
    dinv: &'a mut [f64],
    etree: &'a mut [usize],
    anc: &'a mut [usize],
    live: &'a mut [bool],
    ax: &'a mut [f64],
}

impl Half<'_> {
    /// Columns `lo..at` and `at..hi`, borrowed from this one.
    fn split_at(&mut self, at: usize, sh: &Shared) -> (Half<'_>, Half<'_>) {
        let (c, l, e) = (at - self.lo, sh.lp[at] - sh.lp[self.lo], sh.ap[at] - sh.ap[self.lo]);
        let (lend0, lend1) = self.lend.split_at_mut(c);
        let (lmid0, lmid1) = self.lmid.split_at_mut(c);
        let (li0, li1) = self.li.split_at_mut(l);
        let (lx0, lx1) = self.lx.split_at_mut(l);
        let (d0, d1) = self.d.split_at_mut(c);
        let (dinv0, dinv1) = self.dinv.split_at_mut(c);
        let (et0, et1) = self.etree.split_at_mut(c);
        let (anc0, anc1) = self.anc.split_at_mut(c);
        let (live0, live1) = self.live.split_at_mut(e);
        let (ax0, ax1) = self.ax.split_at_mut(e);
        (
            Half {
                lo: self.lo,
                hi: at,
                lend: lend0,
                lmid: lmid0,
                li: li0,
                lx: lx0,
                d: d0,
                dinv: dinv0,
                etree: et0,
                anc: anc0,
                live: live0,
                ax: ax0,
            },
            Half {
                lo: at,
                hi: self.hi,
                lend: lend1,
                lmid: lmid1,
                li: li1,
                lx: lx1,
                d: d1,
                dinv: dinv1,
                etree: et1,
                anc: anc1,
                live: live1,
                ax: ax1,
            },
        )
    }

    /// Factor rows `lo..hi` (their entries all lie in columns `lo..hi`).
    fn rows(&mut self, sh: &Shared, w: &mut Work) -> bool {
        self.etree_rows(sh, self.lo..self.hi);
        for k in self.lo..self.hi {
            // Row k of L: solve L(0:k, 0:k) y = A(0:k, k), pattern from the etree.
            let mut nnz_y = 0;
            let dk = self.load_row(sh, k, self.lo, w, &mut nnz_y);
            let dk = self.eliminate::<false>(sh, k, nnz_y, dk, w);
            if !self.set_pivot(sh, k, dk) {
                return false;
            }
        }
        self.lmid.copy_from_slice(self.lend);
        true
    }

    /// Values, live entries and elimination tree of the live pattern for rows `ks`
    /// (Liu's algorithm with path compression; the rows' entries lie in columns
    /// `lo..`).
    fn etree_rows(&mut self, sh: &Shared, ks: std::ops::Range<usize>) {
        let (lo, pbase) = (self.lo, sh.ap[self.lo]);
        for k in ks {
            self.etree[k - lo] = NONE;
            self.anc[k - lo] = NONE;
            let ck = sh.pc[k];
            for p in sh.ap[k]..sh.ap[k + 1] {
                self.ax[p - pbase] = sh.val[sh.src[p]];
                let i0 = sh.ai[p] as usize;
                let live = ck && sh.pc[i0] && i0 != k;
                self.live[p - pbase] = live || i0 == k;
                if !live {
                    continue;
                }
                let mut i = i0;
                while i != NONE && i < k {
                    let next = self.anc[i - lo];
                    self.anc[i - lo] = k;
                    if next == NONE {
                        self.etree[i - lo] = k;
                    }
                    i = next;
                }
            }
        }
    }

    /// Row k's live entries in columns `from..k` into `w` (values and pattern); returns
    /// its diagonal.
    fn load_row(&self, sh: &Shared, k: usize, from: usize, w: &mut Work, nnz_y: &mut usize) -> f64 {
        let pbase = sh.ap[self.lo];
        let mut dk = 0.0;
        for p in sh.ap[k]..sh.ap[k + 1] {
            let b = sh.ai[p] as usize;
            if !self.live[p - pbase] || b < from {
                continue;
            }
            if b == k {
                dk = self.ax[p - pbase];
                continue;
            }
            w.y_vals[b] += self.ax[p - pbase];
            w.reach(b, k, self.etree, self.lo, nnz_y);
        }
        dk
    }

    /// Eliminate row k's pattern (`w.y_idx[..nnz_y]`, columns in `lo..hi`): scatter each
    /// column into the rows below, append L(k, c); returns the pivot less their share.
    /// With `SEP` (a half's part of a separator row) also record where the half's
    /// roots continue into the separator.
    #[inline]
    fn eliminate<const SEP: bool>(&mut self, sh: &Shared, k: usize, nnz_y: usize, mut dk: f64, w: &mut Work) -> f64 {
        let (lo, base) = (self.lo, sh.lp[self.lo]);
        let Half { lend, lmid, li, lx, dinv, etree, .. } = self;
        let Work { y_vals, y_used, y_idx, eidx, .. } = w;
        for &c in y_idx[..nnz_y].iter().rev() {
            let (s, end) = (sh.lp[c] - base, lend[c - lo] - base);
            let yc = y_vals[c];
            for (&r, &l) in li[s..end].iter().zip(&lx[s..end]) {
                y_vals[r as usize] -= l * yc;
            }
            // A root of the half's forest: its path continues at its first separator
            // row (if that lies before k).
            if SEP && etree[c - lo] == NONE && lmid[c - lo] - base < end {
                eidx.push(li[lmid[c - lo] - base]);
            }
            let lkc = yc * dinv[c - lo];
            li[end] = k as u32;
            lx[end] = lkc;
            dk -= yc * lkc;
            lend[c - lo] += 1;
            y_vals[c] = 0.0;
            y_used[c] = false;
        }
        dk
    }

    /// Store pivot k (regularized, see [`pivot`]); false if not finite.
    fn set_pivot(&mut self, sh: &Shared, k: usize, dk: f64) -> bool {
        match pivot(dk, sh.signs[k]) {
            Some(v) => {
                self.d[k - self.lo] = v;
                self.dinv[k - self.lo] = 1.0 / v;
                true
            }
            None => false,
        }
    }

    /// This half's part of every separator row k: the solve through its columns, whose
    /// entries of row k it appends, and the deltas that part adds to the separator's
    /// entries of row k and to its pivot (in `w`'s lists, for the caller to finish).
    /// (Live entries are judged from the coupled flags: the separator rows' own pass
    /// comes later.)
    fn separator(&mut self, sh: &Shared, w: &mut Work) {
        let ns = sh.n - sh.s1;
        sized(&mut w.tri, ns * ns.saturating_sub(1) / 2, 0.0);
        w.sd.clear();
        w.eptr.clear();
        w.eptr.push(0);
        w.eidx.clear();
        for k in sh.s1..sh.n {
            let t = k - sh.s1;
            let mut nnz_y = 0;
            if sh.pc[k] {
                for p in sh.ap[k]..sh.ap[k + 1] {
                    let b = sh.ai[p] as usize;
                    if b < self.lo || b >= self.hi || !sh.pc[b] {
                        continue;
                    }
                    w.y_vals[b] = sh.val[sh.src[p]];
                    w.reach(b, k, self.etree, self.lo, &mut nnz_y);
                }
            }
            // Into the half's rows and (this thread's copy of) the separator's, then
            // moved to the row's deltas.
            let dk = self.eliminate::<true>(sh, k, nnz_y, 0.0, w);
            let tri = &mut w.tri[t * (t + 1) / 2 - t..][..t];
            for (d, y) in tri.iter_mut().zip(&mut w.y_vals[sh.s1..k]) {
                *d = *y;
                *y = 0.0;
            }
            w.eptr.push(w.eidx.len());
            w.sd.push(dk);
        }
    }
}

impl Ldl {
    /// Solve in place for `k` right-hand sides at once: `x` holds them row-interleaved
    /// (entry i of right-hand side j at `x[i * k + j]`). Four at a time, so every entry
    /// of L read is applied to four values: about half a single solve's time each.
    pub fn solve_many(&mut self, x: &mut [f64], k: usize) {
        let n = self.order.len();
        let split = self.split_used();
        let mut w = vec![[0.0f64; 4]; n];
        let sep = if split[1] > 0 { n - split[1] } else { 0 };
        let mut acc = [vec![[0.0f64; 4]; sep], vec![[0.0f64; 4]; sep]];
        let f =
            Factor { lp: &self.lp, lmid: &self.lmid, lend: &self.lend, li: &self.li, lx: &self.lx, dinv: &self.dinv };
        for g in (0..k).step_by(4) {
            let kk = (k - g).min(4);
            for (t, &i) in self.order.iter().enumerate() {
                let mut v = [0.0; 4];
                v[..kk].copy_from_slice(&x[i * k + g..i * k + g + kk]);
                w[t] = v;
            }
            f.solve(split, &mut w, &mut acc);
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

/// `Σ val[t] · w[idx[t] − off]` for four right-hand sides, two partial sums each.
#[inline(always)]
fn dot4(idx: &[u32], val: &[f64], w: &[[f64; 4]], off: usize) -> [f64; 4] {
    let mut a = [0.0f64; 4];
    let mut b = [0.0f64; 4];
    let (ci, cv) = (idx.chunks_exact(2), val.chunks_exact(2));
    let (ti, tv) = (ci.remainder(), cv.remainder());
    for (i, v) in ci.zip(cv) {
        let (p, q) = (w[i[0] as usize - off], w[i[1] as usize - off]);
        for t in 0..4 {
            a[t] += v[0] * p[t];
            b[t] += v[1] * q[t];
        }
    }
    for (&i, &v) in ti.iter().zip(tv) {
        let p = w[i as usize - off];
        for t in 0..4 {
            a[t] += v * p[t];
        }
    }
    for t in 0..4 {
        a[t] += b[t];
    }
    a
}

/// `Σ val[t] · w[idx[t] − off]` with four partial sums: a triangular solve is a chain of such
/// short dot products, and one accumulator would serialize on the add latency.
#[inline(always)]
fn dot(idx: &[u32], val: &[f64], w: &[f64], off: usize) -> f64 {
    let mut a = [0.0f64; 4];
    let (ci, cv) = (idx.chunks_exact(4), val.chunks_exact(4));
    let (ti, tv) = (ci.remainder(), cv.remainder());
    for (i, v) in ci.zip(cv) {
        a[0] += v[0] * w[i[0] as usize - off];
        a[1] += v[1] * w[i[1] as usize - off];
        a[2] += v[2] * w[i[2] as usize - off];
        a[3] += v[3] * w[i[3] as usize - off];
    }
    let mut s = (a[0] + a[1]) + (a[2] + a[3]);
    for (&i, &v) in ti.iter().zip(tv) {
        s += v * w[i as usize - off];
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

/// Nested dissection by coordinates: a fill-reducing order of a pattern whose couplings
/// are mostly local in a plane (`xy[i]`: node i's position). Each set splits at the
/// median of its wider extent; the nodes of the side with fewer couplings across the cut
/// that have one form the separator, ordered after both halves. Nodes with more than
/// [`ND_DENSE`] × the median degree (couplings no cut can avoid) come last of all, in
/// increasing degree. Returns the order and the sizes of the top level's two halves
/// (uncoupled, first in the order), or `None` when the median degree exceeds
/// [`ND_LOCAL`] (the couplings are not local: use AMD).
///
/// On the identification QP's Everett grid it costs a fraction of AMD's time and fills
/// as little or less for sweeps, whose rows couple nearby Everett values (benchmark
/// record at n_h = 40: ordering 0.52 → 0.17 ms, factor entries within 2 %; n_h = 60 and
/// 100: 7 % and 17 % fewer). Random-walk inputs couple far-apart values (median degree
/// about 30 instead of 11–12), where it fills up to 25 % more than AMD.
pub fn nd_order(pat: &Pattern, xy: &[[u32; 2]]) -> Option<(Vec<usize>, [usize; 2])> {
    let n = pat.colptr.len() - 1;
    // Symmetric adjacency without the diagonal.
    let mut adjp = vec![0usize; n + 1];
    for j in 0..n {
        for &i in &pat.rowval[pat.colptr[j]..pat.colptr[j + 1]] {
            if i != j {
                adjp[i + 1] += 1;
                adjp[j + 1] += 1;
            }
        }
    }
    let deg: Vec<usize> = (0..n).map(|i| adjp[i + 1]).collect();
    let mut sorted = deg.clone();
    let median = if n > 0 { *sorted.select_nth_unstable(n / 2).1 } else { 0 };
    if median > ND_LOCAL {
        return None;
    }
    for i in 0..n {
        adjp[i + 1] += adjp[i];
    }
    let mut adj = vec![0u32; adjp[n]];
    let mut fill = adjp[..n].to_vec();
    for j in 0..n {
        for &i in &pat.rowval[pat.colptr[j]..pat.colptr[j + 1]] {
            if i != j {
                adj[fill[i]] = j as u32;
                fill[i] += 1;
                adj[fill[j]] = i as u32;
                fill[j] += 1;
            }
        }
    }
    let limit = (ND_DENSE * median).max(16);
    let mut dense: Vec<u32> = (0..n as u32).filter(|&i| deg[i as usize] > limit).collect();
    dense.sort_unstable_by_key(|&i| deg[i as usize]);
    let mut buf: Vec<u32> = (0..n as u32).filter(|&i| deg[i as usize] <= limit).collect();
    let mut out = Vec::with_capacity(n);
    let mut side = vec![0u8; n];
    let g = Graph { adjp: &adjp, adj: &adj, xy };
    let halves = g.dissect(&mut buf, &mut side, &mut out);
    out.extend(dense.iter().map(|&i| i as usize));
    Some((out, halves))
}

/// Nested dissection is used while the median degree is at most this.
const ND_LOCAL: usize = 20;
/// Nodes of more than this many times the median degree are ordered last.
const ND_DENSE: usize = 2;

struct Graph<'a> {
    adjp: &'a [usize],
    adj: &'a [u32],
    xy: &'a [[u32; 2]],
}

/// Sets at most this large are not split further.
const ND_LEAF: usize = 4;

impl Graph<'_> {
    /// Whether node v couples to a node of side `other` (low two bits of the mark).
    fn crosses(&self, v: u32, side: &[u8], other: u8) -> bool {
        let v = v as usize;
        self.adj[self.adjp[v]..self.adjp[v + 1]].iter().any(|&u| side[u as usize] & 3 == other)
    }

    /// Order `buf` (its nodes marked 0 in `side` on entry and on return) into `out`.
    /// Returns the sizes of the two halves (`[0, 0]` if not split): uncoupled, they
    /// come first in the order, then the separator.
    fn dissect(&self, buf: &mut [u32], side: &mut [u8], out: &mut Vec<usize>) -> [usize; 2] {
        if buf.len() <= ND_LEAF {
            out.extend(buf.iter().map(|&v| v as usize));
            return [0, 0];
        }
        let (mut lo, mut hi) = ([u32::MAX; 2], [0u32; 2]);
        for &v in buf.iter() {
            for d in 0..2 {
                lo[d] = lo[d].min(self.xy[v as usize][d]);
                hi[d] = hi[d].max(self.xy[v as usize][d]);
            }
        }
        let axis = usize::from(hi[1] - lo[1] > hi[0] - lo[0]);
        let mid = buf.len() / 2;
        buf.select_nth_unstable_by_key(mid, |&v| self.xy[v as usize][axis]);
        let med = self.xy[buf[mid] as usize][axis];
        // Side 1 below the median, 2 from it on (1 up to it if nothing lies below).
        let cut = if med > lo[axis] { med } else { med + 1 };
        for &v in buf.iter() {
            side[v as usize] = if self.xy[v as usize][axis] < cut { 1 } else { 2 };
        }
        // Bit 4: a coupling across the cut.
        let (mut b1, mut b2) = (0usize, 0usize);
        for &v in buf.iter() {
            let sv = side[v as usize];
            if self.crosses(v, side, 3 - sv) {
                side[v as usize] = sv | 4;
                if sv == 1 {
                    b1 += 1;
                } else {
                    b2 += 1;
                }
            }
        }
        let sep = if b2 <= b1 { 2u8 } else { 1u8 };
        // Partition in place: the other side, the separating side's inside, then its
        // boundary (the separator).
        let class = |m: u8| -> u8 {
            if m & 3 != sep {
                0
            } else if m & 4 == 0 {
                1
            } else {
                2
            }
        };
        let (mut lo_end, mut k, mut hi_start) = (0usize, 0usize, buf.len());
        while k < hi_start {
            match class(side[buf[k] as usize]) {
                0 => {
                    buf.swap(lo_end, k);
                    lo_end += 1;
                    k += 1;
                }
                1 => k += 1,
                _ => {
                    hi_start -= 1;
                    buf.swap(k, hi_start);
                }
            }
        }
        for &v in buf.iter() {
            side[v as usize] = 0;
        }
        let (n1, n2) = (lo_end, hi_start - lo_end);
        if n1 == 0 || n1 == buf.len() {
            // No cut (all nodes on one point): a leaf.
            out.extend(buf.iter().map(|&v| v as usize));
            return [0, 0];
        }
        let (a, rest) = buf.split_at_mut(n1);
        let (b, s) = rest.split_at_mut(n2);
        self.dissect(a, side, out);
        self.dissect(b, side, out);
        out.extend(s.iter().map(|&v| v as usize));
        [n1, n2]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A random quasi-definite matrix `[H, Bᵀ; B, −C]` (H, C positive definite) in upper
    /// CSC with every diagonal present, as (colptr, rowval, val).
    fn quasi_definite(n: usize, m: usize, seed: u64) -> (Vec<usize>, Vec<usize>, Vec<f64>) {
        quasi_definite_where(n, m, seed, |_, _| true)
    }

    /// [`quasi_definite`] with only the off-diagonal entries (i, j) that `keep` allows
    /// (still diagonally dominant).
    fn quasi_definite_where(
        n: usize,
        m: usize,
        seed: u64,
        keep: impl Fn(usize, usize) -> bool,
    ) -> (Vec<usize>, Vec<usize>, Vec<f64>) {
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
                if !dual_block && rnd() < 0.15 && keep(i, j) {
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
    /// `b − A x` with only the entries between coupled indices (all when `live` is None).
    fn residual(colptr: &[usize], rowval: &[usize], val: &[f64], live: Option<&[bool]>, b: &[f64], x: &[f64]) -> f64 {
        let on = |i: usize| live.is_none_or(|c| c[i]);
        let mut r = b.to_vec();
        for j in 0..b.len() {
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
        r.iter().fold(0.0f64, |a, v| a.max(v.abs()))
    }

    #[test]
    fn split_factorization_and_solves_equal_the_serial_ones() {
        // Indices in three parts, parts 0 and 1 uncoupled: ordered [0 | 1 | 2], the
        // factorization and the solves may run the first two on two threads.
        let (n, m) = (70, 45);
        let dim = n + m;
        let part = |i: usize| match (i * 7) % 10 {
            0..=3 => 0,
            4..=7 => 1,
            _ => 2,
        };
        let (colptr, rowval, val) = quasi_definite_where(n, m, 11, |i, j| part(i) + part(j) != 1);
        let pat = Pattern { colptr: &colptr, rowval: &rowval };
        // AMD's order, stably partitioned by part (a valid elimination order for both).
        let amd = amd_order(&pat).unwrap();
        let mut order: Vec<usize> = Vec::new();
        for q in 0..3 {
            order.extend(amd.iter().copied().filter(|&i| part(i) == q));
        }
        let n0 = (0..dim).filter(|&i| part(i) == 0).count();
        let n1 = (0..dim).filter(|&i| part(i) == 1).count();
        let signs: Vec<i8> = (0..dim).map(|i| if i < n { 1 } else { -1 }).collect();
        let mut serial = Ldl::new(&pat, &order, &signs);
        let mut split = Ldl::new(&pat, &order, &signs);
        split.set_split([n0, n0 + n1]);
        split.force_split = true;
        assert_eq!(split.split, [n0, n0 + n1]);
        // Not a valid split (empty half, separator empty): none.
        let mut other = Ldl::new(&pat, &order, &signs);
        other.set_split([0, n1]);
        assert_eq!(other.split, [0, 0]);
        other.set_split([n0, dim]);
        assert_eq!(other.split, [0, 0]);
        let b: Vec<f64> = (0..dim).map(|i| (i as f64 * 0.37).cos()).collect();
        let some: Vec<bool> = (0..dim).map(|i| i < n || i % 3 != 0).collect();
        let few: Vec<bool> = (0..dim).map(|i| i < n || i % 4 == 0).collect();
        // Several factorizations in the same buffers, with different live patterns.
        for live in [None, Some(&some[..]), Some(&few[..]), None] {
            assert!(serial.factor(&val, live));
            assert!(split.factor(&val, live));
            assert!(split.split_now && !serial.split_now);
            let (mut xs, mut xp) = (b.clone(), b.clone());
            serial.solve(&mut xs);
            split.solve(&mut xp);
            let scale = xs.iter().fold(0.0f64, |a, v| a.max(v.abs()));
            for (a, c) in xs.iter().zip(&xp) {
                assert!((a - c).abs() <= 1e-12 * scale, "{a} vs {c}");
            }
            let err = residual(&colptr, &rowval, &val, live, &b, &xp);
            assert!(err < 1e-12, "residual {err}");
            // The pivots agree too (the same elimination, summed in another order).
            for (d1, d2) in serial.d.iter().zip(&split.d) {
                assert!((d1 - d2).abs() <= 1e-12 * d1.abs().max(1.0));
            }
            // Six right-hand sides at once (four, then two), interleaved: each as alone.
            let k = 6;
            let mut many: Vec<f64> = (0..dim * k).map(|t| ((t * 7 % 13) as f64 - 6.0) * 0.1).collect();
            let rhs = many.clone();
            split.solve_many(&mut many, k);
            for j in 0..k {
                let mut one: Vec<f64> = (0..dim).map(|i| rhs[i * k + j]).collect();
                serial.solve(&mut one);
                for i in 0..dim {
                    assert!((many[i * k + j] - one[i]).abs() <= 1e-12 * scale.max(1.0), "rhs {j} row {i}");
                }
            }
        }
    }

    /// A k × k grid graph (5-point couplings, upper CSC) with one node coupled to all
    /// the others appended, and the grid positions.
    fn grid_with_a_hub(k: usize) -> (Vec<usize>, Vec<usize>, Vec<[u32; 2]>) {
        let n = k * k + 1;
        let (mut colptr, mut rowval) = (vec![0], Vec::new());
        for j in 0..n - 1 {
            let (a, b) = (j / k, j % k);
            if a > 0 {
                rowval.push(j - k);
            }
            if b > 0 {
                rowval.push(j - 1);
            }
            rowval.push(j);
            colptr.push(rowval.len());
        }
        rowval.extend(0..n);
        colptr.push(rowval.len());
        let mut xy: Vec<[u32; 2]> = (0..n - 1).map(|j| [(j / k) as u32, (j % k) as u32]).collect();
        xy.push([0, 0]);
        (colptr, rowval, xy)
    }

    #[test]
    fn nested_dissection_splits_a_grid_into_uncoupled_halves_and_fills_like_amd() {
        let k = 30;
        let (colptr, rowval, xy) = grid_with_a_hub(k);
        let n = colptr.len() - 1;
        let pat = Pattern { colptr: &colptr, rowval: &rowval };
        let (order, [h0, h1]) = nd_order(&pat, &xy).expect("local couplings");
        let mut sorted = order.clone();
        sorted.sort_unstable();
        assert_eq!(sorted, (0..n).collect::<Vec<_>>());
        assert_eq!(order[n - 1], n - 1, "the hub comes last");
        // Halves of similar size, a separator of about one grid line.
        assert!(h0.min(h1) * 3 >= h0.max(h1), "halves {h0}, {h1}");
        let sep = n - h0 - h1;
        assert!(sep > 1 && sep <= 2 * k + 1, "separator {sep}");
        let mut pos = vec![0; n];
        for (t, &i) in order.iter().enumerate() {
            pos[i] = t;
        }
        let half = |i: usize| {
            if pos[i] < h0 {
                0
            } else if pos[i] < h0 + h1 {
                1
            } else {
                2
            }
        };
        for j in 0..n {
            for &i in &rowval[colptr[j]..colptr[j + 1]] {
                assert!(half(i) + half(j) != 1, "{i} and {j} couple the halves");
            }
        }
        let signs = vec![1i8; n];
        let nd = Ldl::new(&pat, &order, &signs).full_nnz();
        let amd = Ldl::new(&pat, &amd_order(&pat).unwrap(), &signs).full_nnz();
        assert!(nd as f64 <= 1.3 * amd as f64, "fill {nd} vs AMD {amd}");
    }

    #[test]
    fn nested_dissection_declines_couplings_that_are_not_local() {
        // Every node coupled to 40 random others: a median degree far above ND_LOCAL.
        let n = 400;
        let mut s = 5u64;
        let (mut colptr, mut rowval) = (vec![0], Vec::new());
        for j in 0..n {
            let mut col: Vec<usize> = (0..40)
                .map(|_| {
                    s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                    (s >> 33) as usize % (j + 1)
                })
                .collect();
            col.push(j);
            col.sort_unstable();
            col.dedup();
            rowval.extend(col);
            colptr.push(rowval.len());
        }
        let xy: Vec<[u32; 2]> = (0..n).map(|j| [(j / 20) as u32, (j % 20) as u32]).collect();
        assert!(nd_order(&Pattern { colptr: &colptr, rowval: &rowval }, &xy).is_none());
    }
}
