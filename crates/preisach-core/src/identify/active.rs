//! Exact primal–dual active-set solver of the identification QP (`solver="active"`).
//!
//! The variables are those of the structured solver ([`super::qp::solve_everett`]): the
//! Everett values and the offset, with the masses (second differences, `D x`) >= 0. The
//! objective is sparse there (O(depth²) per row), so one equality-constrained step is one
//! sparse quasi-definite KKT solve:
//!
//! ```text
//!   [ H    D_Aᵀ ] [ x ]   [ −q ]      H, q: the least-squares objective ½xᵀHx + qᵀx
//!   [ D_A  0    ] [ ν ] = [  0 ]      A: masses guessed zero; multipliers λ = −ν
//! ```
//!
//! The primal–dual active-set method (Hintermüller, Ito & Kunisch, SIAM J. Optim. 13,
//! 2002) then moves to the guess {λ > 0} ∪ {mass < 0} and stops when the guess no longer
//! changes: that is exactly the KKT conditions of the convex QP, so the point is optimal,
//! with no interior-point tolerance to polish away. The KKT pattern holds every
//! constraint column; an inactive constraint's row is `−ν_c = 0`, decoupled. One
//! fill-reducing ordering of the full pattern serves every step ([`super::ldl`]): each
//! step factors only the coupled (active) constraints' fill under the induced order, a
//! third of the full pattern's work in the benchmark, then refines iteratively against
//! the unregularized matrix. A step that switches only a few constraints borders the
//! last factorization instead ([`Border`]: one triangular solve per switched
//! constraint, about half of one when solved four at a time).
//!
//! The ordering is a nested dissection of the Everett grid where the rows couple nearby
//! Everett values (sweeps; AMD otherwise, see [`Kkt::order`]). Its top level splits the
//! unknowns into two uncoupled halves and a separator, and every factorization and solve
//! then runs the halves on two threads ([`crate::pair`]) before the separator: at
//! n_h = 40 in the benchmark the whole solve takes 2.4–2.5 ms instead of 3.3 ms with AMD
//! on one thread (3.0–3.1 ms with the dissection on one thread).
//!
//! From "all masses free" the method needs a dozen or more factorizations on noisy
//! sweeps (14 at n_h = 40 in the benchmark). Without a caller's guess it therefore
//! starts from a few OSQP-style ADMM iterations on the same KKT pattern (values
//! `[H + σI, Dᵀ; D, −1/ρ]`: one numeric factorization, then only triangular solves)
//! and takes the cells ADMM left at zero as the first guess: 4 factorizations there.
//!
//! The large buffers (objective triplets, KKT matrix, factor) are kept per thread for
//! the next solve ([`Scratch`]): on the benchmark's VM a fresh 4 KiB page costs about
//! 2 µs on first touch, which was 0.4–0.5 ms of a 4.3 ms solve at n_h = 40. Only memory
//! is reused; every solve builds, orders and factors its own problem.
//!
//! Block switching can cycle when H is not an M-matrix (degenerate problems: many
//! unobserved Everett values, masses at zero with zero multipliers). When the number of
//! violated conditions has not fallen for a few steps, after a step cap, or if the
//! refined KKT residual is not small or not finite, it returns `None` and the caller
//! falls back to the interior point, so a failure costs a few factorizations. (Murty's
//! single-pivot rule would terminate, but one flip per factorization is slower than the
//! interior point.)

use super::ldl::{amd_order, nd_order, Ldl, Pattern};
#[cfg(test)]
use super::qp::everett_objective;
use super::qp::{everett_objective_into, Problem, Solution};
use super::rows::everett_var;
use crate::error::Result;
use std::cell::RefCell;

/// Bordering instead of refactoring (see [`Border`]): at most this many changed
/// constraints, and new ones only while their solves cost less than this share of a
/// refactorization.
const BORDER_MAX: usize = 48;
const BORDER_SHARE: f64 = 0.75;
/// Steps without fewer violated conditions before giving up.
const STALL_STEPS: u32 = 3;
/// Refinement passes per step (each is one pair of triangular solves).
const REFINE: usize = 6;
/// ADMM warm start: iterations, penalty (relative to the Hessian's mass diagonal) and
/// over-relaxation. Tuned on the benchmark sweep at n_h = 20…100: 30 iterations (about
/// the cost of two factorizations) cut the active-set steps from 11/14/22/31 to 2/4/8/9.
/// The result is only a guess: a poor one costs steps, never exactness.
const ADMM_ITERS: usize = 20;
const ADMM_RHO: f64 = 0.1;
const ADMM_ALPHA: f64 = 1.6;

