//! Identification (the paper §3.2–3.3, done exactly): non-negative least squares on the
//! masses with a free offset in one QP, over merged rows, with the paper's pitfalls
//! reported.

pub mod active;
pub mod filtered;
pub mod nnls;
mod order;
pub mod projection;
pub mod qp;
pub mod rows;
#[cfg(test)]
mod testing;

use crate::error::{check_scalar, check_signal, PreisachError, Result};
use crate::grid::{cell_index, Grid};
use crate::model::PreisachModel;
pub use qp::{dense_bytes, Problem, Solution};
pub use rows::{build_rows, Rows};

/// Largest n_h `fit` accepts: the sparse factors grow like n_q^1.5 (time and memory
/// measured in `docs/method/identification.md`).
pub const MAX_N_H_STRUCTURED: usize = 600;

/// `auto` uses the active-set solver up to this many free cells (it needs a handful of
/// sparse factorizations there; beyond, its step count grows and the interior point wins).
pub const ACTIVE_AUTO_MAX: usize = 2000;
/// Step cap of the active-set solver before it hands over to the interior point.
pub const ACTIVE_STEPS: u32 = 40;

/// Which exact solver to use.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Solver {
    /// The active-set solver up to [`ACTIVE_AUTO_MAX`] free cells of stepwise rows, else
    /// the structured one.
    Auto,
    /// Dense QP over the masses (AᵀWA formed), clarabel.
    Clarabel,
    /// Sparse QP in Everett coordinates, clarabel; never forms the dense matrix.
    Structured,
    /// Primal–dual active set on the sparse Everett-coordinate KKT system (exact; the
    /// fastest for small and mid-size n_h).
    Active,
}

impl Solver {
    pub fn parse(s: &str) -> Result<Self> {
        match s {
            "auto" => Ok(Solver::Auto),
            "clarabel" => Ok(Solver::Clarabel),
            "structured" => Ok(Solver::Structured),
            "active" => Ok(Solver::Active),
            "gradient" => Err(PreisachError::invalid(
                "solver",
                format!("'gradient' has been removed; use 'auto' or 'structured' (exact, n_h <= {MAX_N_H_STRUCTURED})"),
            )),
            _ => Err(PreisachError::invalid(
                "solver",
                format!("expected 'auto', 'active', 'clarabel' or 'structured', got {s:?}"),
            )),
        }
    }
}

/// Options of [`fit`].
#[derive(Debug, Clone)]
pub struct FitOptions {
    pub n_h: usize,
    /// Model range; `None` = [`default_range`] of the input.
    pub u_range: Option<(f64, f64)>,
    pub reg: f64,
    pub solver: Solver,
    /// Fit the interpolated model (masses spread over their cells) instead of the
    /// stepwise one.
    pub interpolated: bool,
    /// Lower bound on the diagonal (reversible) masses of the excited cells, as a
    /// fraction of the average slope of the major loop: every diagonal mass is at least
    /// `diagonal_floor · span(y) / (2 · excited levels)`, so a branch leaving a turn of
    /// the input starts with at least that fraction of the average slope. 0 = plain
    /// non-negative least squares. [`DEFAULT_DIAGONAL_FLOOR`] is the default.
    pub diagonal_floor: f64,
}

/// Default [`FitOptions::diagonal_floor`]: a branch leaving a turn starts with at least
/// 1 % of the major loop's average slope. Without a floor, dynamics the static model
/// cannot follow (lag, creep) often drive fitted diagonal masses to zero: the model is
/// then flat for up to a cell after every turn and its continuous inverse jumps across
/// that flat (`docs/method/inversion.md`).
pub const DEFAULT_DIAGONAL_FLOOR: f64 = 0.01;

/// What the fit did and what to worry about.
#[derive(Debug, Clone, Default)]
pub struct FitReport {
    /// RMSE of the fitted model on the training samples, output units.
    pub rmse: f64,
    pub n_samples: usize,
    /// Distinct relay states (merged regression rows).
    pub n_rows: usize,
    /// Direction changes of the quantized input (what the relays see).
    pub reversals: usize,
    /// Cells whose relay never switched on (fixed to zero: the data says nothing).
    pub cells_never_excited: usize,
    /// Cells switched on but never off again (identified only in sums).
    pub cells_switched_once: usize,
    pub input_min: f64,
    pub input_max: f64,
    pub lo: f64,
    pub hi: f64,
    pub solver: &'static str,
    pub iterations: u32,
    /// Wall time spent building the merged rows and solving the QP.
    pub time_rows_s: f64,
    pub time_solve_s: f64,
    /// The paper's pitfalls (§3.3) met by this data, as sentences.
    pub warnings: Vec<String>,
}

