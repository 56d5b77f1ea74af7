//! pyo3 glue for inversion (the paper §4.1): `invert` over a whole reference and the
//! streaming `InverseStream`. Validation of method/lookahead names lives in the core so
//! the messages are the same from Rust and Python.

use numpy::{IntoPyArray, PyArray1, PyReadonlyArray1};
use preisach_core::invert::{
    invert as core_invert, reachable, saturation as core_saturation, Inverter, InverterState, Method,
};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use crate::{guard, slice, to_py, Model};

/// Invert `model` over the reference `r` from negative saturation.
/// Returns `(u, saturated)`: the input and the number of out-of-range references.
#[pyfunction]
#[pyo3(signature = (model, r, method="closest", lookahead=None))]
fn invert<'py>(
    py: Python<'py>,
    model: &Model,
    r: PyReadonlyArray1<'py, f64>,
    method: &str,
    lookahead: Option<usize>,
) -> PyResult<(Bound<'py, PyArray1<f64>>, u64)> {
    guard(|| {
        let method: Method = method.parse().map_err(to_py)?;
        let r = slice("r", &r)?;
        let m = &model.inner;
        let (u, sat) = py.detach(|| core_invert(m, r, method, lookahead)).map_err(to_py)?;
        Ok((u.into_pyarray(py), sat))
    })
}

/// The references of `r` outside the model's reachable output range:
/// `(count, first index or None, (y_lo, y_hi))`.
#[pyfunction]
fn saturation<'py>(model: &Model, r: PyReadonlyArray1<'py, f64>) -> PyResult<(u64, Option<usize>, (f64, f64))> {
    guard(|| {
        let r = slice("r", &r)?;
        let (count, first) = core_saturation(&model.inner, r);
        Ok((count, first, reachable(&model.inner)))
    })
}

/// A streaming inverter: one reference sample in, one input out (see `preisach.Inverter`).
#[pyclass(module = "preisach._preisach")]
pub struct InverseStream {
    inner: Inverter,
}

type StateTuple<'py> =
    (Bound<'py, PyArray1<f64>>, u64, u64, f64, f64, Bound<'py, PyArray1<u64>>, Bound<'py, PyArray1<f64>>, f64);

#[pymethods]
impl InverseStream {
    #[new]
    #[pyo3(signature = (model, method="closest", lookahead=None))]
    fn new(model: &Model, method: &str, lookahead: Option<usize>) -> PyResult<Self> {
        guard(|| {
            let method: Method = method.parse().map_err(to_py)?;
            let inner = Inverter::new(model.inner.clone(), method, lookahead).map_err(to_py)?;
            Ok(InverseStream { inner })
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

    fn reset(&mut self) {
        self.inner.reset()
    }

    #[getter]
    fn saturated(&self) -> u64 {
        self.inner.saturated()
    }
    #[getter]
    fn method(&self) -> &'static str {
        self.inner.method().name()
    }
    #[getter]
    fn lookahead(&self) -> usize {
        self.inner.lookahead()
    }

    /// (memory, saturated, t, u_prev, last_cm, knot_t, knot_v, r_prev)
    fn get_state<'py>(&self, py: Python<'py>) -> StateTuple<'py> {
        let s = self.inner.state();
        let (kt, kv): (Vec<u64>, Vec<f64>) = s.knots.iter().copied().unzip();
        (
            s.memory.into_pyarray(py),
            s.saturated,
            s.t,
            s.u_prev,
            s.last_cm,
            kt.into_pyarray(py),
            kv.into_pyarray(py),
            s.r_prev,
        )
    }

    #[allow(clippy::too_many_arguments)]
    fn set_state(
        &mut self,
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
            let s = inverter_state(&memory, saturated, t, u_prev, last_cm, &knot_t, &knot_v, r_prev)?;
            self.inner.set_state(&s).map_err(to_py)
        })
    }
}

/// A hysteresis inverter's state from the plain numbers and arrays Python holds (the
/// streaming inverter's and the chain inverter's `set_state`).
#[allow(clippy::too_many_arguments)]
pub(crate) fn inverter_state(
    memory: &PyReadonlyArray1<'_, f64>,
    saturated: u64,
    t: u64,
    u_prev: f64,
    last_cm: f64,
    knot_t: &PyReadonlyArray1<'_, u64>,
    knot_v: &PyReadonlyArray1<'_, f64>,
    r_prev: f64,
) -> PyResult<InverterState> {
    let kt = knot_t.as_slice().map_err(|_| PyValueError::new_err("state: knot times must be contiguous"))?;
    let kv = slice("state", knot_v)?;
    if kt.len() != kv.len() {
        return Err(PyValueError::new_err("state: knot times and values differ in length"));
    }
    Ok(InverterState {
        memory: slice("state", memory)?.to_vec(),
        saturated,
        t,
        u_prev,
        last_cm,
        knots: kt.iter().copied().zip(kv.iter().copied()).collect(),
        r_prev,
    })
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(invert, m)?)?;
    m.add_function(wrap_pyfunction!(saturation, m)?)?;
    m.add_class::<InverseStream>()?;
    Ok(())
}