/// The solver's large buffers, kept per thread for the next solve: fresh memory costs a
/// page fault per 4 KiB on first touch (about 2 µs each in the benchmark's VM, 0.5 ms of
/// a 4 ms solve at n_h = 40), reused memory none. Only the buffers are reused, never
/// values: every solve rebuilds and refactors from its own problem.
#[derive(Default)]
struct Scratch {
    trip: Vec<(u64, f64)>,
    bucket: Vec<(u32, f64)>,
    kkt: Kkt,
    fact: Ldl,
    kval: Vec<f64>,
}

/// Scratch larger than this is released after the solve rather than kept.
const SCRATCH_KEEP: usize = 32 << 20;

impl Scratch {
    fn bytes(&self) -> usize {
        16 * (self.trip.capacity() + self.bucket.capacity() + self.kkt.val.capacity())
            + 8 * (self.kval.capacity() + self.kkt.colptr.capacity() + self.kkt.rowval.capacity())
            + 8 * (self.kkt.reg.capacity() + self.kkt.diag.capacity() + self.kkt.dval.capacity())
            + self.fact.capacity_bytes()
    }
}

thread_local! {
    static SCRATCH: RefCell<Scratch> = RefCell::new(Scratch::default());
}

/// The KKT matrix (upper triangle, CSC) with the positions needed to switch a
/// constraint on or off.
#[derive(Default)]
struct Kkt {
    n: usize,
    m: usize,
    colptr: Vec<usize>,
    rowval: Vec<usize>,
    /// Values of the unregularized KKT matrix for the current active set.
    val: Vec<f64>,
    /// Regularization added on the diagonal for the factorization (per row/col).
    reg: Vec<f64>,
    /// Position of each diagonal entry in `val`.
    diag: Vec<usize>,
    /// Constraint coefficients (the D row of each mass), in column order.
    dval: Vec<f64>,
}

impl Kkt {
    #[cfg(test)]
    fn build(pb: &Problem, trip: Vec<(u64, f64)>) -> Self {
        let mut k = Kkt::default();
        k.build_in(pb, &trip, &mut Vec::new());
        k
    }

    /// Build from the objective's triplets in this matrix's buffers (`bucket`: scratch).
    fn build_in(&mut self, pb: &Problem, trip: &[(u64, f64)], bucket: &mut Vec<(u32, f64)>) {
        let n_q = pb.rows.n_vars();
        let n = n_q + 1;
        let m = n_q;
        // Bucket the triplets by column (a counting sort), then sum each column's
        // duplicates and sort its distinct rows: cheaper than one sort of all the
        // triplets.
        let mut start = vec![0usize; n + 1];
        for t in trip {
            start[(t.0 >> 32) as usize + 1] += 1;
        }
        for c in 0..n {
            start[c + 1] += start[c];
        }
        let mut next = start.clone();
        bucket.clear();
        bucket.resize(trip.len(), (0u32, 0.0f64));
        for &(k, v) in trip {
            let c = (k >> 32) as usize;
            bucket[next[c]] = ((k & 0xffff_ffff) as u32, v);
            next[c] += 1;
        }
        let Kkt { colptr, rowval, val, reg, diag, dval, .. } = self;
        colptr.clear();
        colptr.resize(n + m + 1, 0);
        rowval.clear();
        rowval.reserve(bucket.len() + n + 5 * m);
        val.clear();
        val.reserve(bucket.len() + n + 5 * m);
        // Duplicates are summed in a dense accumulator (`acc`, rows marked by `seen`),
        // so only the distinct rows are sorted: the offset's column holds a triplet per
        // row entry (thousands) but only n distinct rows. (Sorting the triplets was 40 %
        // of this build at n_h = 40.)
        let mut seen = vec![usize::MAX; n];
        let mut acc = vec![0.0f64; n];
        let mut list: Vec<usize> = Vec::new();
        for c in 0..n {
            list.clear();
            for &(r, v) in &bucket[start[c]..start[c + 1]] {
                let r = r as usize;
                if seen[r] == c {
                    acc[r] += v;
                } else {
                    seen[r] = c;
                    acc[r] = v;
                    list.push(r);
                }
            }
            // The diagonal, present even where no row observes the variable.
            if seen[c] != c {
                acc[c] = 0.0;
                list.push(c);
            }
            list.sort_unstable();
            for &r in &list {
                rowval.push(r);
                val.push(acc[r]);
            }
            colptr[c + 1] = rowval.len();
        }
        // The mass of cell (i, j) in Everett values, in increasing index order:
        // −E(j, i) + E(j, i+1) + E(j+1, i) − E(j+1, i+1) (see `mass_from_everett`; the
        // terms with a <= b vanish on and next to the diagonal).
        dval.clear();
        dval.reserve(4 * m);
        let mut c = 0;
        for i in 0..pb.rows.n_h {
            for j in i..pb.rows.n_h {
                let terms = [
                    (j > i, everett_var_or0(j, i), -1.0),
                    (j > i + 1, everett_var_or0(j, i + 1), 1.0),
                    (true, everett_var(j + 1, i), 1.0),
                    (j > i, everett_var_or0(j + 1, i + 1), -1.0),
                ];
                for &(present, k, v) in &terms {
                    if present {
                        rowval.push(k);
                        val.push(v);
                        dval.push(v);
                    }
                }
                rowval.push(n + c);
                val.push(0.0);
                colptr[n + c + 1] = rowval.len();
                c += 1;
            }
        }
        diag.clear();
        diag.extend((0..n + m).map(|c| colptr[c + 1] - 1));
        reg.clear();
        reg.resize(n + m, 0.0);
        self.n = n;
        self.m = m;
    }