/// Default model range: the input range shrunk by 0.5 % of its span on each side, so
/// the input slightly exceeds the model range as the paper advises (§3.3, Fig. 7b:
/// model [−90, 90] identified from input [−91, 91]).
pub fn default_range(u: &[f64]) -> Result<(f64, f64)> {
    check_signal("u", u)?;
    let (mn, mx) = min_max(u);
    if mx <= mn {
        return Err(PreisachError::invalid("u", format!("input is constant ({mn}); it has no range to identify")));
    }
    let pad = 0.005 * (mx - mn);
    Ok((mn + pad, mx - pad))
}

/// Range of a finite signal (four lanes of plain comparisons: they vectorize, where
/// the NaN-aware `f64::min` does not).
pub(super) fn min_max(u: &[f64]) -> (f64, f64) {
    let mut lo = [f64::INFINITY; 4];
    let mut hi = [f64::NEG_INFINITY; 4];
    let chunks = u.chunks_exact(4);
    let tail = chunks.remainder();
    for c in chunks {
        for t in 0..4 {
            lo[t] = if c[t] < lo[t] { c[t] } else { lo[t] };
            hi[t] = if c[t] > hi[t] { c[t] } else { hi[t] };
        }
    }
    let (mut a, mut b) = (lo[0].min(lo[1]).min(lo[2].min(lo[3])), hi[0].max(hi[1]).max(hi[2].max(hi[3])));
    for &x in tail {
        a = a.min(x);
        b = b.max(x);
    }
    (a, b)
}

/// Excitation statistics on the quantized levels (consecutive repeats may be dropped:
/// they change nothing here): (reversals, never switched on, switched on but never off).
pub(super) fn excitation(q: &[u32], n_h: usize) -> (usize, usize, usize) {
    let mut reversals = 0;
    let mut dir = 0i8;
    for w in q.windows(2) {
        let d = (w[1] as i64 - w[0] as i64).signum() as i8;
        if d != 0 {
            if dir != 0 && d != dir {
                reversals += 1;
            }
            dir = d;
        }
    }
    // Cell (i, j) switches on when the level first reaches j + 1 and off when it later
    // falls to i or below.
    let n = q.len();
    let mut suffix_min = vec![u32::MAX; n + 1];
    for t in (0..n).rev() {
        suffix_min[t] = suffix_min[t + 1].min(q[t]);
    }
    let mut first = vec![usize::MAX; n_h];
    let mut reached = 0usize;
    for (t, &k) in q.iter().enumerate() {
        while reached < k as usize {
            first[reached] = t;
            reached += 1;
        }
    }
    let mut never = 0;
    let mut once = 0;
    for (j, &t) in first.iter().enumerate() {
        if t == usize::MAX {
            never += j + 1;
        } else {
            let m = suffix_min[t + 1].min(j as u32 + 1) as usize;
            once += m; // i < m never switched off again
        }
    }
    (reversals, never, once)
}

/// Training sum of squared residuals of a stepwise model from its merged rows (exact:
/// a row's samples share one prediction, so each contributes its count times the squared
/// residual at the row mean, plus the within-row scatter), without re-running the model
/// over every sample. (Interpolated pseudo-rows hold the scatter only as a difference of
/// large sums, so those are re-predicted instead.)
fn stepwise_sse(rows: &Rows, model: &PreisachModel) -> f64 {
    let n_h = rows.n_h;
    let ev = model.everett();
    // Everett value of each variable index E(a, b), a > b, packed like `everett_var`.
    let mut e = Vec::with_capacity(rows.n_vars());
    for a in 1..=n_h {
        for b in 0..a {
            e.push(ev.at(a as u32, b as u32));
        }
    }
    let mut sse = rows.within_ss;
    for r in 0..rows.n_rows() {
        let (idx, val) = rows.row(r);
        let p: f64 =
            idx.iter().zip(val).map(|(&k, &v)| v * e[k as usize]).sum::<f64>() + rows.offset_coef[r] * model.offset();
        let d = p - rows.target[r];
        sse += rows.weight[r] * d * d;
    }
    sse
}

/// The diagonal floor's mass per excited diagonal cell: `fraction · span(y) / (2 · top)`
/// (half the output span spread over the `top` excited levels is the major loop's
/// average slope per level).
fn diagonal_floor_mass(y: &[f64], top: usize, fraction: f64) -> Result<f64> {
    check_scalar("diagonal_floor", fraction)?;
    if !(0.0..1.0).contains(&fraction) {
        return Err(PreisachError::invalid("diagonal_floor", format!("must be in [0, 1), got {fraction}")));
    }
    if fraction == 0.0 || top == 0 {
        return Ok(0.0);
    }
    let (lo, hi) = min_max(y);
    Ok(fraction * (hi - lo) / (2.0 * top as f64))
}

