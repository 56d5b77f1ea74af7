//! The exact non-negative least-squares projection of an interpolated model onto
//! non-negative masses, for many targets on one input.
//!
//! A fit behind a chain (`filtered::Behind`) ends with the masses >= 0 nearest to its
//! unconstrained optimum `x*` (Everett values and offset) in the metric of the input's
//! samples:
//!
//! ```text
//!   minimise  Σ_t (B_t x − B_t x*)²   over x with masses D x >= 0,
//! ```
//!
//! `B` the interpolated model's rows of input `u`. Everything but `x*` depends on `u`
//! only, so the merged rows and the objective's Hessian `BᵀB` in Everett coordinates are
//! built once ([`Projection::new`]); a projection ([`Projection::project`]) sets the
//! rows' targets `B x*` and the linear term, then runs the structured interior point
//! (`qp::solve_everett_with`) on the kept Hessian. Assembling that Hessian (a product
//! per pair of entries of every row, summed in a packed triangle where it fits: a noisy
//! input makes a row per sample, and tens of millions of products) costs more than
//! the interior point itself on the diagnosis's records.
//!
//! The optimal output is unique, the masses are not: a record leaves many combinations
//! of masses undetermined (the cells its staircases never separate), and every point of
//! that face of optimal masses predicts another record differently. Which point a solver
//! returns is then a matter of its path and of rounding: the interior point stops near
//! the face's centre, and its polish (equality-constrained re-solves on the cells it
//! classifies as zero) is kept or dropped on objective differences of 1e-12; between two
//! such equally optimal answers a held-out record's error can differ by a third. So the
//! diagnosis's projections carry a small smoothness term ([`TIE`]: neighbouring cells'
//! masses alike, as `fit`'s `reg` does): the optimum is unique, the smoothest of the
//! near-optimal masses, and the interior point's solution to its tolerances (a relative
//! gap of 1e-11) is that optimum, with no polish to pay for. Without the term (weight 0)
//! the projection is the plain one, polished as `fit` polishes.
//!
//! (The primal–dual active-set method, warm-started from the last projection's zero
//! masses, settles in a few factorizations on a smooth sweep, but cycles on the
//! diagnosis's records, as it does from a cold start on interpolated rows; so it is not
//! tried here.)

use std::time::Instant;

use clarabel::algebra::CscMatrix;

use super::qp::{
    csc_upper, everett_objective_with, linear_term_of, solve_everett_with, Problem, Solution, DENSE_SUM_MAX,
};
use super::rows::{build_rows_interpolated, Rows};
use super::{excitation, min_max, never_on, pitfalls, seen_levels, FitReport, MAX_N_H_STRUCTURED};
use crate::error::{check_finite, check_scalar, check_signal, PreisachError, Result};
use crate::grid::Grid;
use crate::model::PreisachModel;

/// Weight of the smoothness term that makes the projection's optimum unique (see the
/// module documentation; the objective's `reg`, in the solver's scaled units). On the
/// unit tests' records of both simulators it moves a chain's RMSE on the record by at
/// most 6e-6 of it (1e-4 moves it by up to 9e-5).
pub const TIE: f64 = 1e-5;

/// The projection's problem on one input (see the module documentation).
pub struct Projection {
    grid: Grid,
    /// Interpolated rows of the input; their targets are set per projection.
    rows: Rows,
    /// Cells never switched on (fixed to zero mass).
    zero: Vec<bool>,
    /// The objective's Hessian in Everett coordinates (upper triangle).
    hessian: CscMatrix<f64>,
    /// The report's fields that depend on the input only.
    base: FitReport,
    /// Weight of the smoothness term (0: the exact projection, polished).
    tie: f64,
}

impl Projection {
    /// The problem of input `u` on `grid`, with a smoothness term of weight `tie` (>= 0;
    /// [`TIE`] makes the optimum unique; 0 is the plain projection, whose interior
    /// point is polished towards the exact optimum).
    pub fn new(grid: &Grid, u: &[f64], tie: f64) -> Result<Self> {
        Projection::after(grid, &[], u, tie)
    }

