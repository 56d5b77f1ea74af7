//! Identification bindings: `fit` and the regression rows (the latter for tests and
//! peer comparisons against SciPy on the same rows).

use std::sync::Arc;

use numpy::{IntoPyArray, PyArray1, PyArray2, PyArrayMethods, PyReadonlyArray1};
use std::sync::Mutex;

use numpy::{PyReadonlyArray2, PyUntypedArrayMethods};
use preisach_core::blocks::{Discretization, Filter};
use preisach_core::identify::filtered::{
    fit_behind as core_fit_behind, Behind as CoreBehind, BehindOptions, ProjectionHandle, Stop, Terms,
};
use preisach_core::identify::nnls::nnls as core_nnls;
use preisach_core::identify::{build_rows, fit as core_fit, FitOptions, Solver, DEFAULT_DIAGONAL_FLOOR};
use preisach_core::Grid;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::sim::Chain;
use crate::{guard, slice, to_py, Model};

/// Fit a model; returns (Model, report dict).
#[pyfunction]
#[pyo3(signature = (u, y, n_h, u_range=None, reg=0.0, solver="auto", interpolated=false, diagonal_floor=None))]
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
    diagonal_floor: Option<f64>,
) -> PyResult<(Model, Bound<'py, PyDict>)> {
    guard(|| {
        if n_h < 1 {
            return Err(to_py(preisach_core::PreisachError::invalid("n_h", format!("must be >= 1, got {n_h}"))));
        }
        let solver = Solver::parse(solver).map_err(to_py)?;
        let diagonal_floor = diagonal_floor.unwrap_or(DEFAULT_DIAGONAL_FLOOR);
        let opts = FitOptions { n_h: n_h as usize, u_range, reg, solver, interpolated, diagonal_floor };
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

/// Most values the dense rows of [`regression_rows`] may hold (2^27 doubles: 1 GiB).
const MAX_DENSE_ROWS_VALUES: usize = 1 << 27;

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
        let (a, rows) = py
            .detach(|| {
                let rows = build_rows(&grid, u, y, interpolated);
                let m = rows.n_rows();
                let values = m.saturating_mul(n_q + 1);
                if values > MAX_DENSE_ROWS_VALUES {
                    return Err(preisach_core::PreisachError::invalid(
                        "n_h",
                        format!(
                            "{n_h}: the dense rows would hold {m} x {} values ({:.1} GB), above the limit of \
                         {MAX_DENSE_ROWS_VALUES} values",
                            n_q + 1,
                            values as f64 * 8e-9
                        ),
                    ));
                }
                let mut a = vec![0.0; values];
                for r in 0..m {
                    let row = &mut a[r * (n_q + 1)..(r + 1) * (n_q + 1)];
                    rows.add_mass_row(r, 1.0, &mut row[..n_q]);
                    row[n_q] = rows.offset_coef[r];
                }
                Ok((a, rows))
            })
            .map_err(to_py)?;
        let m = rows.n_rows();
        let a = a.into_pyarray(py).reshape([m, n_q + 1])?;
        Ok((a, rows.weight.into_pyarray(py), rows.target.into_pyarray(py), rows.within_ss))
    })
}

/// Fit the interpolated model's masses behind a chain of linear blocks (the diagnoser's
/// augmented chains); returns (Model, report dict).
#[pyfunction]
#[pyo3(signature = (u, z, n_h, u_range, dt, chain, weights=None, tol=1e-6, max_iter=200))]
#[allow(clippy::too_many_arguments)]
fn fit_behind<'py>(
    py: Python<'py>,
    u: PyReadonlyArray1<'py, f64>,
    z: PyReadonlyArray1<'py, f64>,
    n_h: i64,
    u_range: (f64, f64),
    dt: f64,
    chain: PyRef<'py, Chain>,
    weights: Option<PyReadonlyArray1<'py, f64>>,
    tol: f64,
    max_iter: usize,
) -> PyResult<(Model, Bound<'py, PyDict>)> {
    guard(|| {
        if n_h < 1 {
            return Err(to_py(preisach_core::PreisachError::invalid("n_h", format!("must be >= 1, got {n_h}"))));
        }
        let (u, z) = (slice("u", &u)?, slice("z", &z)?);
        let w = match &weights {
            Some(w) => Some(slice("weights", w)?),
            None => None,
        };
        let blocks = chain.desc().ltis().map_err(to_py)?;
        let opts = BehindOptions { n_h: n_h as usize, u_range, dt, tol, max_iter };
        let (model, rep) = py.detach(|| core_fit_behind(u, z, w, &blocks, &opts)).map_err(to_py)?;
        let d = PyDict::new(py);
        d.set_item("iterations", rep.iterations)?;
        d.set_item("residual", rep.residual)?;
        d.set_item("rmse", rep.rmse)?;
        d.set_item("rmse_unconstrained", rep.rmse_unconstrained)?;
        d.set_item("solver", rep.projection.solver)?;
        Ok((Model { inner: Arc::new(model) }, d))
    })
}

