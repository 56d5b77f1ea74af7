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
//! with no interior-point tolerance to polish away. Every KKT system is factored by
//! clarabel's QDLDL ([`factor`]) in one fill-reducing order per solve ([`Kkt::order`]).
//! An inactive constraint's row is `−ν_c = 0`, decoupled, so a step factors only its
//! active constraints' couplings, then refines iteratively against the unregularized
//! matrix. A step that switches only a few constraints borders the last factorization
//! instead ([`Border`]: one triangular solve per switched constraint).
//!
//! From "all masses free" the method needs a dozen or more factorizations on noisy
//! sweeps (14 at n_h = 40 in the benchmark). Without a caller's guess it therefore
//! starts from a few OSQP-style ADMM iterations on the same KKT pattern (values
//! `[H + σI, Dᵀ; D, −1/ρ]`: one numeric factorization, then only triangular solves)
//! and takes the cells ADMM left at zero as the first guess: 4 factorizations there.
//!
//! Block switching can cycle when H is not an M-matrix (degenerate problems: many
//! unobserved Everett values, masses at zero with zero multipliers). When the number of
//! violated conditions has not fallen for a few steps, after a step cap, or if the
//! refined KKT residual is not small or not finite, it returns `None` and the caller
//! falls back to the interior point, so a failure costs a few factorizations. (Murty's
//! single-pivot rule would terminate, but one flip per factorization is slower than the
//! interior point.)

use clarabel::algebra::CscMatrix;
use clarabel::qdldl::{QDLDLError, QDLDLFactorisation, QDLDLSettingsBuilder};

use super::order::{amd_order, nd_order, Pattern};
use super::qp::{cell_coords, csc_upper, everett_objective, key, Problem, Solution};
use super::rows::{everett_coords, mass_from_everett};
use crate::error::{PreisachError, Result};

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

/// The KKT matrix (upper triangle, CSC) with the positions needed to switch a
/// constraint on or off.
#[derive(Default)]
pub(super) struct Kkt {
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
    /// The KKT matrix of the objective (its triplets, see [`everett_objective`]) with
    /// every constraint column, all constraints inactive.
    pub(super) fn build(pb: &Problem, mut trip: Vec<(u64, f64)>) -> Result<Self> {
        let n = pb.rows.n_vars() + 1;
        let m = n - 1;
        // Column n + c: the mass of cell c in Everett values, then the multiplier's
        // diagonal (added by `csc_upper`, the last entry of the column).
        let mut d = Vec::new();
        for (c, &(i, j)) in cell_coords(pb.rows.n_h).iter().enumerate() {
            mass_from_everett(i, j, &mut d);
            trip.extend(d.iter().map(|&(k, v)| (key(k, n + c), v)));
        }
        let a = csc_upper(n + m, trip)?;
        let diag: Vec<usize> = a.colptr[1..].iter().map(|&p| p - 1).collect();
        let dval = (n..n + m).flat_map(|c| a.nzval[a.colptr[c]..diag[c]].iter().copied()).collect();
        let mut kkt = Kkt { n, m, colptr: a.colptr, rowval: a.rowval, val: a.nzval, reg: vec![0.0; n + m], diag, dval };
        for c in 0..m {
            kkt.set(c, false, 0.0);
        }
        Ok(kkt)
    }

    /// The objective's Hessian H (upper triangle, CSC): the first n columns.
    pub(super) fn hessian(&self) -> CscMatrix<f64> {
        let (n, nnz) = (self.n, self.colptr[self.n]);
        CscMatrix::new(n, n, self.colptr[..=n].to_vec(), self.rowval[..nnz].to_vec(), self.val[..nnz].to_vec())
    }

