//! Non-negative least squares on a few dense columns: `argmin ‖A x − b‖₂` over `x ≥ 0`.
//!
//! Solved as the QP `½ xᵀ(AᵀA)x − (Aᵀb)ᵀx` under `x ≥ 0` by clarabel's interior point,
//! with the columns scaled to unit norm, then polished: the least-squares solution on
//! the support the interior point found replaces it when it is positive and optimal (the
//! active set's zeros are then exact zeros). For small problems (a bank of a few dozen
//! columns over many rows); the masses of a model have their own solvers.

use clarabel::algebra::CscMatrix;
use clarabel::solver::{DefaultSettingsBuilder, DefaultSolver, IPSolver, NonnegativeConeT, SolverStatus};

use crate::error::{check_finite, PreisachError, Result};

/// `x ≥ 0` minimizing `‖A x − b‖₂`, `A` given row-major with `n_cols` columns.
pub fn nnls(a: &[f64], n_cols: usize, b: &[f64]) -> Result<Vec<f64>> {
    let m = b.len();
    if n_cols == 0 || m == 0 || a.len() != m * n_cols {
        return Err(PreisachError::invalid(
            "a",
            format!("expected {} x {} values (len(b) rows), got {}", m, n_cols, a.len()),
        ));
    }
    check_finite("a", a)?;
    check_finite("b", b)?;
    let am = faer::Mat::<f64>::from_fn(m, n_cols, |i, j| a[i * n_cols + j]);
    let norms: Vec<f64> = (0..n_cols).map(|j| am.col(j).norm_l2()).collect();
    let scaled = faer::Mat::<f64>::from_fn(m, n_cols, |i, j| if norms[j] > 0.0 { am[(i, j)] / norms[j] } else { 0.0 });
    let bm = faer::Mat::<f64>::from_fn(m, 1, |i, _| b[i]);
    let g = scaled.transpose() * &scaled;
    let ab = scaled.transpose() * &bm;
    let atb: Vec<f64> = (0..n_cols).map(|j| ab[(j, 0)]).collect();
    let x = interior_point(&g, &atb)?;
    let x = polish(&g, &atb, x);
    Ok(x.iter().zip(&norms).map(|(v, nj)| if *nj > 0.0 { v / nj } else { 0.0 }).collect())
}

fn interior_point(g: &faer::Mat<f64>, atb: &[f64]) -> Result<Vec<f64>> {
    let n = atb.len();
    let mut colptr = vec![0];
    let (mut rowval, mut nzval) = (Vec::new(), Vec::new());
    for c in 0..n {
        for r in 0..=c {
            rowval.push(r);
            nzval.push(g[(r, c)]);
        }
        colptr.push(rowval.len());
    }
    let p = CscMatrix::new(n, n, colptr, rowval, nzval);
    let q: Vec<f64> = atb.iter().map(|v| -v).collect();
    // s = 0 − (−I) x = x ∈ the non-negative cone.
    let con = CscMatrix::new(n, n, (0..=n).collect(), (0..n).collect(), vec![-1.0; n]);
    let settings = DefaultSettingsBuilder::default()
        .verbose(false)
        .tol_gap_abs(1e-12)
        .tol_gap_rel(1e-12)
        .tol_feas(1e-12)
        .max_iter(200)
        .build()
        .map_err(|e| PreisachError::Solver(format!("settings: {e:?}")))?;
    let mut solver = DefaultSolver::new(&p, &q, &con, &vec![0.0; n], &[NonnegativeConeT(n)], settings)
        .map_err(|e| PreisachError::Solver(format!("{e:?}")))?;
    solver.solve();
    match solver.solution.status {
        SolverStatus::Solved | SolverStatus::AlmostSolved | SolverStatus::InsufficientProgress => {}
        other => return Err(PreisachError::Solver(format!("clarabel stopped with status {other:?}"))),
    }
    Ok(solver.solution.x.iter().map(|v| v.max(0.0)).collect())
}

/// The least-squares solution on `x`'s support when it is positive and no column off
/// the support would lower the objective (the optimality conditions); else `x`. The
/// support is `x`'s entries above a fraction of its largest, the fraction raised until
/// one passes (an interior point leaves small positive values where the optimum is 0).
fn polish(g: &faer::Mat<f64>, atb: &[f64], x: Vec<f64>) -> Vec<f64> {
    let top = x.iter().copied().fold(0.0, f64::max);
    for frac in [1e-9, 1e-6, 1e-4] {
        let s: Vec<usize> = (0..atb.len()).filter(|&j| x[j] > frac * top).collect();
        if let Some(y) = on_support(g, atb, &s) {
            return y;
        }
    }
    x
}

/// The least-squares solution with the columns `s` only, if it is positive and optimal.
fn on_support(g: &faer::Mat<f64>, atb: &[f64], s: &[usize]) -> Option<Vec<f64>> {
    let n = atb.len();
    if s.is_empty() {
        return None;
    }
    let gs = nalgebra::DMatrix::<f64>::from_fn(s.len(), s.len(), |i, j| g[(s[i], s[j])]);
    let rhs = nalgebra::DVector::<f64>::from_fn(s.len(), |i, _| atb[s[i]]);
    let z = gs.cholesky()?.solve(&rhs);
    if z.iter().any(|&v| v <= 0.0) {
        return None;
    }
    let mut y = vec![0.0; n];
    s.iter().zip(z.iter()).for_each(|(&j, &v)| y[j] = v);
    // The gradient Aᵀ(b − A y) must be <= 0 (to rounding) off the support.
    let scale = atb.iter().fold(0.0f64, |a, v| a.max(v.abs())).max(1e-300);
    let ok = (0..n).all(|j| y[j] > 0.0 || atb[j] - (0..n).map(|k| g[(j, k)] * y[k]).sum::<f64>() <= 1e-9 * scale);
    ok.then_some(y)
}
