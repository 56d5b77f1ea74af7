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

use super::rows::{mass_from_everett, Rows};
use crate::error::{PreisachError, Result};
use crate::grid::cell_index;

/// Active-set steps allowed when polishing an interior-point solution.
const POLISH_STEPS: u32 = 4;

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

/// Upper-triangular CSC from keyed values (`key(row, col)`); duplicates summed.
fn csc_upper(n: usize, mut trip: Vec<(u64, f64)>) -> CscMatrix<f64> {
    trip.sort_unstable_by_key(|t| t.0);
    let mut merged: Vec<(usize, usize, f64)> = Vec::with_capacity(trip.len());
    let mut last = u64::MAX;
    for (k, v) in trip {
        if k == last {
            merged.last_mut().unwrap().2 += v;
        } else {
            last = k;
            merged.push(((k & 0xffff_ffff) as usize, (k >> 32) as usize, v));
        }
    }
    csc_sorted(n, n, merged)
}

#[inline]
pub(super) fn key(row: usize, col: usize) -> u64 {
    let (r, c) = if row <= col { (row, col) } else { (col, row) };
    ((c as u64) << 32) | r as u64
}

/// General CSC (m × n) from (row, col, value) triplets.
fn csc_general(m: usize, n: usize, mut trip: Vec<(usize, usize, f64)>) -> CscMatrix<f64> {
    trip.sort_unstable_by_key(|t| (t.1, t.0));
    csc_sorted(m, n, trip)
}

/// CSC from triplets already sorted by (col, row).
fn csc_sorted(m: usize, n: usize, trip: Vec<(usize, usize, f64)>) -> CscMatrix<f64> {
    let mut colptr = vec![0usize; n + 1];
    let mut rowval = Vec::with_capacity(trip.len());
    let mut nzval = Vec::with_capacity(trip.len());
    for (r, c, v) in trip {
        colptr[c + 1] += 1;
        rowval.push(r);
        nzval.push(v);
    }
    for c in 0..n {
        colptr[c + 1] += colptr[c];
    }
    CscMatrix::new(m, n, colptr, rowval, nzval)
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
    let first = ipm(p, q, a_trip, n, n_zero, n_rows)?;
    polish(p, q, a_trip, n, n_zero, n_rows, first)
}

/// The interior point on the full problem (first `n_zero` constraint rows equalities).
fn ipm(
    p: &CscMatrix<f64>,
    q: &[f64],
    a_trip: &[(usize, usize, f64)],
    n: usize,
    n_zero: usize,
    n_rows: usize,
) -> Result<Iterate> {
    let a = csc_general(n_rows, n, a_trip.to_vec());
    let mut cones = Vec::new();
    if n_zero > 0 {
        cones.push(ZeroConeT(n_zero));
    }
    if n_rows > n_zero {
        cones.push(NonnegativeConeT(n_rows - n_zero));
    }
    clarabel_once(p, q, &a, &cones)
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
        let a2 = csc_general(k, n, trip);
        let cones2 = if k > 0 { vec![ZeroConeT(k)] } else { vec![] };
        let Ok((x2, _, _, it2)) = clarabel_once(p, q, &a2, &cones2) else { break };
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

fn clarabel_once(p: &CscMatrix<f64>, q: &[f64], a: &CscMatrix<f64>, cones: &[SupportedConeT<f64>]) -> Result<Iterate> {
    let settings = DefaultSettingsBuilder::default()
        .verbose(false)
        .tol_gap_abs(1e-11)
        .tol_gap_rel(1e-11)
        .tol_feas(1e-11)
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
    let mut trip = Vec::new();
    let q = everett_objective_into(pb, &mut trip);
    (trip, q)
}

/// [`everett_objective`] with the triplets written to `trip` (cleared first; its memory
/// reused).
pub(super) fn everett_objective_into(pb: &Problem, trip: &mut Vec<(u64, f64)>) -> Vec<f64> {
    let rows = pb.rows;
    let n_h = rows.n_h;
    let n_q = rows.n_vars();
    let n = n_q + 1;
    let n_total = rows.n_samples as f64;
    // One triplet per pair of entries in a row (the offset included).
    let pairs: usize = rows.indptr.windows(2).map(|w| (w[1] - w[0] + 1) * (w[1] - w[0] + 2) / 2).sum();
    trip.clear();
    trip.reserve(pairs);
    let mut q = vec![0.0; n];
    let mut ent: Vec<(usize, f64)> = Vec::new();
    for r in 0..rows.n_rows() {
        let (idx, val) = rows.row(r);
        ent.clear();
        ent.extend(idx.iter().map(|&i| i as usize).zip(val.iter().copied()));
        ent.push((n_q, rows.offset_coef[r]));
        let cw = 2.0 * rows.weight[r] / n_total;
        let yt = (rows.target[r] - pb.mu * rows.offset_coef[r]) / pb.scale;
        for (k, &(i, vi)) in ent.iter().enumerate() {
            q[i] -= cw * yt * vi;
            for &(j, vj) in &ent[k..] {
                trip.push((key(i, j), cw * vi * vj));
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
                        trip.push((key(d[a].0, d[b].0), 2.0 * pb.reg * d[a].1 * d[b].1));
                    }
                }
            }
        }
    }
    q
}

/// The structured solver: Everett coordinates, sparse objective, masses >= 0 as
/// second differences.
pub fn solve_everett(pb: &Problem) -> Result<Solution> {
    let n_h = pb.rows.n_h;
    let n_q = pb.rows.n_vars();
    let n = n_q + 1;
    let (trip, q) = everett_objective(pb);
    let mut d1 = Vec::new();
    let cell_ij = cell_coords(n_h);
    let p = csc_upper(n, trip);
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
    let first = ipm(&p, &q, &at, n, n_zero, n_q)?;
    // Polish: the cells whose slack is below the multiplier are the active-set method's
    // starting guess; from there it usually needs one or two factorizations to the exact
    // optimum (the clarabel polish below is the fallback).
    let mut guess = pb.zero.to_vec();
    for (r, &c) in order.iter().enumerate() {
        guess[c] |= first.1[r] < first.2[r];
    }
    // (Not for interpolated rows: there it cycles; the clarabel polish is cheaper.)
    if !pb.rows.interpolated {
        if let Some(mut sol) = super::active::solve_active(pb, Some(guess), POLISH_STEPS)? {
            sol.iterations += first.3;
            return Ok(sol);
        }
    }
    let (x, iterations) = polish(&p, &q, &at, n, n_zero, n_q, first)?;
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
