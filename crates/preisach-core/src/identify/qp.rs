//! The two exact solvers of the identification QP
//!
//!   minimise  (1/N) Σ_r W_r (a_r·x − ȳ_r)²  +  reg · Σ_{neighbouring cells} (w_a − w_b)²
//!   over masses w >= 0 and a free offset,
//!
//! one problem (the paper §3.3 alternates lsqnonneg and lsqnonlin; one QP is exact), both
//! solved by clarabel's interior point method:
//! - [`solve_everett`] ("structured"): variables are the Everett values, so the
//!   objective is sparse (O(depth²) per row) and the masses are second differences
//!   constrained >= 0. Never forms the dense N × n_q matrix nor AᵀA; carries large n_h.
//! - [`solve_dense`] ("clarabel"): variables are the masses; AᵀWA is formed densely with
//!   faer. Only where it fits in memory; the reference the structured solver must match.
//!
//! Targets are centred and scaled before solving (ỹ = (y − μ)/s) so the tolerances mean
//! the same for every unit system; results are mapped back.

use clarabel::algebra::CscMatrix;
use clarabel::solver::{
    DefaultSettingsBuilder, DefaultSolver, IPSolver, NonnegativeConeT, SolverStatus, SupportedConeT, ZeroConeT,
};
use faer::sparse::{SparseColMat, Triplet};

use super::active::{solve_kkt, Kkt};
use super::rows::{mass_from_everett, Rows};
use crate::error::{PreisachError, Result};
use crate::grid::cell_index;

/// Active-set steps allowed when polishing an interior-point solution.
const POLISH_STEPS: u32 = 4;

/// Iterative-refinement steps per KKT solve of the interior point: clarabel's default
/// where its iterate is polished (the active set read from it must be right) ...
const REFINE_STEPS: u32 = 10;
/// ... and one where the iterate is the answer (the projection with a smoothness term,
/// `projection::TIE`): the nine more change the masses by less than 1e-5 of the largest
/// and the RMSE by less than 1e-7 of itself (noisy and clean records, n_h = 40 and 80),
/// and take a quarter of the interior point's time at n_h = 40.
const REFINE_STEPS_FINAL: u32 = 1;

/// Problem data shared by both solvers.
pub struct Problem<'a> {
    pub rows: &'a Rows,
    /// Centre and scale of the targets.
    pub mu: f64,
    pub scale: f64,
    /// Cells fixed to zero (never switched on: no information), packed like the masses.
    pub zero: &'a [bool],
    pub reg: f64,
}

/// Solution in the original units.
pub struct Solution {
    pub masses: Vec<f64>,
    pub offset: f64,
    pub iterations: u32,
}

/// Neighbouring cell pairs for the smoothness penalty.
fn neighbour_pairs(n_h: usize) -> Vec<(usize, usize)> {
    let mut p = Vec::new();
    for i in 0..n_h {
        for j in i..n_h {
            if i < j {
                p.push((cell_index(n_h, i, j), cell_index(n_h, i + 1, j)));
            }
            if j + 1 < n_h {
                p.push((cell_index(n_h, i, j), cell_index(n_h, i, j + 1)));
            }
        }
    }
    p
}

/// CSC (m × n) from (row, col, value) triplets in any order, duplicates summed (faer's
/// triplet constructor). Every sparse matrix of the identification is built here.
pub(super) fn csc(m: usize, n: usize, trip: &[Triplet<u32, u32, f64>]) -> Result<CscMatrix<f64>> {
    let a = SparseColMat::<u32, f64>::try_new_from_triplets(m, n, trip)
        .map_err(|e| PreisachError::Solver(format!("sparse matrix: {e:?}")))?;
    let (sym, val) = a.into_parts();
    let (_, _, colptr, _, rowval) = sym.into_parts();
    let colptr = colptr.into_iter().map(|p| p as usize).collect();
    let rowval = rowval.into_iter().map(|r| r as usize).collect();
    Ok(CscMatrix::new(m, n, colptr, rowval, val))
}

