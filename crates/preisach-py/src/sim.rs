//! pyo3 glue for chains (`preisach_core::blocks`) and the timed sample loop
//! (`preisach_core::sim`). Thin: JSON and arrays in, arrays out.

use numpy::{Complex64, IntoPyArray, PyArray1, PyReadonlyArray1};
use preisach_core::blocks::{self, Chain as CoreChain, IdentifiedHysteresis, Output, Runtime};
use preisach_core::invert::{Inverter, Method};
use preisach_core::sim::{run_loop_preview, Compensator, Identity};
use preisach_core::PreisachError;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::chain_invert::ChainInverseStream;
use crate::{guard, slice, to_py, Model};

fn parse_output(output: &str) -> Result<Output, PreisachError> {
    match output {
        "interpolated" => Ok(Output::Interpolated),
        "stepwise" => Ok(Output::Stepwise),
        other => Err(PreisachError::invalid("output", format!("expected 'stepwise' or 'interpolated', got '{other}'"))),
    }
}

fn json(name: &str, text: &str) -> Result<serde_json::Value, PreisachError> {
    serde_json::from_str(text).map_err(|e| PreisachError::invalid(name, format!("not JSON ({e})")))
}

/// A chain description and, once it runs per sample at its own rate, its state (see
/// `preisach.Chain`).
#[pyclass(module = "preisach._preisach")]
pub struct Chain {
    desc: CoreChain,
    /// The stage at its own rate (compiled on first use).
    stage: Option<Runtime>,
}

impl Chain {
    fn of(desc: CoreChain) -> Self {
        Chain { desc, stage: None }
    }

    fn stage(&mut self) -> Result<&mut Runtime, PreisachError> {
        if self.stage.is_none() {
            self.stage = Some(self.desc.stage()?);
        }
        Ok(self.stage.as_mut().expect("compiled above"))
    }

    pub(crate) fn desc(&self) -> &CoreChain {
        &self.desc
    }

    /// A record run (`predict` or `simulate`) without the GIL.
    fn record<'py>(
        &self,
        py: Python<'py>,
        t: PyReadonlyArray1<'py, f64>,
        u: PyReadonlyArray1<'py, f64>,
        initial_input: Option<f64>,
        run: RecordRun,
    ) -> PyResult<Bound<'py, PyArray1<f64>>> {
        guard(|| {
            let (t, u) = (slice("t", &t)?, slice("u", &u)?);
            let y = py.detach(|| run(&self.desc, t, u, initial_input)).map_err(to_py)?;
            Ok(y.into_pyarray(py))
        })
    }
}

/// `Chain::predict` or `Chain::simulate`.
type RecordRun = fn(&CoreChain, &[f64], &[f64], Option<f64>) -> Result<Vec<f64>, PreisachError>;

#[pymethods]
impl Chain {
    /// Any chain, model or stage file's JSON text (version 1 or 2).
    #[staticmethod]
    fn from_json(text: &str) -> PyResult<Self> {
        guard(|| Ok(Chain::of(CoreChain::from_json(text).map_err(to_py)?)))
    }

    /// A named preset with overrides as a JSON object text (compiled at once).
    #[staticmethod]
    fn preset(name: &str, overrides_json: &str) -> PyResult<Self> {
        guard(|| {
            let mut c = Chain::of(blocks::preset(name, overrides_json).map_err(to_py)?);
            c.stage().map_err(to_py)?;
            Ok(c)
        })
    }

    /// Blocks (a JSON list of dicts with version-2 or version-1 stage fields), with an
    /// optional own sample rate and initial input.
    #[staticmethod]
    #[pyo3(signature = (blocks_json, sample_rate_hz=None, initial_input=None))]
    fn from_blocks(blocks_json: &str, sample_rate_hz: Option<f64>, initial_input: Option<f64>) -> PyResult<Self> {
        guard(|| {
            let build = || -> Result<CoreChain, PreisachError> {
                let serde_json::Value::Array(list) = json("blocks", blocks_json)? else {
                    return Err(PreisachError::invalid("blocks", "expected a list of dicts"));
                };
                blocks::stage_blocks(list)?.with_sample_rate(sample_rate_hz)?.with_initial_input(initial_input)
            };
            Ok(Chain::of(build().map_err(to_py)?))
        })
    }