    /// Fill-reducing elimination order, and the KKT positions where the top level's two
    /// uncoupled halves end (`[0, 0]`: no split). The order is computed on the pattern
    /// with the constraints eliminated (`H + DᵀD`, each mass a clique of its four
    /// Everett values: half the nodes, the same fill), each multiplier then placed just
    /// before the first of its Everett values. Its elimination creates exactly that
    /// clique, so the factor's fill is that of `H + DᵀD` plus four entries per
    /// constraint, as an order of the whole KKT pattern gives (±5 % with AMD on the
    /// benchmark sweeps and random inputs), in about 20 % less ordering time.
    ///
    /// On `H + DᵀD`: nested dissection by the Everett values' grid positions
    /// ([`nd_order`]) where the couplings are local, else AMD. On the benchmark record it
    /// takes 0.17 ms instead of AMD's 0.52 ms for about the same fill, and its halves
    /// let the factorizations run on two threads.
    fn order(&self) -> Result<(Vec<usize>, [usize; 2])> {
        let (n, m) = (self.n, self.m);
        let dcol = |c: usize| self.colptr[n + c]..self.colptr[n + c + 1] - 1;
        // Constraints touching each Everett value.
        let mut start = vec![0usize; n + 1];
        for c in 0..m {
            for p in dcol(c) {
                start[self.rowval[p] + 1] += 1;
            }
        }
        for i in 0..n {
            start[i + 1] += start[i];
        }
        let mut cons = vec![0usize; start[n]];
        let mut next = start.clone();
        for c in 0..m {
            for p in dcol(c) {
                let i = self.rowval[p];
                cons[next[i]] = c;
                next[i] += 1;
            }
        }
        // Upper triangle of H + DᵀD, rows sorted.
        let mut mark = vec![usize::MAX; n];
        let mut colptr = Vec::with_capacity(n + 1);
        let mut rowval = Vec::with_capacity(self.colptr[n] + 4 * m);
        colptr.push(0);
        for j in 0..n {
            let s0 = rowval.len();
            for &i in &self.rowval[self.colptr[j]..self.colptr[j + 1]] {
                mark[i] = j;
                rowval.push(i);
            }
            for &c in &cons[start[j]..start[j + 1]] {
                for p in dcol(c) {
                    let i = self.rowval[p];
                    if i < j && mark[i] != j {
                        mark[i] = j;
                        rowval.push(i);
                    }
                }
            }
            rowval[s0..].sort_unstable();
            colptr.push(rowval.len());
        }
        let pat = Pattern { colptr: &colptr, rowval: &rowval };
        // Nested dissection on the Everett grid's (a, b) positions where the couplings
        // are local, AMD where not (the offset, coupled to every value, comes last in both).
        let xy: Vec<[u32; 2]> = (0..n).map(|v| if v + 1 < n { everett_pos(v) } else { [0, 0] }).collect();
        let (xorder, halves) = match nd_order(&pat, &xy) {
            Some(o) => o,
            None => (amd_order(&pat)?, [0, 0]),
        };
        // Each multiplier just before the first of its Everett values.
        let mut pos = vec![0usize; n];
        for (k, &i) in xorder.iter().enumerate() {
            pos[i] = k;
        }
        let mut bstart = vec![0usize; n + 1];
        let first: Vec<usize> = (0..m)
            .map(|c| {
                let f = dcol(c).map(|p| self.rowval[p]).min_by_key(|&i| pos[i]).unwrap_or(n - 1);
                bstart[f + 1] += 1;
                f
            })
            .collect();
        for i in 0..n {
            bstart[i + 1] += bstart[i];
        }
        let mut before = vec![0usize; m];
        let mut bnext = bstart.clone();
        for (c, &f) in first.iter().enumerate() {
            before[bnext[f]] = n + c;
            bnext[f] += 1;
        }
        let mut order = Vec::with_capacity(n + m);
        let mut split = [0usize; 2];
        for (k, &i) in xorder.iter().enumerate() {
            order.extend_from_slice(&before[bstart[i]..bstart[i + 1]]);
            order.push(i);
            if k + 1 == halves[0] {
                split[0] = order.len();
            }
            if k + 1 == halves[0] + halves[1] {
                split[1] = order.len();
            }
        }
        if halves[0] == 0 || halves[1] == 0 {
            split = [0, 0];
        }
        Ok((order, split))
    }

