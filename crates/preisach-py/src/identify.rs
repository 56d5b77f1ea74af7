//! Identification bindings: `fit` and the regression rows (the latter for tests and
//! peer comparisons against SciPy on the same rows).

use std::sync::Arc;

use numpy::{IntoPyArray, PyArray1, PyArray2, PyArrayMethods, PyReadonlyArray1};
use preisach_core::identify::{build_rows, fit as core_fit, FitOptions, Solver};
use preisach_core::Grid;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::{guard, slice, to_py, Model};

/// Fit a model; returns (Model, report dict).
#[pyfunction]
#[pyo3(signature = (u, y, n_h, u_range=None, reg=0.0, solver="auto", interpolated=false))]
#[allow(clippy::too_many_arguments)]
fn fit<'py>(
    py: Python<'py>,
    u: PyReadonlyArray1<'py, f64>,
    y: PyReadonlyArray1<'py, f64>,
    n_h: i64,
    u_range: Option<(f64, f64)>,
    reg: f64,
    solver: &str,
    interpolated: bool,
) -> PyResult<(Model, Bound<'py, PyDict>)> {
    guard(|| {
        if n_h < 1 {
            return Err(to_py(preisach_core::PreisachError::invalid("n_h", format!("must be >= 1, got {n_h}"))));
        }
        let opts = FitOptions {
            n_h: n_h as usize,
            u_range,
            reg,
            solver: Solver::parse(solver).map_err(to_py)?,
            interpolated,
        };
        let (u, y) = (slice("u", &u)?, slice("y", &y)?);
        let (model, rep) = py.detach(|| core_fit(u, y, &opts)).map_err(to_py)?;
        let d = PyDict::new(py);
        d.set_item("rmse", rep.rmse)?;
        d.set_item("n_samples", rep.n_samples)?;
        d.set_item("n_rows", rep.n_rows)?;
        d.set_item("reversals", rep.reversals)?;
        d.set_item("cells_never_excited", rep.cells_never_excited)?;
        d.set_item("cells_switched_once", rep.cells_switched_once)?;
        d.set_item("input_range", (rep.input_min, rep.input_max))?;
        d.set_item("u_range", (rep.lo, rep.hi))?;
        d.set_item("solver", rep.solver)?;
        d.set_item("iterations", rep.iterations)?;
        d.set_item("time_rows_s", rep.time_rows_s)?;
        d.set_item("time_solve_s", rep.time_solve_s)?;
        d.set_item("warnings", rep.warnings)?;
        Ok((Model { inner: Arc::new(model) }, d))
    })
}

/// The merged regression rows in mass coordinates: (A (rows, n_q + 1) with the offset
/// column last, counts, targets, within-row sum of squares). Objective:
/// (Σ counts·(A x − targets)² + within) / n_samples. Dense: for tests and
/// comparisons only.
#[pyfunction]
#[pyo3(signature = (u, y, n_h, u_range, interpolated=false))]
#[allow(clippy::type_complexity)]
fn regression_rows<'py>(
    py: Python<'py>,
    u: PyReadonlyArray1<'py, f64>,
    y: PyReadonlyArray1<'py, f64>,
    n_h: usize,
    u_range: (f64, f64),
    interpolated: bool,
) -> PyResult<(Bound<'py, PyArray2<f64>>, Bound<'py, PyArray1<f64>>, Bound<'py, PyArray1<f64>>, f64)> {
    guard(|| {
        let (u, y) = (slice("u", &u)?, slice("y", &y)?);
        if u.len() != y.len() {
            return Err(to_py(preisach_core::PreisachError::invalid("y", "length does not match u")));
        }
        preisach_core::error::check_signal("u", u).map_err(to_py)?;
        preisach_core::error::check_signal("y", y).map_err(to_py)?;
        let grid = Grid::new(u_range.0, u_range.1, n_h).map_err(to_py)?;
        let n_q = grid.n_q();
        // Without the GIL: the diagnoser builds rows for several candidates in threads.
        let (a, rows) = py.detach(|| {
            let rows = build_rows(&grid, u, y, interpolated);
            let m = rows.n_rows();
            let mut a = vec![0.0; m * (n_q + 1)];
            for r in 0..m {
                let row = &mut a[r * (n_q + 1)..(r + 1) * (n_q + 1)];
                rows.add_mass_row(r, 1.0, &mut row[..n_q]);
                row[n_q] = rows.offset_coef[r];
            }
            (a, rows)
        });
        let m = rows.n_rows();
        let a = a.into_pyarray(py).reshape([m, n_q + 1])?;
        Ok((a, rows.weight.into_pyarray(py), rows.target.into_pyarray(py), rows.within_ss))
    })
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(fit, m)?)?;
    m.add_function(wrap_pyfunction!(regression_rows, m)?)?;
    Ok(())
}