    /// A model (or none) followed by effects (JSON: a list of {name, params} or an object
    /// name -> params), the effects in their fixed order.
    #[staticmethod]
    #[pyo3(signature = (model, output, effects_json, report_json=None))]
    fn from_effects(
        model: Option<PyRef<'_, Model>>,
        output: &str,
        effects_json: &str,
        report_json: Option<&str>,
    ) -> PyResult<Self> {
        guard(|| {
            let build = || -> Result<CoreChain, PreisachError> {
                let mut list = Vec::new();
                if let Some(m) = &model {
                    let h = IdentifiedHysteresis::of_model(&m.inner, parse_output(output)?);
                    list.push(blocks::BlockSpec::Hysteresis(blocks::HysteresisParams::Identified(h)));
                }
                list.extend(blocks::effect_blocks(&json("effects", effects_json)?)?);
                let report = report_json.map(|r| json("report", r)).transpose()?;
                Ok(CoreChain::new(list)?.with_report(report))
            };
            Ok(Chain::of(build().map_err(to_py)?))
        })
    }

    /// The version-2 JSON text.
    fn to_json(&self) -> String {
        self.desc.to_json()
    }

    #[getter]
    fn sample_rate_hz(&self) -> Option<f64> {
        self.desc.sample_rate_hz()
    }

    #[setter]
    fn set_sample_rate_hz(&mut self, fs: Option<f64>) -> PyResult<()> {
        self.desc = self.desc.clone().with_sample_rate(fs).map_err(to_py)?;
        self.stage = None;
        Ok(())
    }

    #[getter]
    fn initial_input(&self) -> Option<f64> {
        self.desc.initial_input()
    }

    #[setter]
    fn set_initial_input(&mut self, x: Option<f64>) -> PyResult<()> {
        self.desc = self.desc.clone().with_initial_input(x).map_err(to_py)?;
        if let Some(s) = &mut self.stage {
            s.set_initial_input(x).map_err(to_py)?;
        }
        Ok(())
    }

    #[getter]
    fn time_s(&mut self) -> PyResult<f64> {
        Ok(self.stage().map_err(to_py)?.time_s())
    }

    #[setter]
    fn set_time_s(&mut self, t: f64) -> PyResult<()> {
        self.stage().and_then(|s| s.set_time(t)).map_err(to_py)
    }

