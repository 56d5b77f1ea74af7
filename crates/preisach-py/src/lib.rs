//! pyo3 glue for `preisach._preisach`: arrays in, arrays out, core errors mapped to
//! `ValueError`. No modelling logic lives here.

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::Arc;

use numpy::{
    IntoPyArray, PyArray1, PyArray2, PyArrayMethods, PyReadonlyArray1, PyReadonlyArray2, PyUntypedArrayMethods,
};
use preisach_core::model::StepMemory;
use preisach_core::{PreisachError, PreisachModel};
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;

mod chain_invert;
mod identify;
mod invert;
mod sim;

/// Core error → Python `ValueError` with the core's message (names the argument).
pub(crate) fn to_py(e: PreisachError) -> PyErr {
    PyValueError::new_err(e.to_string())
}

/// Run `f` so that a Rust panic surfaces as a `RuntimeError`, never as a
/// `PanicException` (which is not an `Exception`).
pub(crate) fn guard<T>(f: impl FnOnce() -> PyResult<T>) -> PyResult<T> {
    match catch_unwind(AssertUnwindSafe(f)) {
        Ok(r) => r,
        Err(p) => {
            let msg = p
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| p.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "unknown".into());
            Err(PyRuntimeError::new_err(format!("internal error in preisach core: {msg}")))
        }
    }
}

/// Borrow a contiguous float64 1-D array (the Python layer converts before calling).
pub(crate) fn slice<'a>(name: &str, a: &'a PyReadonlyArray1<'_, f64>) -> PyResult<&'a [f64]> {
    a.as_slice().map_err(|_| PyValueError::new_err(format!("{name}: array must be C-contiguous float64")))
}

/// Two float64 arrays (output and final state).
type ArrayPair<'py> = (Bound<'py, PyArray1<f64>>, Bound<'py, PyArray1<f64>>);

/// The compiled model: grid, masses, offset, Everett table.
#[pyclass(frozen, module = "preisach._preisach")]
pub struct Model {
    pub(crate) inner: Arc<PreisachModel>,
}

#[pymethods]
impl Model {
    #[new]
    fn new(weights: PyReadonlyArray2<'_, f64>, lo: f64, hi: f64, offset: f64) -> PyResult<Self> {
        guard(|| {
            let shape = weights.shape();
            if shape.len() != 2 || shape[0] != shape[1] {
                return Err(PyValueError::new_err(format!(
                    "weights: expected a square (n_h, n_h) array, got shape {shape:?}"
                )));
            }
            let n_h = shape[0];
            if n_h < 1 {
                return Err(PyValueError::new_err("n_h: must be >= 1, got 0"));
            }
            let dense = weights.as_slice().map_err(|_| PyValueError::new_err("weights: must be C-contiguous"))?;
            let m = PreisachModel::from_dense(lo, hi, n_h, dense, offset).map_err(to_py)?;
            Ok(Model { inner: Arc::new(m) })
        })
    }

    /// Dense (n_h, n_h) weights, zero below the diagonal.
    fn weights<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let n = self.inner.n_h();
        let arr = self.inner.dense_weights().into_pyarray(py);
        arr.reshape([n, n])
    }

    #[getter]
    fn n_h(&self) -> usize {
        self.inner.n_h()
    }
    #[getter]
    fn lo(&self) -> f64 {
        self.inner.grid().lo()
    }
    #[getter]
    fn hi(&self) -> f64 {
        self.inner.grid().hi()
    }
    #[getter]
    fn offset(&self) -> f64 {
        self.inner.offset()
    }

    fn levels<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        self.inner.grid().levels().into_pyarray(py)
    }

    /// Run the model over `u` from `state` (input values; empty = negative saturation).
    /// Returns (y, final state). `interpolated` selects the continuous output.
    #[pyo3(signature = (u, state, interpolated=false))]
    fn predict<'py>(
        &self,
        py: Python<'py>,
        u: PyReadonlyArray1<'py, f64>,
        state: PyReadonlyArray1<'py, f64>,
        interpolated: bool,
    ) -> PyResult<ArrayPair<'py>> {
        guard(|| {
            let u = slice("u", &u)?;
            let state = slice("state", &state)?;
            let m = &self.inner;
            let (y, snap) = py
                .detach(|| -> Result<_, PreisachError> {
                    preisach_core::error::check_finite("u", u)?;
                    let mut y = vec![0.0; u.len()];
                    if interpolated {
                        let mut mem = m.interp_memory_from(state)?;
                        m.run_interpolated(&mut mem, u, &mut y);
                        Ok((y, m.interp_memory_values(&mem)))
                    } else {
                        let mut mem = m.step_memory_from(state)?;
                        m.run(&mut mem, u, &mut y);
                        Ok((y, m.step_memory_values(&mem)))
                    }
                })
                .map_err(to_py)?;
            Ok((y.into_pyarray(py), snap.into_pyarray(py)))
        })
    }

    /// A streaming stepwise operator starting from `state`.
    fn stream(&self, state: PyReadonlyArray1<'_, f64>) -> PyResult<Stream> {
        guard(|| {
            let mem = self.inner.step_memory_from(slice("state", &state)?).map_err(to_py)?;
            Ok(Stream { model: self.inner.clone(), mem })
        })
    }
}

/// Sample-by-sample forward operator (the staircase), with a snapshot of its state.
#[pyclass(module = "preisach._preisach")]
pub struct Stream {
    model: Arc<PreisachModel>,
    mem: StepMemory,
}

#[pymethods]
impl Stream {
    fn step(&mut self, u: f64) -> PyResult<f64> {
        if !u.is_finite() {
            return Err(PyValueError::new_err(format!("u: must be finite, got {u}")));
        }
        Ok(self.model.step(&mut self.mem, u))
    }

    fn process<'py>(
        &mut self,
        py: Python<'py>,
        block: PyReadonlyArray1<'py, f64>,
    ) -> PyResult<Bound<'py, PyArray1<f64>>> {
        guard(|| {
            let u = slice("block", &block)?;
            preisach_core::error::check_finite("block", u).map_err(to_py)?;
            let mut y = vec![0.0; u.len()];
            let (model, mem) = (&self.model, &mut self.mem);
            py.detach(|| model.run(mem, u, &mut y));
            Ok(y.into_pyarray(py))
        })
    }

    fn get_state<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        self.model.step_memory_values(&self.mem).into_pyarray(py)
    }

    fn set_state(&mut self, state: PyReadonlyArray1<'_, f64>) -> PyResult<()> {
        self.mem = self.model.step_memory_from(slice("state", &state)?).map_err(to_py)?;
        Ok(())
    }
}

#[pymodule(gil_used = false)]
fn _preisach(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add_class::<Model>()?;
    m.add_class::<Stream>()?;
    identify::register(m)?;
    invert::register(m)?;
    sim::register(m)?;
    chain_invert::register(m)?;
    Ok(())
}