/// The upper triangle (n × n, CSC) of a symmetric matrix from keyed triplets ([`key`]),
/// duplicates summed, every diagonal entry present (zero where none is given): rows are
/// sorted, so each column's diagonal is its last entry.
pub(super) fn csc_upper(n: usize, mut trip: Vec<(u64, f64)>) -> Result<CscMatrix<f64>> {
    // Sorted by key first (plain integers, in place): the constructor's passes then read
    // the triplets in memory order, which halves its time on millions of them, and its
    // per-column sorts find them in order and keep it, so duplicates are summed in this
    // order. (The diagonal's zeros go last: each ends its column, still in order.)
    trip.sort_unstable_by_key(|t| t.0);
    trip.extend((0..n).map(|i| (key(i, i), 0.0)));
    // (The same size and alignment: collected in place, no second copy of the triplets.)
    let trip: Vec<Triplet<u32, u32, f64>> =
        trip.into_iter().map(|(k, v)| Triplet::new((k & 0xffff_ffff) as u32, (k >> 32) as u32, v)).collect();
    csc(n, n, &trip)
}

/// Largest packed upper triangle (entries) in which a symmetric matrix's products are
/// summed ([`Upper`]; 64 MB: n_h up to about 88); beyond, they are kept as triplets.
pub(super) const DENSE_SUM_MAX: usize = 8 << 20;

/// Products of a symmetric matrix's upper triangle, to be summed: in a packed triangle
/// when it holds at most `dense_max` entries and the products outnumber them (a noisy
/// input makes a row per sample, whose products, in the tens of millions, would
/// otherwise be stored, sorted and merged), as keyed triplets otherwise (few products:
/// a large triangle would cost more to clear and scan than they to sort).
pub(super) enum Upper {
    Packed { dim: usize, acc: Vec<f64> },
    Triplets(Vec<(u64, f64)>),
}

impl Upper {
    /// For a `dim` × `dim` matrix and `products` products (`None`: many, not counted).
    pub(super) fn new(dim: usize, dense_max: usize, products: Option<usize>) -> Self {
        let packed = dim * (dim + 1) / 2;
        if packed <= dense_max && products.is_none_or(|p| p > packed) {
            Upper::Packed { dim, acc: vec![0.0; packed] }
        } else {
            Upper::Triplets(Vec::with_capacity(products.unwrap_or(0)))
        }
    }

    /// Entry (i, j) or (j, i) gets `v`.
    #[inline]
    pub(super) fn add(&mut self, i: usize, j: usize, v: f64) {
        match self {
            // Entry (row r, column c), r <= c, at c (c + 1) / 2 + r: column by column.
            Upper::Packed { acc, .. } => {
                let (r, c) = if i <= j { (i, j) } else { (j, i) };
                acc[c * (c + 1) / 2 + r] += v;
            }
            Upper::Triplets(t) => t.push((key(i, j), v)),
        }
    }

    /// The keyed triplets for [`csc_upper`] (packed: the sums, in key order, zeros left
    /// out).
    pub(super) fn into_triplets(self) -> Vec<(u64, f64)> {
        match self {
            Upper::Triplets(t) => t,
            Upper::Packed { dim, acc } => {
                let mut trip = Vec::new();
                for c in 0..dim {
                    let col = &acc[c * (c + 1) / 2..(c + 1) * (c + 2) / 2];
                    trip.extend(col.iter().enumerate().filter(|(_, &v)| v != 0.0).map(|(r, &v)| (key(r, c), v)));
                }
                trip
            }
        }
    }
}

/// Key of the upper-triangle entry (row, col) or (col, row): the column in the high
/// half, the row in the low one.
#[inline]
pub(super) fn key(row: usize, col: usize) -> u64 {
    let (r, c) = if row <= col { (row, col) } else { (col, row) };
    ((c as u64) << 32) | r as u64
}

/// `csc` of (row, col, value) triplets.
fn csc_general(m: usize, n: usize, trip: &[(usize, usize, f64)]) -> Result<CscMatrix<f64>> {
    let t: Vec<Triplet<u32, u32, f64>> = trip.iter().map(|&(r, c, v)| Triplet::new(r as u32, c as u32, v)).collect();
    csc(m, n, &t)
}

/// Solve `min ½xᵀPx + qᵀx` s.t. the first `n_zero` rows of `A x = 0` and the remaining
/// rows `A x <= 0`, then polish: interior-point iterates stop a little inside the
/// boundary, and this problem is ill-conditioned, so the constraints classified as
/// active (slack below multiplier) are made equalities and the reduced problem is
/// solved again. The polished point is kept only if it is still feasible and no worse.
fn run_clarabel(
    p: &CscMatrix<f64>,
    q: &[f64],
    a_trip: &[(usize, usize, f64)],
    n: usize,
    n_zero: usize,
    n_rows: usize,
) -> Result<(Vec<f64>, u32)> {
    let first = ipm(p, q, a_trip, n, n_zero, n_rows, REFINE_STEPS)?;
    polish(p, q, a_trip, n, n_zero, n_rows, first)
}