    /// Block type names in signal order.
    fn kinds(&self) -> Vec<&'static str> {
        self.desc.blocks().iter().map(|b| b.kind()).collect()
    }

    /// The model of hysteresis block `k` and its output kind, if it is an identified one.
    fn identified_model(&self, k: usize) -> Option<(Model, &'static str)> {
        match self.desc.blocks().get(k) {
            Some(blocks::BlockSpec::Hysteresis(blocks::HysteresisParams::Identified(_))) => {
                let core = self.desc.hysteresis(k)?;
                let out = if core.output() == Output::Interpolated { "interpolated" } else { "stepwise" };
                Some((Model { inner: core.model().clone() }, out))
            }
            _ => None,
        }
    }

    /// Compile the stage at its own rate now (errors for that rate surface here).
    fn check_stage(&mut self) -> PyResult<()> {
        self.stage().map(|_| ()).map_err(to_py)
    }

    fn step(&mut self, u: f64) -> PyResult<f64> {
        if !u.is_finite() {
            return Err(PyValueError::new_err(format!("u: must be finite, got {u}")));
        }
        guard(|| Ok(self.stage().map_err(to_py)?.step(u)))
    }

    fn run<'py>(&mut self, py: Python<'py>, u: PyReadonlyArray1<'py, f64>) -> PyResult<Bound<'py, PyArray1<f64>>> {
        guard(|| {
            let u = slice("u", &u)?;
            preisach_core::error::check_finite("u", u).map_err(to_py)?;
            let stage = self.stage().map_err(to_py)?;
            let mut y = vec![0.0; u.len()];
            py.detach(|| stage.run(u, &mut y));
            Ok(y.into_pyarray(py))
        })
    }

    fn reset(&mut self) -> PyResult<()> {
        self.stage().map_err(to_py)?.reset();
        Ok(())
    }

    fn reset_state(&mut self) -> PyResult<()> {
        self.stage().map_err(to_py)?.reset_state();
        Ok(())
    }

    fn copy(&self) -> Chain {
        Chain { desc: self.desc.clone(), stage: self.stage.clone() }
    }

    /// Deterministic output on the record (t, u) (first-order hold, at the rate of t).
    #[pyo3(signature = (t, u, initial_input=None))]
    fn predict<'py>(
        &self,
        py: Python<'py>,
        t: PyReadonlyArray1<'py, f64>,
        u: PyReadonlyArray1<'py, f64>,
        initial_input: Option<f64>,
    ) -> PyResult<Bound<'py, PyArray1<f64>>> {
        self.record(py, t, u, initial_input, CoreChain::predict)
    }

    /// Simulated measurement on the record (t, u) (per sample, noise and quantization).
    #[pyo3(signature = (t, u, initial_input=None))]
    fn simulate<'py>(
        &self,
        py: Python<'py>,
        t: PyReadonlyArray1<'py, f64>,
        u: PyReadonlyArray1<'py, f64>,
        initial_input: Option<f64>,
    ) -> PyResult<Bound<'py, PyArray1<f64>>> {
        self.record(py, t, u, initial_input, CoreChain::simulate)
    }

    /// Frequency response of the chain's series linear blocks at `f_hz`.
    fn response<'py>(
        &self,
        py: Python<'py>,
        f_hz: PyReadonlyArray1<'py, f64>,
    ) -> PyResult<Bound<'py, PyArray1<Complex64>>> {
        guard(|| {
            let f = slice("f_hz", &f_hz)?;
            let h = self.desc.response(f).map_err(to_py)?;
            Ok(h.into_pyarray(py))
        })
    }
}

/// The sample period of a time column (strictly increasing and regular).
#[pyfunction]
fn sample_period(t: PyReadonlyArray1<'_, f64>) -> PyResult<f64> {
    guard(|| blocks::sample_period(slice("t", &t)?).map_err(to_py))
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
    chain: PyRefMut<'py, Chain>,
    reference: PyReadonlyArray1<'py, f64>,
    method: &str,
    lookahead: Option<usize>,
) -> PyResult<Bound<'py, PyDict>> {
    guard(|| {
        let (comp, preview) = compensator_for(model.as_deref(), method, lookahead).map_err(to_py)?;
        loop_dict(py, comp, preview, chain, &reference)
    })
}

/// [`run_loop`] with the chain inverse as the compensator (a copy of `inverse`, reset;
/// the reference is fed ahead by its latency).
#[pyfunction]
fn run_loop_chain<'py>(
    py: Python<'py>,
    inverse: PyRef<'py, ChainInverseStream>,
    chain: PyRefMut<'py, Chain>,
    reference: PyReadonlyArray1<'py, f64>,
) -> PyResult<Bound<'py, PyDict>> {
    guard(|| {
        let comp = inverse.inner.clone();
        let preview = comp.latency();
        loop_dict(py, Box::new(comp), preview, chain, &reference)
    })
}

fn loop_dict<'py>(
    py: Python<'py>,
    mut comp: Box<dyn Compensator + Send>,
    preview: usize,
    mut chain: PyRefMut<'py, Chain>,
    reference: &PyReadonlyArray1<'py, f64>,
) -> PyResult<Bound<'py, PyDict>> {
    let r = slice("reference", reference)?;
    let plant = chain.stage().map_err(|e| PyValueError::new_err(format!("stage: {e}")))?;
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
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<Chain>()?;
    m.add_function(wrap_pyfunction!(run_loop, m)?)?;
    m.add_function(wrap_pyfunction!(run_loop_chain, m)?)?;
    m.add_function(wrap_pyfunction!(sample_period, m)?)?;
    Ok(())
}