    /// Set constraint `c` active (mass fixed to 0) or inactive (multiplier fixed to 0).
    fn set(&mut self, c: usize, active: bool, eps: f64) {
        let col = self.n + c;
        let (s, e) = (self.colptr[col], self.colptr[col + 1] - 1);
        let base = s - self.colptr[self.n] - c; // entries of D before this column
        for (p, k) in (s..e).zip(base..) {
            self.val[p] = if active { self.dval[k] } else { 0.0 };
        }
        self.val[e] = if active { 0.0 } else { -1.0 };
        self.reg[col] = if active { -eps } else { 0.0 };
    }

    /// Set constraint `c` to its ADMM row: `D_c x − ν_c / ρ_c` (the same pattern, so the
    /// same symbolic factorization serves both phases).
    fn set_admm(&mut self, c: usize, rho: f64) {
        let col = self.n + c;
        let (s, e) = (self.colptr[col], self.colptr[col + 1] - 1);
        let base = s - self.colptr[self.n] - c;
        for (p, k) in (s..e).zip(base..) {
            self.val[p] = self.dval[k];
        }
        self.val[e] = -1.0 / rho;
        self.reg[col] = 0.0;
    }

    /// `out = K v` with the unregularized values.
    fn mul(&self, v: &[f64], out: &mut [f64]) {
        out.iter_mut().for_each(|o| *o = 0.0);
        for j in 0..self.n + self.m {
            // Rows sorted, the diagonal last.
            let (s, d) = (self.colptr[j], self.diag[j]);
            let vj = v[j];
            let mut acc = self.val[d] * vj;
            for (&i, &a) in self.rowval[s..d].iter().zip(&self.val[s..d]) {
                out[i] += a * vj;
                acc += a * v[i];
            }
            out[j] += acc;
        }
    }

    /// Values with the regularization on the diagonal (what is factored).
    fn regularized(&self, out: &mut [f64]) {
        out.copy_from_slice(&self.val);
        for (c, &p) in self.diag.iter().enumerate() {
            out[p] += self.reg[c];
        }
    }
}

/// `[a, b]` of the Everett value with index `v` (the inverse of [`everett_var`]).
fn everett_pos(v: usize) -> [u32; 2] {
    // a(a − 1)/2 <= v < a(a + 1)/2.
    let mut a = ((1.0 + (1.0 + 8.0 * v as f64).sqrt()) / 2.0) as usize;
    while a * (a - 1) / 2 > v {
        a -= 1;
    }
    while a * (a + 1) / 2 <= v {
        a += 1;
    }
    [a as u32, (v - a * (a - 1) / 2) as u32]
}

/// `everett_var(a, b)`, or 0 where a <= b (a term the caller drops).
fn everett_var_or0(a: usize, b: usize) -> usize {
    if a > b {
        everett_var(a, b)
    } else {
        0
    }
}

/// Solve the identification QP exactly by the primal–dual active-set method, starting
/// from the guess `start` (cells believed to have zero mass; `None` = only the fixed
/// ones). `Ok(None)` means it did not converge within `max_steps` (use the interior
/// point instead).
pub fn solve_active(pb: &Problem, start: Option<Vec<bool>>, max_steps: u32) -> Result<Option<Solution>> {
    // (Taken, not borrowed: a nested solve would find it empty, never in use.)
    let mut scratch = SCRATCH.with(|s| s.take());
    let out = solve_in(pb, start, max_steps, &mut scratch);
    if scratch.bytes() <= SCRATCH_KEEP {
        SCRATCH.with(|s| *s.borrow_mut() = scratch);
    }
    out
}