/// `y` minus the output of `floor` on each of the excited diagonal cells (i < `top`):
/// with the masses `w = w' + floor` on those cells, a fit of `w' >= 0` to this is the
/// fit of `w` with the diagonal bounded below by the floor, with the same residuals.
fn above_floor(grid: &Grid, u: &[f64], y: &[f64], top: usize, floor: f64, interpolated: bool) -> Result<Vec<f64>> {
    let n_h = grid.n_h();
    let mut masses = vec![0.0; grid.n_q()];
    for i in 0..top.min(n_h) {
        masses[cell_index(n_h, i, i)] = floor;
    }
    let diag = PreisachModel::new(grid.clone(), masses, 0.0)?;
    let mut out = vec![0.0; u.len()];
    if interpolated {
        diag.run_interpolated(&mut diag.interp_memory(), u, &mut out);
    } else {
        diag.run(&mut diag.memory(), u, &mut out);
    }
    for (o, &v) in out.iter_mut().zip(y) {
        *o = v - *o;
    }
    Ok(out)
}

/// The quantized input levels, consecutive repeats dropped (what the relays see).
pub(super) fn seen_levels(grid: &Grid, u: &[f64]) -> Vec<u32> {
    let mut seen = Vec::new();
    for &x in u {
        let k = grid.quantize(x);
        if seen.last() != Some(&k) {
            seen.push(k);
        }
    }
    seen
}

/// Cells never switched on (i, j >= `top`): their column equals the offset's, so they
/// are fixed to 0.
pub(super) fn never_on(grid: &Grid, top: usize) -> Vec<bool> {
    let n_h = grid.n_h();
    let mut zero = vec![false; grid.n_q()];
    for i in 0..n_h {
        for j in i.max(top)..n_h {
            zero[cell_index(n_h, i, j)] = true;
        }
    }
    zero
}

/// The paper's pitfalls (§3.3) met by an input of range `(u_min, u_max)` with
/// `reversals` reversals, for a model of n_h levels on `(lo, hi)`, as sentences.
pub(super) fn pitfalls(reversals: usize, n_h: usize, (u_min, u_max): (f64, f64), (lo, hi): (f64, f64)) -> Vec<String> {
    let mut warnings = Vec::new();
    if reversals < n_h {
        warnings.push(format!(
            "only {reversals} input reversals for n_h = {n_h}: fewer than n_h, so not every relay is switched on and off (Stakvik et al. 2015, §3.2); use more reversals or a smaller n_h"
        ));
    }
    if u_max < hi || u_min > lo {
        warnings.push(format!(
            "the input range [{u_min:.4}, {u_max:.4}] does not exceed the model range [{lo:.4}, {hi:.4}]: border cells are not excited and absorb the offset (Stakvik et al. 2015, §3.3, Fig. 7a)"
        ));
    }
    let span = hi - lo;
    if u_max - hi > 0.1 * span || lo - u_min > 0.1 * span {
        warnings.push(format!(
            "the input range [{u_min:.4}, {u_max:.4}] extends far beyond the model range [{lo:.4}, {hi:.4}]: the end cells absorb everything outside it (Stakvik et al. 2015, §3.3, Fig. 7c)"
        ));
    }
    warnings
}