/// The interior point on the full problem (first `n_zero` constraint rows equalities),
/// with `refine` iterative-refinement steps per KKT solve.
fn ipm(
    p: &CscMatrix<f64>,
    q: &[f64],
    a_trip: &[(usize, usize, f64)],
    n: usize,
    n_zero: usize,
    n_rows: usize,
    refine: u32,
) -> Result<Iterate> {
    let a = csc_general(n_rows, n, a_trip)?;
    let mut cones = Vec::new();
    if n_zero > 0 {
        cones.push(ZeroConeT(n_zero));
    }
    if n_rows > n_zero {
        cones.push(NonnegativeConeT(n_rows - n_zero));
    }
    clarabel_once(p, q, &a, &cones, refine)
}

/// Polish an interior-point iterate with equality-constrained clarabel solves.
fn polish(
    p: &CscMatrix<f64>,
    q: &[f64],
    a_trip: &[(usize, usize, f64)],
    n: usize,
    n_zero: usize,
    n_rows: usize,
    first: Iterate,
) -> Result<(Vec<f64>, u32)> {
    let (x, s, z, iters) = first;
    // Active set: zero-cone rows, and inequality rows whose slack is below the multiplier.
    let mut active: Vec<bool> = (0..n_rows).map(|r| r < n_zero || s[r] < z[r]).collect();
    let obj = |x: &[f64]| {
        let mut px = vec![0.0; n];
        for c in 0..n {
            for idx in p.colptr[c]..p.colptr[c + 1] {
                let r = p.rowval[idx];
                px[r] += p.nzval[idx] * x[c];
                if r != c {
                    px[c] += p.nzval[idx] * x[r];
                }
            }
        }
        (0..n).map(|i| 0.5 * x[i] * px[i] + q[i] * x[i]).sum::<f64>()
    };
    let f_ipm = obj(&x);
    let mut total = iters;
    // A few rounds of a primal active-set step: rows violated by the polished point join
    // the active set.
    for _ in 0..4 {
        let mut map = vec![usize::MAX; n_rows];
        let mut k = 0;
        for r in 0..n_rows {
            if active[r] {
                map[r] = k;
                k += 1;
            }
        }
        let trip: Vec<(usize, usize, f64)> =
            a_trip.iter().filter(|t| map[t.0] != usize::MAX).map(|&(r, c, v)| (map[r], c, v)).collect();
        let Ok(a2) = csc_general(k, n, &trip) else { break };
        let cones2 = if k > 0 { vec![ZeroConeT(k)] } else { vec![] };
        let Ok((x2, _, _, it2)) = clarabel_once(p, q, &a2, &cones2, REFINE_STEPS) else { break };
        total += it2;
        let mut ax = vec![0.0; n_rows];
        for &(r, c, v) in a_trip {
            ax[r] += v * x2[c];
        }
        let scale = x2.iter().fold(1e-300f64, |m, v| m.max(v.abs()));
        let mut violated = false;
        for r in n_zero..n_rows {
            if ax[r] > 1e-10 * scale {
                active[r] = true;
                violated = true;
            }
        }
        if !violated {
            if obj(&x2) <= f_ipm + 1e-12 * f_ipm.abs().max(1.0) {
                return Ok((x2, total));
            }
            break;
        }
    }
    Ok((x, iters))
}

type Iterate = (Vec<f64>, Vec<f64>, Vec<f64>, u32);