fn solve_in(pb: &Problem, start: Option<Vec<bool>>, max_steps: u32, scratch: &mut Scratch) -> Result<Option<Solution>> {
    let n_q = pb.rows.n_vars();
    let Scratch { trip, bucket, kkt, fact, kval } = scratch;
    // The factorizations and solves below split over two threads: start the helper
    // spinning now, it takes tens of microseconds to wake.
    let _session = crate::pair::session();
    let q = everett_objective_into(pb, trip);
    kkt.build_in(pb, trip, bucket);
    let (n, m) = (kkt.n, kkt.m);
    let dim = n + m;
    let hmax = (0..n).map(|i| kkt.val[kkt.diag[i]]).fold(0.0f64, f64::max);
    if hmax <= 0.0 {
        return Ok(None);
    }
    // Static regularization of the quasi-definite matrix (removed again by the
    // refinement); 1e-9 let pivots of degenerate interpolated problems break down.
    let eps = 1e-8 * hmax;
    for i in 0..n {
        kkt.reg[i] = eps;
    }
    // Without a guess, a few ADMM iterations (one factorization, then only solves)
    // guess the active set: from there the active-set method needs a handful of steps
    // instead of a dozen or more from "all free".
    let warm = start.is_none() && n_q > 0;
    let mut active: Vec<bool> = match start {
        Some(mut a) if a.len() == pb.zero.len() => {
            a.iter_mut().zip(pb.zero).for_each(|(a, &z)| *a |= z);
            a
        }
        _ => pb.zero.to_vec(),
    };
    // Scale of the objective in mass coordinates: a relay column is ±1 like the
    // offset's, so the offset's diagonal is the masses' Hessian diagonal too.
    let hoff = kkt.val[kkt.diag[n_q]].max(1e-300);
    let (rho, sigma) = (ADMM_RHO * hoff, 1e-6 * hoff);
    if warm {
        for i in 0..n {
            kkt.reg[i] = sigma;
        }
        for c in 0..m {
            kkt.set_admm(c, if pb.zero[c] { 1e3 * rho } else { rho });
        }
    } else {
        for (c, &a) in active.iter().enumerate() {
            kkt.set(c, a, eps);
        }
    }
    kval.clear();
    kval.resize(kkt.val.len(), 0.0);
    kkt.regularized(kval);
    let mut signs = vec![1i8; dim];
    signs[n..].iter_mut().for_each(|s| *s = -1);
    let (order, split) = kkt.order()?;
    fact.analyze(&Pattern { colptr: &kkt.colptr, rowval: &kkt.rowval }, &order, &signs);
    fact.set_split(split);
    if warm {
        if !fact.factor(kval, None) {
            return Ok(None);
        }
        let z = admm_masses(kkt, fact, &q, pb.zero, rho, sigma);
        for c in 0..m {
            active[c] = pb.zero[c] || z[c] <= 0.0;
        }
        for i in 0..n {
            kkt.reg[i] = eps;
        }
        for (c, &a) in active.iter().enumerate() {
            kkt.set(c, a, eps);
        }
    }
    let mut coupled = vec![true; dim];

    let qmax = q.iter().fold(0.0f64, |a, v| a.max(v.abs())).max(1e-300);
    let mut b = vec![0.0; dim];
    for i in 0..n {
        b[i] = -q[i];
    }
    let mut v = vec![0.0; dim];
    let mut best = vec![0.0; dim];
    let mut r = vec![0.0; dim];
    let mut kv = vec![0.0; dim];
    let mut w = vec![0.0; m];
    let mut best_inf = usize::MAX;
    let mut stall = 0;
    // Active set of the matrix last factored (None: none yet for the active-set steps).
    let mut base: Option<Vec<bool>> = None;
    let mut border = Border::default();
    for step in 1..=max_steps {
        // Few constraints changed since the last factorization: border it instead.
        let changed: Vec<usize> = match &base {
            Some(b0) => (0..m).filter(|&c| b0[c] != active[c]).collect(),
            None => Vec::new(),
        };
        // New border columns are solved four at a time, at about two solves' cost.
        let new = changed.iter().filter(|&&c| !border.has(c)).count();
        let cost = 2.0 * new.div_ceil(4) as f64;
        let bordered = base.is_some()
            && changed.len() <= BORDER_MAX
            && cost < BORDER_SHARE * fact.refactor_in_solves()
            // (A singular Schur complement: refactor instead.)
            && border.update(&changed, &active, kkt, fact, eps);
        if !bordered {
            // Only the active constraints' rows: an inactive one is `−ν_c = 0`, decoupled.
            coupled[n..].copy_from_slice(&active);
            kkt.regularized(kval);
            if !fact.factor(kval, Some(&coupled)) {
                return Ok(None);
            }
            base = Some(active.clone());
            border.clear();
        }
        v.copy_from_slice(&b);
        border.solve(kkt, fact, &mut v);
        // Iterative refinement against the unregularized matrix: to 1e-9 while the step
        // is only a guess to correct (the signs decide), to 1e-13 once it satisfies
        // every condition. Where that matrix is singular (Everett values no row
        // observes, masses free), refinement need not contract: keep the best iterate
        // and stop as soon as the residual grows.
        let mut res = residual(kkt, &b, &v, &mut kv, &mut r);
        let (mut tol_w, mut tol_l): (f64, f64);
        let mut pass = 0;
        let mut stuck = false;
        let mut tight = false;
        let n_inf = loop {
            let target = if tight { 1e-13 } else { 1e-9 } * qmax;
            while res > target && pass < REFINE && !stuck && res.is_finite() {
                best.copy_from_slice(&v);
                border.solve(kkt, fact, &mut r);
                v.iter_mut().zip(&r).for_each(|(x, d)| *x += d);
                pass += 1;
                let rn = residual(kkt, &b, &v, &mut kv, &mut r);
                // A NaN must not pass (`rn >= res` is false for it).
                if rn.is_nan() || rn >= res {
                    v.copy_from_slice(&best);
                    stuck = true;
                } else {
                    res = rn;
                }
            }
            if !res.is_finite() {
                return Ok(None);
            }
            // Masses of the inactive cells and multipliers of the active ones.
            let mut wmax = 0.0f64;
            let mut lmax = 0.0f64;
            for c in 0..m {
                let col = n + c;
                let mut s = 0.0;
                for p in kkt.colptr[col]..kkt.colptr[col + 1] - 1 {
                    let k = p - kkt.colptr[n] - c;
                    s += kkt.dval[k] * v[kkt.rowval[p]];
                }
                w[c] = s;
                if active[c] {
                    lmax = lmax.max(v[col].abs());
                } else {
                    wmax = wmax.max(s.abs());
                }
            }
            tol_w = 1e-10 * wmax.max(1e-300);
            tol_l = 1e-10 * lmax.max(qmax);
            // Violations: active with a negative multiplier (λ = −ν), inactive with a
            // negative mass.
            let mut n_inf = 0;
            for c in 0..m {
                if pb.zero[c] {
                    continue;
                }
                let bad = if active[c] { -v[n + c] < -tol_l } else { w[c] < -tol_w };
                if bad {
                    n_inf += 1;
                }
            }
            if n_inf == 0 && !tight && !stuck && pass < REFINE && res > 1e-13 * qmax {
                tight = true;
                continue;
            }
            break n_inf;
        };
        if n_inf == 0 {
            if res > 1e-7 * qmax {
                return Ok(None);
            }
            let masses: Vec<f64> = (0..m).map(|c| if active[c] { 0.0 } else { (w[c] * pb.scale).max(0.0) }).collect();
            return Ok(Some(Solution { masses, offset: v[n_q] * pb.scale + pb.mu, iterations: step }));
        }
        if n_inf < best_inf {
            best_inf = n_inf;
            stall = 0;
        } else {
            stall += 1;
            if stall > STALL_STEPS {
                // Cycling (H is not an M-matrix): the interior point settles it.
                return Ok(None);
            }
        }
        for c in 0..m {
            if pb.zero[c] {
                continue;
            }
            let flip = if active[c] { -v[n + c] < -tol_l } else { w[c] < -tol_w };
            if flip {
                active[c] = !active[c];
                kkt.set(c, active[c], eps);
            }
        }
    }
    Ok(None)
}