    /// [`Projection::new`] for an input whose memory starts after `extrema`
    /// (alternating extrema, input units; see `filtered::Behind::after`).
    pub fn after(grid: &Grid, extrema: &[f64], u: &[f64], tie: f64) -> Result<Self> {
        check_signal("u", u)?;
        check_finite("initial_extrema", extrema)?;
        check_tie(tie)?;
        let n_h = grid.n_h();
        if n_h > MAX_N_H_STRUCTURED {
            return Err(PreisachError::invalid(
                "n_h",
                format!("{n_h} is too large to identify (the solvers handle n_h <= {MAX_N_H_STRUCTURED})"),
            ));
        }
        let t0 = Instant::now();
        let rows = build_rows_interpolated(grid, extrema, u, &vec![0.0; u.len()]);
        let (u_min, u_max) = min_max(u);
        let zero = never_on(grid, grid.position(u_max).ceil() as usize);
        let pb = Problem { rows: &rows, mu: 0.0, scale: 1.0, zero: &zero, reg: tie };
        let (trip, _) = everett_objective_with(&pb, DENSE_SUM_MAX);
        let hessian = csc_upper(rows.n_vars() + 1, trip)?;
        let (reversals, never, once) = excitation(&seen_levels(grid, u), n_h);
        let (lo, hi) = (grid.lo(), grid.hi());
        let base = FitReport {
            n_samples: u.len(),
            n_rows: rows.n_rows(),
            reversals,
            cells_never_excited: never,
            cells_switched_once: once,
            input_min: u_min,
            input_max: u_max,
            lo,
            hi,
            time_rows_s: t0.elapsed().as_secs_f64(),
            warnings: pitfalls(reversals, n_h, (u_min, u_max), (lo, hi)),
            ..FitReport::default()
        };
        Ok(Projection { grid: grid.clone(), rows, zero, hessian, base, tie })
    }

    /// The model with masses >= 0 whose output on the input is nearest (least squares
    /// over the samples) to that of `x` (Everett values, then the offset); `h`: that
    /// output, `B x` on every sample (it sets the scale the solvers work in).
    pub fn project(&self, x: &[f64], h: &[f64]) -> Result<(PreisachModel, FitReport)> {
        let n_q = self.rows.n_vars();
        if x.len() != n_q + 1 {
            return Err(PreisachError::invalid("x", format!("expected {} values, got {}", n_q + 1, x.len())));
        }
        if h.len() != self.base.n_samples {
            return Err(PreisachError::invalid(
                "h",
                format!("length {} does not match the input (length {})", h.len(), self.base.n_samples),
            ));
        }
        check_signal("x", x)?;
        check_signal("h", h)?;
        let t0 = Instant::now();
        let nt = h.len() as f64;
        let mu = h.iter().sum::<f64>() / nt;
        let var = h.iter().map(|v| (v - mu) * (v - mu)).sum::<f64>() / nt;
        let scale = if var > 0.0 { var.sqrt() } else { mu.abs().max(1.0) };
        let target: Vec<f64> = (0..self.rows.n_rows()).map(|r| row_dot(&self.rows, r, x)).collect();
        let pb = Problem { rows: &self.rows, mu, scale, zero: &self.zero, reg: self.tie };
        let q = linear_term_of(&pb, &target);
        let polish = self.tie == 0.0;
        let Solution { masses, offset, iterations } = solve_everett_with(&pb, &self.hessian, &q, None, polish)?;
        let model = PreisachModel::new(self.grid.clone(), masses, offset)?;
        // The residual's sum of squares over the samples: ‖B (x_model − x)‖², the merged
        // rows' sum (exact: they hold BᵀB).
        let mut d = model.everett_values();
        d.push(model.offset());
        d.iter_mut().zip(x).for_each(|(a, b)| *a -= b);
        let sse: f64 = (0..self.rows.n_rows()).map(|r| self.rows.weight[r] * row_dot(&self.rows, r, &d).powi(2)).sum();
        let report = FitReport {
            rmse: (sse / nt).sqrt(),
            solver: "structured",
            iterations,
            time_rows_s: 0.0,
            time_solve_s: t0.elapsed().as_secs_f64(),
            ..self.base.clone()
        };
        Ok((model, report))
    }
}