fn clarabel_once(
    p: &CscMatrix<f64>,
    q: &[f64],
    a: &CscMatrix<f64>,
    cones: &[SupportedConeT<f64>],
    refine: u32,
) -> Result<Iterate> {
    let settings = DefaultSettingsBuilder::default()
        .verbose(false)
        .tol_gap_abs(1e-11)
        .tol_gap_rel(1e-11)
        .tol_feas(1e-11)
        .iterative_refinement_max_iter(refine)
        .max_iter(200)
        .build()
        .map_err(|e| PreisachError::Solver(format!("settings: {e:?}")))?;
    let b = vec![0.0; a.m];
    let mut solver =
        DefaultSolver::new(p, q, a, &b, cones, settings).map_err(|e| PreisachError::Solver(format!("{e:?}")))?;
    solver.solve();
    match solver.solution.status {
        SolverStatus::Solved | SolverStatus::AlmostSolved | SolverStatus::InsufficientProgress => {}
        other => return Err(PreisachError::Solver(format!("clarabel stopped with status {other:?}"))),
    }
    let sol = &solver.solution;
    Ok((sol.x.clone(), sol.s.clone(), sol.z.clone(), sol.iterations))
}

/// The objective in Everett coordinates (variables: the n_q Everett values, then the
/// offset): upper-triangular Hessian triplets keyed by [`key`] (duplicates to be summed)
/// and the linear term, for `½ xᵀPx + qᵀx`.
pub(super) fn everett_objective(pb: &Problem) -> (Vec<(u64, f64)>, Vec<f64>) {
    everett_objective_with(pb, 0)
}

/// [`everett_objective`] with the Hessian's products summed in a packed triangle when it
/// holds at most `dense_max` entries ([`Upper`]; the triplets then come summed, in key
/// order).
pub(super) fn everett_objective_with(pb: &Problem, dense_max: usize) -> (Vec<(u64, f64)>, Vec<f64>) {
    let rows = pb.rows;
    let n_h = rows.n_h;
    let n_q = rows.n_vars();
    let n_total = rows.n_samples as f64;
    // One product per pair of entries in a row (the offset included).
    let pairs = rows.indptr.windows(2).map(|w| (w[1] - w[0] + 1) * (w[1] - w[0] + 2) / 2).sum();
    let mut trip = Upper::new(n_q + 1, dense_max, Some(pairs));
    let mut ent: Vec<(usize, f64)> = Vec::new();
    for r in 0..rows.n_rows() {
        let (idx, val) = rows.row(r);
        ent.clear();
        ent.extend(idx.iter().map(|&i| i as usize).zip(val.iter().copied()));
        ent.push((n_q, rows.offset_coef[r]));
        let cw = 2.0 * rows.weight[r] / n_total;
        for (k, &(i, vi)) in ent.iter().enumerate() {
            for &(j, vj) in &ent[k..] {
                trip.add(i, j, cw * vi * vj);
            }
        }
    }
    if pb.reg > 0.0 {
        let mut d1 = Vec::new();
        let mut d2 = Vec::new();
        let cell_ij = cell_coords(n_h);
        for (c1, c2) in neighbour_pairs(n_h) {
            let (i1, j1) = cell_ij[c1];
            let (i2, j2) = cell_ij[c2];
            mass_from_everett(i1, j1, &mut d1);
            mass_from_everett(i2, j2, &mut d2);
            let mut d: Vec<(usize, f64)> = d1.iter().copied().chain(d2.iter().map(|&(k, v)| (k, -v))).collect();
            d.sort_unstable_by_key(|e| e.0);
            for a in 0..d.len() {
                for b in 0..d.len() {
                    if d[a].0 <= d[b].0 {
                        trip.add(d[a].0, d[b].0, 2.0 * pb.reg * d[a].1 * d[b].1);
                    }
                }
            }
        }
    }
    (trip.into_triplets(), linear_term(pb))
}

/// The linear term `q` of the objective in Everett coordinates (see [`everett_objective`]):
/// the only part that depends on the targets.
pub(super) fn linear_term(pb: &Problem) -> Vec<f64> {
    linear_term_of(pb, &pb.rows.target)
}

/// [`linear_term`] with the rows' targets given apart (the rows shared by several
/// problems).
pub(super) fn linear_term_of(pb: &Problem, target: &[f64]) -> Vec<f64> {
    let rows = pb.rows;
    let n_q = rows.n_vars();
    let n_total = rows.n_samples as f64;
    let mut q = vec![0.0; n_q + 1];
    for (r, &t) in target.iter().enumerate().take(rows.n_rows()) {
        let (idx, val) = rows.row(r);
        let cw = 2.0 * rows.weight[r] / n_total;
        let yt = (t - pb.mu * rows.offset_coef[r]) / pb.scale;
        for (&i, &v) in idx.iter().zip(val) {
            q[i as usize] -= cw * yt * v;
        }
        q[n_q] -= cw * yt * rows.offset_coef[r];
    }
    q
}