/// Solves with the KKT matrix of the current active set from the factorization `K₀` of an
/// earlier one. Each constraint whose state changed borders `K₀` with one row and column
/// (a constraint switched on: its row `D_c x − ε μ = r_c` with the new multiplier μ; one
/// switched off: `ν_c = 0` on the factored multiplier, whose own row is then absorbed,
/// the true multiplier being decoupled), and the bordered system is solved through the
/// small dense Schur complement `S = C − Bᵀ K₀⁻¹ B`: one triangular solve per new
/// constraint instead of a refactorization when a step changes only a few.
#[derive(Default)]
struct Border {
    /// Changed constraint, switched on (else off), `K₀⁻¹ B` column.
    cols: Vec<(usize, bool, Vec<f64>)>,
    /// LU factors of S (row-major) and the row permutation.
    lu: Vec<f64>,
    piv: Vec<usize>,
    t: Vec<f64>,
}

impl Border {
    fn has(&self, c: usize) -> bool {
        self.cols.iter().any(|e| e.0 == c)
    }

    fn clear(&mut self) {
        self.cols.clear();
    }

    /// `Bᵀ_j v` for border column j.
    fn bt(kkt: &Kkt, c: usize, on: bool, v: &[f64]) -> f64 {
        let col = kkt.n + c;
        if on {
            let mut s = 0.0;
            for p in kkt.colptr[col]..kkt.colptr[col + 1] - 1 {
                s += kkt.dval[p - kkt.colptr[kkt.n] - c] * v[kkt.rowval[p]];
            }
            s
        } else {
            v[col]
        }
    }

