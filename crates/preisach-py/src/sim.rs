//! pyo3 glue for the plant simulator (`preisach_core::blocks`) and the timed sample
//! loop (`preisach_core::sim`). Thin: JSON and arrays in, arrays out.

use numpy::{IntoPyArray, PyArray1, PyReadonlyArray1};
use preisach_core::blocks::{self, Chain as CoreChain};
use preisach_core::invert::{Inverter, Method};
use preisach_core::sim::{run_loop_preview, Compensator, Identity};
use preisach_core::PreisachError;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::{guard, slice, to_py, Model};

/// A chain of plant blocks with its state (see `preisach.sim.Stage`).
#[pyclass(module = "preisach._preisach")]
pub struct Chain {
    inner: CoreChain,
}

#[pymethods]
impl Chain {
    /// Parse a chain from its JSON text.
    #[staticmethod]
    fn from_json(text: &str) -> PyResult<Self> {
        guard(|| Ok(Chain { inner: CoreChain::from_json(text).map_err(to_py)? }))
    }

    /// A named preset with overrides as a JSON object text.
    #[staticmethod]
    fn preset(name: &str, overrides_json: &str) -> PyResult<Self> {
        guard(|| Ok(Chain { inner: blocks::preset(name, overrides_json).map_err(to_py)? }))
    }

    fn to_json(&self) -> String {
        self.inner.to_json()
    }

    #[getter]
    fn sample_rate_hz(&self) -> f64 {
        self.inner.sample_rate_hz
    }

    #[getter]
    fn time_s(&self) -> f64 {
        self.inner.time_s()
    }

    #[setter]
    fn set_time_s(&mut self, t: f64) -> PyResult<()> {
        self.inner.set_time(t).map_err(to_py)
    }

    /// Block type names in signal order.
    fn kinds(&self) -> Vec<&'static str> {
        self.inner.blocks.iter().map(|b| b.kind()).collect()
    }

    fn step(&mut self, u: f64) -> PyResult<f64> {
        if !u.is_finite() {
            return Err(PyValueError::new_err(format!("u: must be finite, got {u}")));
        }
        guard(|| Ok(self.inner.step(u)))
    }

    fn run<'py>(&mut self, py: Python<'py>, u: PyReadonlyArray1<'py, f64>) -> PyResult<Bound<'py, PyArray1<f64>>> {
        guard(|| {
            let u = slice("u", &u)?;
            preisach_core::error::check_finite("u", u).map_err(to_py)?;
            let mut y = vec![0.0; u.len()];
            let chain = &mut self.inner;
            py.detach(|| chain.run(u, &mut y));
            Ok(y.into_pyarray(py))
        })
    }

    fn reset(&mut self) {
        self.inner.reset();
    }

    fn reset_state(&mut self) {
        self.inner.reset_state();
    }

    fn copy(&self) -> Chain {
        Chain { inner: self.inner.clone() }
    }
}

/// The compensator `run_loop` drives, and its preview (look-ahead) in samples.
/// This is the one place that maps a method name to a compensator.
fn compensator_for(
    model: Option<&Model>,
    method: &str,
    lookahead: Option<usize>,
) -> Result<(Box<dyn Compensator + Send>, usize), PreisachError> {
    if method == "identity" {
        if lookahead.is_some() {
            return Err(PreisachError::invalid("lookahead", "only meaningful for method 'interpolated'"));
        }
        return Ok((Box::new(Identity), 0));
    }
    let method: Method = method.parse().map_err(|_| {
        PreisachError::invalid(
            "method",
            format!("expected one of 'closest', 'interpolated', 'continuous', 'identity', got '{method}'"),
        )
    })?;
    let model =
        model.ok_or_else(|| PreisachError::invalid("model", format!("required for method '{}'", method.name())))?;
    let inv = Inverter::new(model.inner.clone(), method, lookahead)?;
    let preview = inv.lookahead();
    Ok((Box::new(inv), preview))
}

/// Run reference → compensator → chain one sample at a time, timed per sample.
/// Returns a dict with u, y, error (arrays) and timing fields.
#[pyfunction]
#[pyo3(signature = (model, chain, reference, method="continuous", lookahead=None))]
fn run_loop<'py>(
    py: Python<'py>,
    model: Option<PyRef<'py, Model>>,
    mut chain: PyRefMut<'py, Chain>,
    reference: PyReadonlyArray1<'py, f64>,
    method: &str,
    lookahead: Option<usize>,
) -> PyResult<Bound<'py, PyDict>> {
    guard(|| {
        let r = slice("reference", &reference)?;
        let (mut comp, preview) = compensator_for(model.as_deref(), method, lookahead).map_err(to_py)?;
        let plant = &mut chain.inner;
        let out = py.detach(|| run_loop_preview(&mut comp, plant, r, preview)).map_err(to_py)?;
        let d = PyDict::new(py);
        d.set_item("u", out.u.into_pyarray(py))?;
        d.set_item("y", out.y.into_pyarray(py))?;
        d.set_item("error", out.error.into_pyarray(py))?;
        let t = out.timing;
        d.set_item("mean_ns", t.mean_ns)?;
        d.set_item("p99_ns", t.p99_ns)?;
        d.set_item("max_ns", t.max_ns)?;
        d.set_item("misses", t.misses)?;
        d.set_item("budget_ns", t.budget_ns)?;
        d.set_item("samples", t.samples)?;
        d.set_item("preview", preview)?;
        Ok(d)
    })
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<Chain>()?;
    m.add_function(wrap_pyfunction!(run_loop, m)?)?;
    Ok(())
}