/// The smoothness weight checked: a finite number >= 0.
pub fn check_tie(tie: f64) -> Result<()> {
    check_scalar("tie", tie)?;
    if tie < 0.0 {
        return Err(PreisachError::invalid("tie", format!("must be >= 0, got {tie}")));
    }
    Ok(())
}

/// Row `r` (with its offset coefficient) times `x` (Everett values, then the offset).
fn row_dot(rows: &Rows, r: usize, x: &[f64]) -> f64 {
    let (idx, val) = rows.row(r);
    let n_q = x.len() - 1;
    idx.iter().zip(val).map(|(&i, &v)| v * x[i as usize]).sum::<f64>() + rows.offset_coef[r] * x[n_q]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::identify::testing::{input, signed, Rng};
    use crate::identify::{fit, FitOptions, Solver};

    fn output(m: &PreisachModel, u: &[f64]) -> Vec<f64> {
        let mut h = vec![0.0; u.len()];
        m.run_interpolated(&mut m.interp_memory(), u, &mut h);
        h
    }

    #[test]
    fn projection_equals_the_structured_fit_of_the_same_output() {
        // Several targets in turn on one input (signed masses, so the bounds are
        // active): the kept problem gives the structured fit's optimum output and RMSE,
        // with the same smoothness weight (none: the plain projection; `TIE`).
        let mut rng = Rng(0x9E37_79B9_7F4A_7C15);
        for tie in [0.0, TIE] {
            for n_h in [4usize, 7, 12] {
                let u = input(&mut rng, 6000);
                let grid = Grid::new(0.0, 1.0, n_h).unwrap();
                let proj = Projection::new(&grid, &u, tie).unwrap();
                let opts = FitOptions {
                    n_h,
                    u_range: Some((0.0, 1.0)),
                    reg: tie,
                    solver: Solver::Structured,
                    interpolated: true,
                    diagonal_floor: 0.0,
                };
                for k in 0..3 {
                    let (x, h) = signed(&mut rng, &grid, &u);
                    let (got, rep) = proj.project(&x, &h).unwrap();
                    let (want, wrep) = fit(&u, &h, &opts).unwrap();
                    let (a, b) = (output(&got, &u), output(&want, &u));
                    let span = h.iter().fold(0.0f64, |m, v| m.max(v.abs()));
                    let d = a.iter().zip(&b).fold(0.0f64, |e, (p, q)| e.max((p - q).abs()));
                    assert!(d <= 1e-7 * span, "tie {tie} n_h {n_h} target {k}: outputs differ by {d}");
                    assert!(got.masses().iter().all(|&w| w >= 0.0));
                    assert!(wrep.rmse > 1e-4 * span, "n_h {n_h} target {k}: the bounds are not active");
                    assert!((rep.rmse - wrep.rmse).abs() <= 1e-6 * wrep.rmse, "{} vs {}", rep.rmse, wrep.rmse);
                }
            }
        }
    }

    #[test]
    fn bad_arguments_are_named() {
        let mut rng = Rng(7);
        let u = input(&mut rng, 500);
        let grid = Grid::new(0.0, 1.0, 4).unwrap();
        for tie in [-1e-5, f64::NAN] {
            let err = Projection::new(&grid, &u, tie).err().unwrap().to_string();
            assert!(err.contains("tie"), "{err}");
        }
        let proj = Projection::new(&grid, &u, TIE).unwrap();
        let err = proj.project(&[0.0; 3], &u).unwrap_err().to_string();
        assert!(err.contains("x: expected 11 values"), "{err}");
        let err = proj.project(&[0.0; 11], &u[1..]).unwrap_err().to_string();
        assert!(err.contains("h: length 499"), "{err}");
        let mut x = vec![0.0; 11];
        x[2] = f64::NAN;
        assert!(proj.project(&x, &u).unwrap_err().to_string().contains("x:"));
    }
}