/// The structured solver: Everett coordinates, sparse objective, masses >= 0 as
/// second differences.
pub fn solve_everett(pb: &Problem) -> Result<Solution> {
    let n = pb.rows.n_vars() + 1;
    let (trip, q) = everett_objective(pb);
    // Stepwise rows are polished by the active-set method (below), and one assembly then
    // serves both methods: the Hessian is the KKT matrix's first n columns.
    let (p, kkt) = if pb.rows.interpolated {
        (csc_upper(n, trip)?, None)
    } else {
        let kkt = Kkt::build(pb, trip)?;
        (kkt.hessian(), Some(kkt))
    };
    solve_everett_with(pb, &p, &q, kkt, true)
}

/// [`solve_everett`] from the objective's Hessian `p` (upper triangle) and linear term
/// `q`; `kkt` (the KKT matrix of `p`, all constraints inactive), when given, polishes by
/// the active-set method. Without `polish_ipm`, the interior point's solution is taken
/// as it is, to its tolerances (a relative gap of 1e-11): for an objective with a unique
/// optimum (`reg` > 0) the clarabel polish's equality-constrained re-solves cost several
/// interior points and do not move it.
pub(super) fn solve_everett_with(
    pb: &Problem,
    p: &CscMatrix<f64>,
    q: &[f64],
    kkt: Option<Kkt>,
    polish_ipm: bool,
) -> Result<Solution> {
    let n_h = pb.rows.n_h;
    let n_q = pb.rows.n_vars();
    let n = n_q + 1;
    let mut d1 = Vec::new();
    let cell_ij = cell_coords(n_h);
    // Constraints: fixed cells first (zero cone), then the rest (non-negative cone);
    // A x + s = 0 with A = −D, so s = D x = the masses.
    let mut order: Vec<usize> = (0..n_q).filter(|&c| pb.zero[c]).collect();
    let n_zero = order.len();
    order.extend((0..n_q).filter(|&c| !pb.zero[c]));
    let mut at = Vec::with_capacity(4 * n_q);
    for (r, &c) in order.iter().enumerate() {
        let (i, j) = cell_ij[c];
        mass_from_everett(i, j, &mut d1);
        for &(k, v) in &d1 {
            at.push((r, k, -v));
        }
    }
    let refine = if polish_ipm || kkt.is_some() { REFINE_STEPS } else { REFINE_STEPS_FINAL };
    let first = ipm(p, q, &at, n, n_zero, n_q, refine)?;
    // Polish: the cells whose slack is below the multiplier are the active-set method's
    // starting guess; from there it usually needs one or two factorizations to the exact
    // optimum (the clarabel polish below is the fallback).
    let mut guess = pb.zero.to_vec();
    for (r, &c) in order.iter().enumerate() {
        guess[c] |= first.1[r] < first.2[r];
    }
    // (Not for interpolated rows: there it cycles; the clarabel polish is cheaper.)
    if let Some(kkt) = kkt {
        if let Some(mut sol) = solve_kkt(pb, kkt, q, Some(guess), POLISH_STEPS)? {
            sol.iterations += first.3;
            return Ok(sol);
        }
    }
    let (x, iterations) = if polish_ipm { polish(p, q, &at, n, n_zero, n_q, first)? } else { (first.0, first.3) };
    let mut masses = vec![0.0; n_q];
    for (c, m) in masses.iter_mut().enumerate() {
        if pb.zero[c] {
            continue;
        }
        let (i, j) = cell_ij[c];
        mass_from_everett(i, j, &mut d1);
        let w: f64 = d1.iter().map(|&(k, v)| v * x[k]).sum();
        *m = (w * pb.scale).max(0.0);
    }
    Ok(Solution { masses, offset: x[n_q] * pb.scale + pb.mu, iterations })
}

/// (i, j) of each packed cell.
pub(super) fn cell_coords(n_h: usize) -> Vec<(usize, usize)> {
    let mut v = Vec::with_capacity(n_h * (n_h + 1) / 2);
    for i in 0..n_h {
        for j in i..n_h {
            v.push((i, j));
        }
    }
    v
}