/// `x >= 0` minimizing `|a x - b|` for a few dense columns (clarabel, then the support
/// polished by least squares).
#[pyfunction]
fn nnls<'py>(
    py: Python<'py>,
    a: PyReadonlyArray2<'py, f64>,
    b: PyReadonlyArray1<'py, f64>,
) -> PyResult<Bound<'py, PyArray1<f64>>> {
    guard(|| {
        let b = slice("b", &b)?;
        let (m, n) = (a.shape()[0], a.shape()[1]);
        if m != b.len() {
            return Err(PyValueError::new_err(format!("a: expected len(b) = {} rows, got {m}", b.len())));
        }
        let av: Vec<f64> = a.as_array().iter().copied().collect();
        let x = py.detach(|| core_nnls(&av, n, b)).map_err(to_py)?;
        Ok(x.into_pyarray(py))
    })
}

/// A fit problem on one input (rows and preconditioner built once): fits targets
/// behind linear blocks, for profiling effect parameters. ``initial_extrema``: the
/// hysteresis memory at the input's start is the one after these alternating extrema
/// (input units; a history nobody recorded), as the hysteresis block's.
#[pyclass(frozen, module = "preisach._preisach")]
pub struct Behind {
    inner: Mutex<CoreBehind>,
    /// What a session sharing this one's projection takes: the inner session's handle,
    /// kept under a lock of its own (read while the session may be solving) and replaced
    /// when the session shares another's.
    handle: Mutex<ProjectionHandle>,
}

fn rows_of<'a>(name: &str, a: &'a Option<PyReadonlyArray2<'_, f64>>) -> PyResult<Vec<&'a [f64]>> {
    match a {
        None => Ok(Vec::new()),
        Some(a) => {
            let n = a.shape()[1];
            let s = a
                .as_slice()
                .map_err(|_| PyValueError::new_err(format!("{name}: array must be C-contiguous float64")))?;
            Ok(if n == 0 { Vec::new() } else { s.chunks(n).collect() })
        }
    }
}

#[pymethods]
impl Behind {
    #[new]
    #[pyo3(signature = (u, n_h, u_range, stride=1, tie=0.0, initial_extrema=None))]
    fn new(
        py: Python<'_>,
        u: PyReadonlyArray1<'_, f64>,
        n_h: i64,
        u_range: (f64, f64),
        stride: usize,
        tie: f64,
        initial_extrema: Option<Vec<f64>>,
    ) -> PyResult<Self> {
        guard(|| {
            if n_h < 1 {
                return Err(to_py(preisach_core::PreisachError::invalid("n_h", format!("must be >= 1, got {n_h}"))));
            }
            let u = slice("u", &u)?;
            let ex = initial_extrema.unwrap_or_default();
            let mut b = py.detach(|| CoreBehind::after(&ex, u, n_h as usize, u_range, stride)).map_err(to_py)?;
            b.set_tie(tie).map_err(to_py)?;
            let handle = Mutex::new(b.projection_handle());
            Ok(Behind { inner: Mutex::new(b), handle })
        })
    }

    /// Share ``other``'s masses' projection (the same input, range, ``n_h`` and ``tie``;
    /// any stride): built once, by the first session that projects. Call it before this
    /// session projects (it waits for a solve running on this session, never on
    /// ``other``'s).
    fn share(&self, py: Python<'_>, other: PyRef<'_, Behind>) -> PyResult<()> {
        guard(|| {
            let handle = other.handle.lock().unwrap_or_else(|e| e.into_inner()).clone();
            py.detach(|| self.inner.lock().unwrap_or_else(|e| e.into_inner()).share_projection(&handle))
                .map_err(to_py)?;
            *self.handle.lock().unwrap_or_else(|e| e.into_inner()) = handle;
            Ok(())
        })
    }