/// Identify a model from input `u` and measured output `y`.
pub fn fit(u: &[f64], y: &[f64], opts: &FitOptions) -> Result<(PreisachModel, FitReport)> {
    check_signal("u", u)?;
    check_signal("y", y)?;
    if u.len() != y.len() {
        return Err(PreisachError::invalid("y", format!("length {} does not match u (length {})", y.len(), u.len())));
    }
    check_scalar("reg", opts.reg)?;
    if opts.reg < 0.0 {
        return Err(PreisachError::invalid("reg", format!("must be >= 0, got {}", opts.reg)));
    }
    let (lo, hi) = match opts.u_range {
        Some(r) => r,
        None => default_range(u)?,
    };
    let grid = Grid::new(lo, hi, opts.n_h)?;
    let n_h = grid.n_h();
    // The sparse factors grow faster than n_q (like n_q^1.5): refuse before allocating
    // rather than exhaust the machine.
    if n_h > MAX_N_H_STRUCTURED {
        return Err(PreisachError::invalid(
            "n_h",
            format!("{n_h} is too large to identify (the solvers handle n_h <= {MAX_N_H_STRUCTURED})"),
        ));
    }
    let (u_min, u_max) = min_max(u);
    // Cells (i, j) with j >= top were never switched on.
    let top = if opts.interpolated { grid.position(u_max).ceil() as usize } else { grid.quantize(u_max) as usize };
    let floor = diagonal_floor_mass(y, top, opts.diagonal_floor)?;
    let shifted;
    let y = if floor > 0.0 {
        shifted = above_floor(&grid, u, y, top, floor, opts.interpolated)?;
        &shifted[..]
    } else {
        y
    };

    let t_rows = std::time::Instant::now();
    let rows = build_rows(&grid, u, y, opts.interpolated);
    let time_rows_s = t_rows.elapsed().as_secs_f64();
    // The levels the relays saw, repeats dropped (the stepwise rows record them).
    let seen;
    let levels: &[u32] = if opts.interpolated {
        seen = seen_levels(&grid, u);
        &seen
    } else {
        &rows.levels
    };
    let (reversals, never, once) = excitation(levels, n_h);
    let zero = never_on(&grid, top);

    // Mean and variance of y: from the stepwise rows (counts, means and within-row
    // scatter hold them exactly) rather than two more passes over the samples.
    let nt = y.len() as f64;
    let (mu, var) = if opts.interpolated {
        let mu = y.iter().sum::<f64>() / nt;
        (mu, y.iter().map(|v| (v - mu) * (v - mu)).sum::<f64>() / nt)
    } else {
        let mu = rows.weight.iter().zip(&rows.target).map(|(w, t)| w * t).sum::<f64>() / nt;
        let between: f64 = rows.weight.iter().zip(&rows.target).map(|(w, t)| w * (t - mu) * (t - mu)).sum();
        (mu, (between + rows.within_ss) / nt)
    };
    let scale = if var > 0.0 { var.sqrt() } else { mu.abs().max(1.0) };
    let pb = Problem { rows: &rows, mu, scale, zero: &zero, reg: opts.reg };
    let n_free = zero.iter().filter(|z| !**z).count();
    let solver = match opts.solver {
        // Interpolated rows make the active-set method cycle (it would give up after
        // wasted factorizations), so those go to the interior point.
        Solver::Auto if n_free <= ACTIVE_AUTO_MAX && !opts.interpolated => Solver::Active,
        Solver::Auto => Solver::Structured,
        s => s,
    };
    let t_solve = std::time::Instant::now();
    let mut solver = solver;
    let sol = match solver {
        Solver::Active => match active::solve_active(&pb, None, ACTIVE_STEPS)? {
            Some(sol) => sol,
            None => {
                // Did not settle within the step cap: the interior point always does.
                solver = Solver::Structured;
                qp::solve_everett(&pb)?
            }
        },
        Solver::Clarabel => {
            let need = dense_bytes(rows.n_rows(), n_free);
            if need > 4e9 {
                return Err(PreisachError::invalid(
                    "n_h",
                    format!(
                        "{n_h} is too large for the dense solver ({:.1} GB needed); use solver='structured'",
                        need / 1e9
                    ),
                ));
            }
            qp::solve_dense(&pb)?
        }
        _ => qp::solve_everett(&pb)?,
    };
    let time_solve_s = t_solve.elapsed().as_secs_f64();
    let model = PreisachModel::new(grid.clone(), sol.masses, sol.offset)?;

    let sse = if opts.interpolated {
        let mut pred = vec![0.0; u.len()];
        model.run_interpolated(&mut model.interp_memory(), u, &mut pred);
        pred.iter().zip(y).map(|(p, t)| (p - t) * (p - t)).sum()
    } else {
        stepwise_sse(&rows, &model)
    };
    // The fit above is of the masses above the floor (same residuals): add it back.
    let model = if floor > 0.0 {
        let mut masses = model.masses().to_vec();
        for i in 0..top.min(n_h) {
            masses[cell_index(n_h, i, i)] += floor;
        }
        PreisachModel::new(grid.clone(), masses, model.offset())?
    } else {
        model
    };

    let warnings = pitfalls(reversals, n_h, (u_min, u_max), (lo, hi));
    let report = FitReport {
        rmse: (sse / u.len() as f64).sqrt(),
        n_samples: u.len(),
        n_rows: rows.n_rows(),
        reversals,
        cells_never_excited: never,
        cells_switched_once: once,
        input_min: u_min,
        input_max: u_max,
        lo,
        hi,
        solver: match solver {
            Solver::Clarabel => "clarabel",
            Solver::Active => "active",
            _ => "structured",
        },
        iterations: sol.iterations,
        time_rows_s,
        time_solve_s,
        warnings,
    };
    Ok((model, report))
}