/// Bytes the dense solver would need (AᵀWA, its CSC copy and factor, and the rows).
pub fn dense_bytes(n_rows: usize, n_free: usize) -> f64 {
    let n = (n_free + 1) as f64;
    8.0 * (3.0 * n * n + n_rows as f64 * n)
}

/// The dense solver: masses as variables, AᵀWA formed with faer, clarabel on the QP.
pub fn solve_dense(pb: &Problem) -> Result<Solution> {
    let rows = pb.rows;
    let n_h = rows.n_h;
    let n_q = rows.n_vars();
    let free: Vec<usize> = (0..n_q).filter(|&c| !pb.zero[c]).collect();
    let mut col_of = vec![usize::MAX; n_q];
    for (k, &c) in free.iter().enumerate() {
        col_of[c] = k;
    }
    let nf = free.len();
    let n = nf + 1;
    let n_total = rows.n_samples as f64;
    let m = rows.n_rows();
    let mut bmat = faer::Mat::<f64>::zeros(m, n);
    let mut z = faer::Mat::<f64>::zeros(m, 1);
    let mut dense = vec![0.0; n_q];
    for r in 0..m {
        let sw = (2.0 * rows.weight[r] / n_total).sqrt();
        dense.iter_mut().for_each(|v| *v = 0.0);
        rows.add_mass_row(r, sw, &mut dense);
        for (k, &c) in free.iter().enumerate() {
            bmat[(r, k)] = dense[c];
        }
        bmat[(r, nf)] = sw * rows.offset_coef[r];
        z[(r, 0)] = sw * (rows.target[r] - pb.mu * rows.offset_coef[r]) / pb.scale;
    }
    let g = bmat.transpose() * &bmat;
    let bz = bmat.transpose() * &z;
    let q: Vec<f64> = (0..n).map(|k| -bz[(k, 0)]).collect();
    let mut reg_diag = vec![0.0; n];
    let mut reg_off: Vec<(usize, usize)> = Vec::new();
    if pb.reg > 0.0 {
        for (c1, c2) in neighbour_pairs(n_h) {
            let (k1, k2) = (col_of[c1], col_of[c2]);
            if k1 != usize::MAX {
                reg_diag[k1] += 2.0 * pb.reg;
            }
            if k2 != usize::MAX {
                reg_diag[k2] += 2.0 * pb.reg;
            }
            if k1 != usize::MAX && k2 != usize::MAX {
                reg_off.push((k1.min(k2), k1.max(k2)));
            }
        }
    }
    let mut colptr = Vec::with_capacity(n + 1);
    let mut rowval = Vec::with_capacity(n * (n + 1) / 2);
    let mut nzval = Vec::with_capacity(n * (n + 1) / 2);
    colptr.push(0);
    for c in 0..n {
        for r in 0..=c {
            rowval.push(r);
            nzval.push(g[(r, c)] + if r == c { reg_diag[c] } else { 0.0 });
        }
        colptr.push(rowval.len());
    }
    let mut p = CscMatrix::new(n, n, colptr, rowval, nzval);
    for (r, c) in reg_off {
        // Column c holds rows 0..=c contiguously.
        let pos = p.colptr[c] + r;
        p.nzval[pos] -= 2.0 * pb.reg;
    }
    let at: Vec<(usize, usize, f64)> = (0..nf).map(|k| (k, k, -1.0)).collect();
    let (x, iterations) = run_clarabel(&p, &q, &at, n, 0, nf)?;
    let mut masses = vec![0.0; n_q];
    for (k, &c) in free.iter().enumerate() {
        masses[c] = (x[k] * pb.scale).max(0.0);
    }
    Ok(Solution { masses, offset: x[nf] * pb.scale + pb.mu, iterations })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Random triplets with many duplicates, against a dense accumulation.
    #[test]
    fn triplets_become_csc_with_duplicates_summed() {
        let mut s = 17u64;
        let mut rnd = move |k: u64| {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (s >> 33) % k
        };
        for (m, n) in [(1, 1), (7, 3), (40, 55)] {
            let trip: Vec<(usize, usize, f64)> = (0..4 * m * n)
                .map(|_| (rnd(m as u64) as usize, rnd(n as u64) as usize, rnd(1000) as f64 - 500.0))
                .collect();
            let mut dense = vec![0.0; m * n];
            let mut present = vec![false; m * n];
            for &(r, c, v) in &trip {
                dense[c * m + r] += v;
                present[c * m + r] = true;
            }
            let a = csc_general(m, n, &trip).unwrap();
            let mut seen = vec![false; m * n];
            for c in 0..n {
                let rows = &a.rowval[a.colptr[c]..a.colptr[c + 1]];
                assert!(rows.windows(2).all(|w| w[0] < w[1]), "rows sorted and distinct");
                for (&r, &v) in rows.iter().zip(&a.nzval[a.colptr[c]..a.colptr[c + 1]]) {
                    assert_eq!(v, dense[c * m + r]);
                    seen[c * m + r] = true;
                }
            }
            assert_eq!(seen, present);
        }
        // The symmetric form: keys in either orientation land in the upper triangle,
        // every diagonal present and last in its column.
        let trip = vec![(key(2, 0), 1.0), (key(0, 2), 2.0), (key(1, 1), 3.0), (key(1, 1), 4.0)];
        let a = csc_upper(4, trip).unwrap();
        assert_eq!(a.colptr, [0, 1, 2, 4, 5]);
        assert_eq!(a.rowval, [0, 1, 0, 2, 3]);
        assert_eq!(a.nzval, [0.0, 7.0, 3.0, 0.0, 0.0]);
    }

    /// The objective's Hessian summed in a packed triangle and as sorted triplets, both
    /// against the plain sum of every row's outer product (and the smoothness term's).
    #[test]
    fn hessian_sums_packed_and_as_triplets_are_the_rows_outer_products() {
        use crate::grid::Grid;
        use crate::identify::rows::build_rows;
        use crate::identify::testing::{input, Rng};
        let mut rng = Rng(5);
        for (case, (n_h, interpolated, reg)) in
            [(6, true, 0.0), (9, true, 1e-3), (7, false, 1e-2)].into_iter().enumerate()
        {
            let grid = Grid::new(0.0, 1.0, n_h).unwrap();
            let u = input(&mut rng, 3000);
            let y: Vec<f64> = u.iter().map(|v| v * v).collect();
            let rows = build_rows(&grid, &u, &y, interpolated);
            let zero = vec![false; grid.n_q()];
            let pb = Problem { rows: &rows, mu: 0.3, scale: 1.0, zero: &zero, reg };
            let dim = rows.n_vars() + 1;
            // The oracle: every row's (entries, offset) outer product, weighted, then the
            // smoothness term's differences of masses.
            let mut want = vec![0.0; dim * dim];
            for r in 0..rows.n_rows() {
                let (idx, val) = rows.row(r);
                let mut e: Vec<(usize, f64)> = idx.iter().map(|&i| i as usize).zip(val.iter().copied()).collect();
                e.push((dim - 1, rows.offset_coef[r]));
                let cw = 2.0 * rows.weight[r] / rows.n_samples as f64;
                for &(i, a) in &e {
                    for &(j, b) in &e {
                        want[i * dim + j] += cw * a * b;
                    }
                }
            }
            let cells = cell_coords(n_h);
            let (mut d1, mut d2) = (Vec::new(), Vec::new());
            for (c1, c2) in neighbour_pairs(n_h) {
                mass_from_everett(cells[c1].0, cells[c1].1, &mut d1);
                mass_from_everett(cells[c2].0, cells[c2].1, &mut d2);
                let mut d = vec![0.0; dim];
                d1.iter().for_each(|&(k, v)| d[k] += v);
                d2.iter().for_each(|&(k, v)| d[k] -= v);
                for i in 0..dim {
                    for j in 0..dim {
                        want[i * dim + j] += 2.0 * reg * d[i] * d[j];
                    }
                }
            }
            let scale = want.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            for dense_max in [usize::MAX, 0] {
                let p = csc_upper(dim, everett_objective_with(&pb, dense_max).0).unwrap();
                let mut got = vec![0.0; dim * dim];
                for c in 0..dim {
                    for k in p.colptr[c]..p.colptr[c + 1] {
                        got[p.rowval[k] * dim + c] = p.nzval[k];
                    }
                }
                for i in 0..dim {
                    for j in i..dim {
                        let (g, w) = (got[i * dim + j], want[i * dim + j]);
                        assert!(
                            (g - w).abs() <= 1e-12 * scale,
                            "case {case}, dense_max {dense_max}, ({i}, {j}): {g} vs {w}"
                        );
                    }
                }
            }
        }
    }
}