    /// A session of the same problem for another thread, as a new session would be but
    /// without the rows and the preconditioner's Gram matrix built again (the rows and
    /// the masses' projection shared); it starts cold.
    fn fork(&self, py: Python<'_>) -> PyResult<Behind> {
        guard(|| {
            let b = py.detach(|| self.inner.lock().unwrap_or_else(|e| e.into_inner()).fork()).map_err(to_py)?;
            let handle = Mutex::new(self.handle.lock().unwrap_or_else(|e| e.into_inner()).clone());
            Ok(Behind { inner: Mutex::new(b), handle })
        })
    }

    /// Number of output samples (windows of ``stride`` input samples).
    #[getter]
    fn n_out(&self) -> usize {
        self.inner.lock().unwrap_or_else(|e| e.into_inner()).n_samples()
    }

    /// Unconstrained optimum of the fit behind ``chain`` (its linear blocks; its delay
    /// delays the hysteresis output before the averaging), and with ``nnls`` the masses
    /// >= 0: a dict with rmse, iterations, residual, extra (coefficients of pre then post
    /// columns), gave_up and, with ``nnls``, model, rmse_nnls, extra_nnls. ``above``: give
    /// up a fit that cannot get below this weighted RMSE (``gave_up``; its rmse is then
    /// where it stopped).
    #[pyo3(signature = (z, dt, chain, weights=None, pre=None, post=None, tol=1e-4, max_iter=300, warm=true, nnls=false, above=None))]
    #[allow(clippy::too_many_arguments)]
    fn solve<'py>(
        &self,
        py: Python<'py>,
        z: PyReadonlyArray1<'py, f64>,
        dt: f64,
        chain: PyRef<'py, Chain>,
        weights: Option<PyReadonlyArray1<'py, f64>>,
        pre: Option<PyReadonlyArray2<'py, f64>>,
        post: Option<PyReadonlyArray2<'py, f64>>,
        tol: f64,
        max_iter: usize,
        warm: bool,
        nnls: bool,
        above: Option<f64>,
    ) -> PyResult<Bound<'py, PyDict>> {
        guard(|| {
            let z = slice("z", &z)?;
            let w = match &weights {
                Some(w) => Some(slice("weights", w)?),
                None => None,
            };
            let (pre_rows, post_rows) = (rows_of("pre", &pre)?, rows_of("post", &post)?);
            let blocks = chain.desc().ltis().map_err(to_py)?;
            let stride = self.inner.lock().unwrap_or_else(|e| e.into_inner()).stride();
            // The chain's delay in input samples (the fit's samples are windows of `stride`).
            let delay = blocks.iter().map(|b| b.delay_s).sum::<f64>() / dt * stride as f64;
            let terms = Terms { omega: w, pre: &pre_rows, post: &post_rows, delay };
            let res = py
                .detach(|| {
                    preisach_core::error::check_scalar("dt", dt)?;
                    if dt <= 0.0 {
                        return Err(preisach_core::PreisachError::invalid("dt", format!("must be > 0, got {dt}")));
                    }
                    let mut lti = Filter::cascade(&blocks, dt, Discretization::Foh);
                    let mut b = self.inner.lock().unwrap_or_else(|e| e.into_inner());
                    let sol = b.solve(z, &mut lti, &terms, &Stop { tol, max_iter, above }, warm)?;
                    let proj = if nnls { Some(b.project(&sol, z, &mut lti, &terms)?) } else { None };
                    Ok::<_, preisach_core::PreisachError>((sol, proj))
                })
                .map_err(to_py)?;
            let (sol, proj) = res;
            let d = PyDict::new(py);
            d.set_item("rmse", sol.rmse)?;
            d.set_item("iterations", sol.iterations)?;
            d.set_item("residual", sol.residual)?;
            d.set_item("extra", sol.extra)?;
            d.set_item("gave_up", sol.gave_up)?;
            if let Some((model, coef, rmse, _)) = proj {
                d.set_item("model", Model { inner: Arc::new(model) })?;
                d.set_item("rmse_nnls", rmse)?;
                d.set_item("extra_nnls", coef)?;
            }
            Ok(d)
        })
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("DEFAULT_DIAGONAL_FLOOR", DEFAULT_DIAGONAL_FLOOR)?;
    m.add("PROJECTION_TIE", preisach_core::identify::projection::TIE)?;
    m.add_class::<Behind>()?;
    m.add_function(wrap_pyfunction!(fit, m)?)?;
    m.add_function(wrap_pyfunction!(fit_behind, m)?)?;
    m.add_function(wrap_pyfunction!(nnls, m)?)?;
    m.add_function(wrap_pyfunction!(regression_rows, m)?)?;
    Ok(())
}
