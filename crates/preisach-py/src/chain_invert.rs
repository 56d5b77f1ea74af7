//! pyo3 glue for the chain inverse (`preisach_core::chain_invert`): the streaming
//! `ChainInverseStream` and its offline run.

use numpy::{IntoPyArray, PyArray1, PyReadonlyArray1};
use preisach_core::chain_invert::{invert_chain, ChainInverter, ChainInverterState, Plan};
use preisach_core::invert::Method;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::invert::inverter_state;
use crate::sim::Chain;
use crate::{guard, slice, to_py};

/// A streaming chain inverse (see `preisach.ChainInverter`).
#[pyclass(module = "preisach._preisach")]
pub struct ChainInverseStream {
    pub(crate) inner: ChainInverter,
}

#[pymethods]
impl ChainInverseStream {
    #[new]
    #[pyo3(signature = (chain, sample_rate_hz, method="continuous", lookahead=None, bandwidth_hz=None))]
    fn new(
        chain: &Chain,
        sample_rate_hz: f64,
        method: &str,
        lookahead: Option<usize>,
        bandwidth_hz: Option<f64>,
    ) -> PyResult<Self> {
        guard(|| {
            let method: Method = method.parse().map_err(to_py)?;
            let plan = Plan::new(chain.desc(), sample_rate_hz, bandwidth_hz).map_err(to_py)?;
            let inner = ChainInverter::new(&plan, method, lookahead).map_err(to_py)?;
            Ok(ChainInverseStream { inner })
        })
    }

    fn step(&mut self, r: f64) -> PyResult<f64> {
        if !r.is_finite() {
            return Err(PyValueError::new_err(format!("r: must be finite, got {r}")));
        }
        guard(|| Ok(self.inner.step(r)))
    }

    fn process<'py>(
        &mut self,
        py: Python<'py>,
        block: PyReadonlyArray1<'py, f64>,
    ) -> PyResult<Bound<'py, PyArray1<f64>>> {
        guard(|| {
            let r = slice("block", &block)?;
            let mut u = vec![0.0; r.len()];
            let inner = &mut self.inner;
            py.detach(|| inner.process(r, &mut u)).map_err(to_py)?;
            Ok(u.into_pyarray(py))
        })
    }

    /// The whole reference offline: `(u, saturated)` (the inverter is reset first).
    fn invert<'py>(
        &mut self,
        py: Python<'py>,
        r: PyReadonlyArray1<'py, f64>,
    ) -> PyResult<(Bound<'py, PyArray1<f64>>, u64)> {
        guard(|| {
            let r = slice("r", &r)?;
            let inner = &mut self.inner;
            let (u, sat) = py.detach(|| invert_chain(inner, r)).map_err(to_py)?;
            Ok((u.into_pyarray(py), sat))
        })
    }

    fn reset(&mut self) {
        self.inner.reset()
    }

    #[getter]
    fn latency(&self) -> usize {
        self.inner.latency()
    }
    #[getter]
    fn preview_s(&self) -> f64 {
        self.inner.preview_s()
    }
    #[getter]
    fn bandwidth_hz(&self) -> f64 {
        self.inner.bandwidth_hz()
    }
    #[getter]
    fn method(&self) -> &'static str {
        self.inner.method().name()
    }
    #[getter]
    fn saturated(&self) -> u64 {
        self.inner.saturated()
    }

    /// The state as a dict of plain numbers and arrays.
    fn get_state<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let s = self.inner.state();
        let d = PyDict::new(py);
        d.set_item("n", s.n)?;
        d.set_item("post", s.post.into_pyarray(py))?;
        d.set_item("shift", s.shift.into_pyarray(py))?;
        d.set_item("pre", s.pre.into_pyarray(py))?;
        let h = s.hysteresis;
        let (kt, kv): (Vec<u64>, Vec<f64>) = h.knots.iter().copied().unzip();
        d.set_item("memory", h.memory.into_pyarray(py))?;
        d.set_item("saturated", h.saturated)?;
        d.set_item("t", h.t)?;
        d.set_item("u_prev", h.u_prev)?;
        d.set_item("last_cm", h.last_cm)?;
        d.set_item("knot_t", kt.into_pyarray(py))?;
        d.set_item("knot_v", kv.into_pyarray(py))?;
        d.set_item("r_prev", h.r_prev)?;
        Ok(d)
    }

    #[allow(clippy::too_many_arguments)]
    fn set_state(
        &mut self,
        n: u64,
        post: PyReadonlyArray1<'_, f64>,
        shift: PyReadonlyArray1<'_, f64>,
        pre: PyReadonlyArray1<'_, f64>,
        memory: PyReadonlyArray1<'_, f64>,
        saturated: u64,
        t: u64,
        u_prev: f64,
        last_cm: f64,
        knot_t: PyReadonlyArray1<'_, u64>,
        knot_v: PyReadonlyArray1<'_, f64>,
        r_prev: f64,
    ) -> PyResult<()> {
        guard(|| {
            let hysteresis = inverter_state(&memory, saturated, t, u_prev, last_cm, &knot_t, &knot_v, r_prev)?;
            let s = ChainInverterState {
                n,
                post: slice("state", &post)?.to_vec(),
                shift: slice("state", &shift)?.to_vec(),
                hysteresis,
                pre: slice("state", &pre)?.to_vec(),
            };
            self.inner.set_state(&s).map_err(to_py)
        })
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<ChainInverseStream>()?;
    Ok(())
}