    /// Border the factored matrix with the constraints in `changed` (their states now
    /// `active`). Returns false if the Schur complement is singular.
    fn update(&mut self, changed: &[usize], active: &[bool], kkt: &Kkt, fact: &mut Ldl, eps: f64) -> bool {
        self.cols.retain(|e| changed.contains(&e.0));
        let dim = kkt.n + kkt.m;
        let fresh: Vec<usize> = changed.iter().copied().filter(|&c| !self.has(c)).collect();
        let kn = fresh.len();
        if kn > 0 {
            // K₀⁻¹ B for the new columns, all at once.
            let mut x = vec![0.0; dim * kn];
            for (j, &c) in fresh.iter().enumerate() {
                let col = kkt.n + c;
                if active[c] {
                    for p in kkt.colptr[col]..kkt.colptr[col + 1] - 1 {
                        x[kkt.rowval[p] * kn + j] = kkt.dval[p - kkt.colptr[kkt.n] - c];
                    }
                } else {
                    x[col * kn + j] = 1.0;
                }
            }
            fact.solve_many(&mut x, kn);
            for (j, &c) in fresh.iter().enumerate() {
                let w: Vec<f64> = (0..dim).map(|i| x[i * kn + j]).collect();
                self.cols.push((c, active[c], w));
            }
        }
        let k = self.cols.len();
        self.lu.clear();
        self.lu.resize(k * k, 0.0);
        for (i, (ci, oni, _)) in self.cols.iter().enumerate() {
            for (j, (_, _, wj)) in self.cols.iter().enumerate() {
                self.lu[i * k + j] = -Self::bt(kkt, *ci, *oni, wj);
            }
            if *oni {
                self.lu[i * k + i] -= eps;
            }
        }
        // LU with partial pivoting.
        self.piv.clear();
        self.piv.extend(0..k);
        for j in 0..k {
            let p = (j..k).max_by(|&a, &b| self.lu[a * k + j].abs().total_cmp(&self.lu[b * k + j].abs())).unwrap();
            if self.lu[p * k + j] == 0.0 || !self.lu[p * k + j].is_finite() {
                return false;
            }
            if p != j {
                for t in 0..k {
                    self.lu.swap(j * k + t, p * k + t);
                }
                self.piv.swap(j, p);
            }
            let d = self.lu[j * k + j];
            for i in j + 1..k {
                let f = self.lu[i * k + j] / d;
                self.lu[i * k + j] = f;
                for t in j + 1..k {
                    self.lu[i * k + t] -= f * self.lu[j * k + t];
                }
            }
        }
        true
    }

    /// Solve in place with the current active set's (regularized) KKT matrix.
    fn solve(&mut self, kkt: &Kkt, fact: &mut Ldl, x: &mut [f64]) {
        let k = self.cols.len();
        if k == 0 {
            fact.solve(x);
            return;
        }
        // Right-hand sides of the border rows; the factored multipliers of changed
        // constraints are dummies with right-hand side 0.
        let n = kkt.n;
        let g: Vec<f64> = self.cols.iter().map(|&(c, on, _)| if on { x[n + c] } else { 0.0 }).collect();
        let off: Vec<f64> = self.cols.iter().map(|&(c, _, _)| -x[n + c]).collect();
        for &(c, _, _) in &self.cols {
            x[n + c] = 0.0;
        }
        fact.solve(x);
        self.t.clear();
        for (j, (c, on, _)) in self.cols.iter().enumerate() {
            self.t.push(g[j] - Self::bt(kkt, *c, *on, x));
        }
        // μ = S⁻¹ t.
        let mut mu: Vec<f64> = self.piv.iter().map(|&p| self.t[p]).collect();
        for i in 0..k {
            for j in 0..i {
                mu[i] -= self.lu[i * k + j] * mu[j];
            }
        }
        for i in (0..k).rev() {
            for j in i + 1..k {
                mu[i] -= self.lu[i * k + j] * mu[j];
            }
            mu[i] /= self.lu[i * k + i];
        }
        for (j, (_, _, w)) in self.cols.iter().enumerate() {
            x.iter_mut().zip(w).for_each(|(xi, wi)| *xi -= mu[j] * wi);
        }
        for (j, &(c, on, _)) in self.cols.iter().enumerate() {
            x[n + c] = if on { mu[j] } else { off[j] };
        }
    }
}

/// `r = b − K v` (unregularized K); returns ‖r‖∞, NaN if any entry is NaN.
fn residual(kkt: &Kkt, b: &[f64], v: &[f64], kv: &mut [f64], r: &mut [f64]) -> f64 {
    kkt.mul(v, kv);
    let mut rn = 0.0f64;
    for ((ri, &bi), &ki) in r.iter_mut().zip(b).zip(kv.iter()) {
        *ri = bi - ki;
        // A NaN must propagate (f64::max would drop it).
        if ri.is_nan() || ri.abs() > rn {
            rn = ri.abs();
        }
    }
    rn
}