    /// Fill-reducing elimination order of the KKT matrix. It is computed on the pattern
    /// with the constraints eliminated (`H + DᵀD`, each mass a clique of its four
    /// Everett values: half the nodes, the same fill), each multiplier then placed just
    /// before the first of its Everett values. Its elimination creates exactly that
    /// clique, so the factor's fill is that of `H + DᵀD` plus four entries per
    /// constraint, as an order of the whole KKT pattern gives.
    ///
    /// On `H + DᵀD`: nested dissection by the Everett values' grid positions
    /// ([`nd_order`]) where the couplings are local, as sweeps make them, else AMD. On
    /// the benchmark sweeps it takes the solve from 6.2 to 5.6 ms at n_h = 40 and from
    /// 27.9 to 23.8 ms at n_h = 60 against AMD on `H + DᵀD` (QDLDL's own AMD order of
    /// the whole KKT pattern: 6.2 and 28.3 ms).
    fn order(&self) -> Result<Vec<usize>> {
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
        let xy: Vec<[u32; 2]> = (0..n)
            .map(|v| {
                let (a, b) = if v + 1 < n { everett_coords(v) } else { (0, 0) };
                [a as u32, b as u32]
            })
            .collect();
        let xorder = match nd_order(&pat, &xy) {
            Some((o, _)) => o,
            None => amd_order(&pat)?,
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
        for &i in &xorder {
            order.extend_from_slice(&before[bstart[i]..bstart[i + 1]]);
            order.push(i);
        }
        Ok(order)
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

/// Solve the identification QP exactly by the primal–dual active-set method, starting
/// from the guess `start` (cells believed to have zero mass; `None` = only the fixed
/// ones). `Ok(None)` means it did not converge within `max_steps` (use the interior
/// point instead).
pub fn solve_active(pb: &Problem, start: Option<Vec<bool>>, max_steps: u32) -> Result<Option<Solution>> {
    let (trip, q) = everett_objective(pb);
    solve_kkt(pb, Kkt::build(pb, trip)?, &q, start, max_steps)
}

/// [`solve_active`] from the problem's KKT matrix (all constraints inactive) and the
/// objective's linear term `q`.
pub(super) fn solve_kkt(
    pb: &Problem,
    mut kkt: Kkt,
    q: &[f64],
    start: Option<Vec<bool>>,
    max_steps: u32,
) -> Result<Option<Solution>> {
    let n_q = pb.rows.n_vars();
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
    let mut kval = vec![0.0; kkt.val.len()];
    let order = kkt.order()?;
    if warm {
        // Scale of the objective in mass coordinates: a relay column is ±1 like the
        // offset's, so the offset's diagonal is the masses' Hessian diagonal too.
        let hoff = kkt.val[kkt.diag[n_q]].max(1e-300);
        let (rho, sigma) = (ADMM_RHO * hoff, 1e-6 * hoff);
        for i in 0..n {
            kkt.reg[i] = sigma;
        }
        for c in 0..m {
            kkt.set_admm(c, if pb.zero[c] { 1e3 * rho } else { rho });
        }
        kkt.regularized(&mut kval);
        let Some(mut f) = factor(&kkt, &kval, None, &order)? else { return Ok(None) };
        let z = admm_masses(&kkt, &mut f, q, pb.zero, rho, sigma);
        for c in 0..m {
            active[c] = pb.zero[c] || z[c] <= 0.0;
        }
        for i in 0..n {
            kkt.reg[i] = eps;
        }
    }
    for (c, &a) in active.iter().enumerate() {
        kkt.set(c, a, eps);
    }

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
    // The last factorization and its active set (none yet).
    let mut fact: Option<Fact> = None;
    let mut base: Option<Vec<bool>> = None;
    let mut border = Border::default();
    for step in 1..=max_steps {
        // Few constraints changed since the last factorization: border it instead.
        let changed: Vec<usize> = match &base {
            Some(b0) => (0..m).filter(|&c| b0[c] != active[c]).collect(),
            None => Vec::new(),
        };
        // One solve per new border column.
        let new = changed.iter().filter(|&&c| !border.has(c)).count();
        let bordered = match (&base, &mut fact) {
            (Some(_), Some(f)) => {
                changed.len() <= BORDER_MAX
                    && (new as f64) < BORDER_SHARE * refactor_in_solves(f)
                    // (A singular Schur complement: refactor instead.)
                    && border.update(&changed, &active, &kkt, f, eps)
            }
            _ => false,
        };
        if !bordered {
            kkt.regularized(&mut kval);
            let Some(f) = factor(&kkt, &kval, Some(&active), &order)? else { return Ok(None) };
            fact = Some(f);
            base = Some(active.clone());
            border.clear();
        }
        let Some(fact) = fact.as_mut() else { return Ok(None) };
        v.copy_from_slice(&b);
        border.solve(&kkt, fact, &mut v);
        // Iterative refinement against the unregularized matrix: to 1e-9 while the step
        // is only a guess to correct (the signs decide), to 1e-13 once it satisfies
        // every condition. Where that matrix is singular (Everett values no row
        // observes, masses free), refinement need not contract: keep the best iterate
        // and stop as soon as the residual grows.
        let mut res = residual(&kkt, &b, &v, &mut kv, &mut r);
        let (mut tol_w, mut tol_l): (f64, f64);
        let mut pass = 0;
        let mut stuck = false;
        let mut tight = false;
        let n_inf = loop {
            let target = if tight { 1e-13 } else { 1e-9 } * qmax;
            while res > target && pass < REFINE && !stuck && res.is_finite() {
                best.copy_from_slice(&v);
                border.solve(&kkt, fact, &mut r);
                v.iter_mut().zip(&r).for_each(|(x, d)| *x += d);
                pass += 1;
                let rn = residual(&kkt, &b, &v, &mut kv, &mut r);
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

/// Clarabel's QDLDL factorization of a quasi-definite matrix.
type Fact = QDLDLFactorisation<f64>;

/// Factor the KKT matrix with values `kval` in the elimination order `order` (pivot k is
/// index `order[k]`), coupling only the constraints in `coupled` (all when `None`): an
/// uncoupled constraint's row is `−ν_c = 0`, so its couplings are left out of the
/// pattern, and a step's factorization costs what its active constraints' system costs
/// (QDLDL's symbolic analysis, an elimination tree, is cheap next to it). `None` on a
/// zero or non-finite pivot.
fn factor(kkt: &Kkt, kval: &[f64], coupled: Option<&[bool]>, order: &[usize]) -> Result<Option<Fact>> {
    let (n, dim) = (kkt.n, kkt.n + kkt.m);
    let mut colptr = Vec::with_capacity(dim + 1);
    let mut rowval = Vec::with_capacity(kkt.rowval.len());
    let mut nzval = Vec::with_capacity(kkt.rowval.len());
    colptr.push(0);
    for j in 0..dim {
        let (s, d) = (kkt.colptr[j], kkt.diag[j]);
        let s = if j < n || coupled.is_none_or(|a| a[j - n]) { s } else { d };
        rowval.extend_from_slice(&kkt.rowval[s..=d]);
        nzval.extend_from_slice(&kval[s..=d]);
        colptr.push(rowval.len());
    }
    let mat = CscMatrix::new(dim, dim, colptr, rowval, nzval);
    let signs = (0..dim).map(|i| if i < n { 1 } else { -1 }).collect();
    let settings = QDLDLSettingsBuilder::default()
        .Dsigns(signs)
        .perm(order.to_vec())
        .build()
        .map_err(|e| PreisachError::Solver(format!("qdldl settings: {e}")))?;
    match QDLDLFactorisation::new(&mat, Some(settings)) {
        Ok(f) if f.D.iter().all(|d| d.is_finite()) => Ok(Some(f)),
        Ok(_) | Err(QDLDLError::ZeroPivot) => Ok(None),
        Err(e) => Err(PreisachError::Solver(format!("qdldl: {e}"))),
    }
}

/// Cost of a factorization in triangular solves: its Σ (column count)² over twice its
/// entries (the up-looking factorization and the two sweeps of a solve run at about the
/// same speed per entry touched).
fn refactor_in_solves(f: &Fact) -> f64 {
    let (sq, nnz) = f.L.colptr.windows(2).fold((0.0, 0.0), |(sq, nnz), w| {
        let k = (w[1] - w[0]) as f64;
        (sq + k * k, nnz + k)
    });
    sq / (2.0 * nnz).max(1.0)
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
    fn update(&mut self, changed: &[usize], active: &[bool], kkt: &Kkt, fact: &mut Fact, eps: f64) -> bool {
        self.cols.retain(|e| changed.contains(&e.0));
        let dim = kkt.n + kkt.m;
        let fresh: Vec<usize> = changed.iter().copied().filter(|&c| !self.has(c)).collect();
        // K₀⁻¹ B for the new columns.
        for c in fresh {
            let col = kkt.n + c;
            let mut w = vec![0.0; dim];
            if active[c] {
                for p in kkt.colptr[col]..kkt.colptr[col + 1] - 1 {
                    w[kkt.rowval[p]] = kkt.dval[p - kkt.colptr[kkt.n] - c];
                }
            } else {
                w[col] = 1.0;
            }
            fact.solve(&mut w);
            self.cols.push((c, active[c], w));
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
    fn solve(&mut self, kkt: &Kkt, fact: &mut Fact, x: &mut [f64]) {
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
fn admm_masses(kkt: &Kkt, fact: &mut Fact, q: &[f64], zero: &[bool], rho: f64, sigma: f64) -> Vec<f64> {
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

    /// `K x` with only the entries between coupled indices (all rows `< n`; constraint
    /// `c` at `n + c` when `active[c]`), the regularized values, computed densely.
    fn live_product(kkt: &Kkt, kval: &[f64], active: &[bool], x: &[f64]) -> Vec<f64> {
        let dim = kkt.n + kkt.m;
        let on = |i: usize| i < kkt.n || active[i - kkt.n];
        let mut k = vec![0.0; dim * dim];
        for j in 0..dim {
            let col = kkt.colptr[j]..kkt.colptr[j + 1];
            for (&i, &v) in kkt.rowval[col.clone()].iter().zip(&kval[col]) {
                if i == j || (on(i) && on(j)) {
                    k[i * dim + j] = v;
                    k[j * dim + i] = v;
                }
            }
        }
        (0..dim).map(|i| (0..dim).map(|j| k[i * dim + j] * x[j]).sum()).collect()
    }

    /// The KKT matrix of the identification problem of `u`, `y` on [0, 1] with n_h
    /// levels, the Everett values regularized by `eps`.
    fn test_kkt(n_h: usize, u: &[f64], y: &[f64], eps: f64) -> Kkt {
        let grid = Grid::new(0.0, 1.0, n_h).unwrap();
        let rows = build_rows(&grid, u, y, false);
        let zero = vec![false; grid.n_q()];
        let pb = Problem { rows: &rows, mu: 0.5, scale: 1.0, zero: &zero, reg: 0.0 };
        let (trip, _) = everett_objective(&pb);
        let mut kkt = Kkt::build(&pb, trip).unwrap();
        kkt.reg[..kkt.n].fill(eps);
        kkt
    }

    #[test]
    fn factor_of_the_active_constraints_solves_their_kkt_system() {
        let u: Vec<f64> =
            (0..5000).map(|k| 0.5 + 0.55 * (k as f64 * 0.0071).sin() * (k as f64 * 0.0003).cos()).collect();
        let y: Vec<f64> = u.iter().enumerate().map(|(k, x)| x * x + 0.02 * (k as f64 * 0.77).sin()).collect();
        // (Regularized enough to be well conditioned: the residual is then rounding.)
        let eps = 1e-3;
        let mut kkt = test_kkt(9, &u, &y, eps);
        let (n, m) = (kkt.n, kkt.m);
        let order = kkt.order().unwrap();
        let mut kval = vec![0.0; kkt.val.len()];
        for pattern in [0usize, 2, 3, 7] {
            let active: Vec<bool> = (0..m).map(|c| pattern > 0 && c % pattern == 0).collect();
            for (c, &a) in active.iter().enumerate() {
                kkt.set(c, a, eps);
            }
            kkt.regularized(&mut kval);
            let mut f = factor(&kkt, &kval, Some(&active), &order).unwrap().unwrap();
            let b: Vec<f64> = (0..n + m).map(|i| (i as f64 * 0.37).cos()).collect();
            let mut x = b.clone();
            f.solve(&mut x);
            let kx = live_product(&kkt, &kval, &active, &x);
            let err = b.iter().zip(&kx).fold(0.0f64, |e, (a, c)| e.max((a - c).abs()));
            let scale = x.iter().fold(0.0f64, |e, v| e.max(v.abs())) * kval.iter().fold(0.0f64, |e, v| e.max(v.abs()));
            assert!(err < 1e-12 * scale, "pattern {pattern}: residual {err}, |K| |x| {scale}");
        }
    }

    #[test]
    fn bordered_solve_equals_a_refactorization_after_constraints_switch() {
        // A small noisy identification problem; factor the KKT matrix of one active set,
        // switch some constraints on and some off, and solve both ways.
        let n = 20_000;
        let u: Vec<f64> = (0..n)
            .map(|k| {
                let t = k as f64 / n as f64;
                0.5 + 0.5 * t * (60.0 * t).sin() + 0.01 * (k as f64 * 1.7).sin()
            })
            .collect();
        let y: Vec<f64> = u.iter().enumerate().map(|(k, x)| x * x + 0.01 * (k as f64 * 0.37).cos()).collect();
        let eps = 1e-6;
        let mut kkt = test_kkt(12, &u, &y, eps);
        let dim = kkt.n + kkt.m;
        let m = kkt.m;
        let mut active: Vec<bool> = (0..m).map(|c| c % 3 == 0).collect();
        for (c, &a) in active.iter().enumerate() {
            kkt.set(c, a, eps);
        }
        let order = kkt.order().unwrap();
        let mut kval = vec![0.0; kkt.val.len()];
        kkt.regularized(&mut kval);
        let mut fact = factor(&kkt, &kval, Some(&active), &order).unwrap().unwrap();
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
        kkt.regularized(&mut kval);
        let mut direct = factor(&kkt, &kval, Some(&active), &order).unwrap().unwrap();
        let mut xd = rhs.clone();
        direct.solve(&mut xd);
        let scale = xd.iter().fold(0.0f64, |a, v| a.max(v.abs()));
        for (a, b) in xb.iter().zip(&xd) {
            assert!((a - b).abs() <= 1e-10 * scale, "{a} vs {b}");
        }
    }
}