/// OSQP-style ADMM on `min ½xᵀHx + qᵀx` s.t. `D x = z`, `z >= 0` (`z = 0` on the fixed
/// cells), with `fact` holding `[H + σI, Dᵀ; D, −1/ρ]`. Returns the masses `z` after
/// [`ADMM_ITERS`] iterations (zero where the guess is "active").
fn admm_masses(kkt: &Kkt, fact: &mut Ldl, q: &[f64], zero: &[bool], rho: f64, sigma: f64) -> Vec<f64> {
    let (n, m) = (kkt.n, kkt.m);
    let mut x = vec![0.0; n];
    let mut z = vec![0.0; m];
    let mut y = vec![0.0; m];
    let mut rhs = vec![0.0; n + m];
    // Penalty per constraint (the fixed cells' equality 1000× stiffer) and its inverse:
    // no division in the loop.
    let rc: Vec<f64> = zero.iter().map(|&zc| if zc { 1e3 * rho } else { rho }).collect();
    let ic: Vec<f64> = rc.iter().map(|r| 1.0 / r).collect();
    for _ in 0..ADMM_ITERS {
        for i in 0..n {
            rhs[i] = sigma * x[i] - q[i];
        }
        for c in 0..m {
            rhs[n + c] = z[c] - y[c] * ic[c];
        }
        fact.solve(&mut rhs);
        for i in 0..n {
            x[i] = ADMM_ALPHA * rhs[i] + (1.0 - ADMM_ALPHA) * x[i];
        }
        for c in 0..m {
            let zt = z[c] + (rhs[n + c] - y[c]) * ic[c];
            let zh = ADMM_ALPHA * zt + (1.0 - ADMM_ALPHA) * z[c];
            let zn = if zero[c] { 0.0 } else { (zh + y[c] * ic[c]).max(0.0) };
            y[c] += rc[c] * (zh - zn);
            z[c] = zn;
        }
    }
    z
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::Grid;
    use crate::identify::rows::build_rows;

    #[test]
    fn everett_positions_invert_the_variable_index() {
        for a in 1..=300usize {
            for b in 0..a {
                assert_eq!(everett_pos(everett_var(a, b)), [a as u32, b as u32]);
            }
        }
    }

    #[test]
    fn bordered_solve_equals_a_refactorization_after_constraints_switch() {
        // A small noisy identification problem; factor the KKT matrix of one active set,
        // switch some constraints on and some off, and solve both ways.
        let n_h = 12;
        let grid = Grid::new(0.0, 1.0, n_h).unwrap();
        let n = 20_000;
        let u: Vec<f64> = (0..n)
            .map(|k| {
                let t = k as f64 / n as f64;
                0.5 + 0.5 * t * (60.0 * t).sin() + 0.01 * (k as f64 * 1.7).sin()
            })
            .collect();
        let y: Vec<f64> = u.iter().enumerate().map(|(k, x)| x * x + 0.01 * (k as f64 * 0.37).cos()).collect();
        let rows = build_rows(&grid, &u, &y, false);
        let zero = vec![false; grid.n_q()];
        let pb = Problem { rows: &rows, mu: 0.5, scale: 1.0, zero: &zero, reg: 0.0 };
        let (trip, _) = everett_objective(&pb);
        let mut kkt = Kkt::build(&pb, trip);
        let (nv, m) = (kkt.n, kkt.m);
        let dim = nv + m;
        let eps = 1e-6;
        for i in 0..nv {
            kkt.reg[i] = eps;
        }
        let mut active: Vec<bool> = (0..m).map(|c| c % 3 == 0).collect();
        for (c, &a) in active.iter().enumerate() {
            kkt.set(c, a, eps);
        }
        let signs: Vec<i8> = (0..dim).map(|i| if i < nv { 1 } else { -1 }).collect();
        let pat = Pattern { colptr: &kkt.colptr.clone(), rowval: &kkt.rowval.clone() };
        let order = amd_order(&pat).unwrap();
        let mut fact = Ldl::new(&pat, &order, &signs);
        let mut kval = vec![0.0; kkt.val.len()];
        let mut coupled = vec![true; dim];
        coupled[nv..].copy_from_slice(&active);
        kkt.regularized(&mut kval);
        assert!(fact.factor(&kval, Some(&coupled)));
        // Switch constraints both ways.
        let changed = [1usize, 3, 5, 9, 20, 31];
        for &c in &changed {
            active[c] = !active[c];
            kkt.set(c, active[c], eps);
        }
        let mut border = Border::default();
        assert!(border.update(&changed, &active, &kkt, &mut fact, eps));
        let rhs: Vec<f64> = (0..dim).map(|i| (i as f64 * 0.61).sin()).collect();
        let mut xb = rhs.clone();
        border.solve(&kkt, &mut fact, &mut xb);
        let mut direct = Ldl::new(&pat, &order, &signs);
        coupled[nv..].copy_from_slice(&active);
        kkt.regularized(&mut kval);
        assert!(direct.factor(&kval, Some(&coupled)));
        let mut xd = rhs.clone();
        direct.solve(&mut xd);
        let scale = xd.iter().fold(0.0f64, |a, v| a.max(v.abs()));
        for (a, b) in xb.iter().zip(&xd) {
            assert!((a - b).abs() <= 1e-10 * scale, "{a} vs {b}");
        }
    }
}
