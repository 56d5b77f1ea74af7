//! Hysteresis: a Preisach operator (`preisach_core::PreisachModel`).
//!
//! Two sources:
//! - `identified`: an explicit model (masses as a square `n_h × n_h` matrix, β-cell
//!   rows and α-cell columns, zeros below the diagonal; range; offset), so a chain can be
//!   "identified model + effects", or an identified model alone.
//! - `parametric`: the simulator's "true" hysteresis. A fine grid (default 500 levels,
//!   unlike any identification grid) filled from a density that is log-normal in the
//!   coercivity `h = (α − β)/2` and Gaussian in the interaction `m = (α + β)/2`, plus a
//!   reversible (anhysteretic) part `slope · (u − lo) + sat · tanh((u − centre)/width)`.
//!   Serialized by these parameters, never by its masses.
//!
//! `output`: `interpolated` (continuous in `u`, `docs/method/fast-paths.md`) or `stepwise` (the staircase).
//! The memory starts with every relay at −1, or after the input went through
//! `initial_extrema` (alternating extrema of an unrecorded history, input units); at rest
//! with an input, it then moved to that input.
//! Units: input in the operator's input units (piezo volts in the `paper` preset),
//! output in its output units (µm in the preset). A real stage has no steps: the
//! interpolated output is the default.

use std::sync::Arc;

use super::{finite, finite_all, non_negative, positive};
use crate::error::{PreisachError, Result};
use crate::grid::{cell_index, Grid};
use crate::model::{InterpMemory, PreisachModel, StepMemory};
use serde::{Deserialize, Serialize};

/// Which output of the model a block gives.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Output {
    Interpolated,
    Stepwise,
}

fn interpolated() -> Output {
    Output::Interpolated
}
fn default_n_h() -> usize {
    500
}

/// The true hysteresis of a simulated stage (see the module doc).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ParametricHysteresis {
    /// The operator's input range `[β_m, α_m]`, input units.
    pub u_range: [f64; 2],
    /// Levels of the fine grid (default 500; the Everett table is (n_h+1)² doubles).
    #[serde(default = "default_n_h")]
    pub n_h: usize,
    /// Output span of the hysteretic part from negative to positive saturation
    /// (= 2 Σ masses), output units.
    pub hysteretic_stroke: f64,
    /// Median coercivity `h`, input units (> 0).
    pub coercivity_median: f64,
    /// Log-normal shape of the coercivity (σ of ln h, > 0).
    pub coercivity_sigma: f64,
    /// Mean interaction (bias) `m`, input units; default the range centre.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub interaction_mean: Option<f64>,
    /// Standard deviation of the interaction, input units (> 0).
    pub interaction_sigma: f64,
    /// Linear reversible part, output units per input unit (default 0).
    #[serde(default)]
    pub reversible_slope: f64,
    /// Amplitude of the saturating reversible term, output units (default 0).
    #[serde(default)]
    pub reversible_saturation: f64,
    /// Width of the saturating term, input units (default the half range).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reversible_width: Option<f64>,
    /// Output offset, output units (default 0).
    #[serde(default)]
    pub offset: f64,
    /// Default `interpolated`.
    #[serde(default = "interpolated")]
    pub output: Output,
    /// Alternating extrema of the history before the record, input units.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub initial_extrema: Option<Vec<f64>>,
}

/// An explicit (e.g. identified) model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct IdentifiedHysteresis {
    /// The model range `[β_m, α_m]`.
    pub u_range: [f64; 2],
    pub n_h: usize,
    /// Masses `w[i][j] >= 0`: row i = β-cell, column j = α-cell, zero below the diagonal.
    pub weights: Vec<Vec<f64>>,
    /// Offset η0, output units.
    #[serde(default)]
    pub offset: f64,
    pub output: Output,
    /// Alternating extrema of the history before the record, input units.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub initial_extrema: Option<Vec<f64>>,
}

impl IdentifiedHysteresis {
    /// The block of a model (its dense masses copied).
    pub fn of_model(model: &PreisachModel, output: Output) -> Self {
        let n = model.n_h();
        let dense = model.dense_weights();
        IdentifiedHysteresis {
            u_range: [model.grid().lo(), model.grid().hi()],
            n_h: n,
            weights: dense.chunks(n).map(<[f64]>::to_vec).collect(),
            offset: model.offset(),
            output,
            initial_extrema: None,
        }
    }

    fn model(&self) -> Result<PreisachModel> {
        let n = self.n_h;
        let grid = Grid::new(self.u_range[0], self.u_range[1], n)?;
        if self.weights.len() != n || self.weights.iter().any(|r| r.len() != n) {
            return Err(PreisachError::invalid(
                "weights",
                format!("expected a square matrix of {n} rows of {n} values (n_h = {n})"),
            ));
        }
        let mut masses = Vec::with_capacity(grid.n_q());
        for (i, row) in self.weights.iter().enumerate() {
            for (j, &w) in row.iter().enumerate() {
                let name = || format!("weights[{i}][{j}]");
                finite(&name(), w)?;
                if j < i && w != 0.0 {
                    return Err(PreisachError::invalid(
                        name(),
                        format!("must be 0 below the diagonal (rows are β cells, columns α cells), got {w}"),
                    ));
                }
                if j >= i {
                    masses.push(non_negative(&name(), w)?);
                }
            }
        }
        PreisachModel::new(grid, masses, finite("offset", self.offset)?)
    }
}

/// Parameters of a hysteresis block (the JSON form, tagged by `"source"`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "source", rename_all = "lowercase")]
pub enum HysteresisParams {
    Parametric(ParametricHysteresis),
    Identified(IdentifiedHysteresis),
}

#[derive(Debug, Clone, Copy)]
struct Reversible {
    lo: f64,
    slope: f64,
    sat: f64,
    centre: f64,
    inv_width: f64,
    offset: f64,
}

/// What every run of a hysteresis block shares (built once per chain): the model, the
/// output kind, the reversible part and the initial extrema.
#[derive(Debug, Clone)]
pub struct HysteresisCore {
    model: Arc<PreisachModel>,
    output: Output,
    rev: Option<Reversible>,
    extrema: Vec<f64>,
}

impl HysteresisParams {
    /// Validate and build the model (for `parametric`, the fine grid).
    pub fn core(&self) -> Result<HysteresisCore> {
        let (model, output, rev, extrema) = match self {
            HysteresisParams::Identified(p) => (p.model()?, p.output, None, &p.initial_extrema),
            HysteresisParams::Parametric(p) => {
                let (m, rev) = parametric(p)?;
                (m, p.output, Some(rev), &p.initial_extrema)
            }
        };
        let extrema = extrema.clone().unwrap_or_default();
        finite_all("initial_extrema", &extrema)?;
        Ok(HysteresisCore { model: Arc::new(model), output, rev, extrema })
    }

    pub fn output(&self) -> Output {
        match self {
            HysteresisParams::Identified(p) => p.output,
            HysteresisParams::Parametric(p) => p.output,
        }
    }
}

impl HysteresisCore {
    /// The Preisach operator inside (for the parametric source, the fine true grid).
    pub fn model(&self) -> &Arc<PreisachModel> {
        &self.model
    }
    pub fn output(&self) -> Output {
        self.output
    }
}

fn parametric(p: &ParametricHysteresis) -> Result<(PreisachModel, Reversible)> {
    let [lo, hi] = p.u_range;
    let grid = Grid::new(lo, hi, p.n_h)?;
    let stroke = positive("hysteretic_stroke", p.hysteretic_stroke)?;
    let h_med = positive("coercivity_median", p.coercivity_median)?;
    let h_sig = positive("coercivity_sigma", p.coercivity_sigma)?;
    let m_mean = finite("interaction_mean", p.interaction_mean.unwrap_or(0.5 * (lo + hi)))?;
    let m_sig = positive("interaction_sigma", p.interaction_sigma)?;
    finite("reversible_slope", p.reversible_slope)?;
    non_negative("reversible_saturation", p.reversible_saturation)?;
    let width = positive("reversible_width", p.reversible_width.unwrap_or(0.5 * (hi - lo)))?;
    finite("offset", p.offset)?;

    // Density at each cell centre times its area (half a cell on the diagonal).
    // Constant factors cancel in the normalization to `stroke`.
    let n = grid.n_h();
    let d = grid.delta();
    let mut masses = vec![0.0; grid.n_q()];
    let ln_med = h_med.ln();
    for i in 0..n {
        let beta = grid.lo() + (i as f64 + 0.5) * d;
        for j in i..n {
            let alpha = grid.lo() + (j as f64 + 0.5) * d;
            // On the diagonal the centre has h = 0, where the log-normal vanishes;
            // the half cell's centroid lies at h = Δ/6.
            let (h, area) = if i == j { (d / 6.0, 0.5) } else { (0.5 * (alpha - beta), 1.0) };
            let m = 0.5 * (alpha + beta);
            let z = (h.ln() - ln_med) / h_sig;
            let lognormal = (-0.5 * z * z).exp() / h;
            let zm = (m - m_mean) / m_sig;
            masses[cell_index(n, i, j)] = area * lognormal * (-0.5 * zm * zm).exp();
        }
    }
    let total: f64 = masses.iter().sum();
    if !total.is_finite() || total <= 0.0 {
        return Err(PreisachError::invalid(
            "coercivity_median",
            "the density has no mass on the grid: check coercivity and interaction against u_range",
        ));
    }
    let scale = 0.5 * stroke / total;
    masses.iter_mut().for_each(|w| *w *= scale);
    // Offset Σw: the hysteretic part is 0 at negative saturation, `stroke` at positive.
    let model = PreisachModel::new(grid, masses, 0.5 * stroke)?;
    let rev = Reversible {
        lo,
        slope: p.reversible_slope,
        sat: p.reversible_saturation,
        centre: m_mean,
        inv_width: 1.0 / width,
        offset: p.offset,
    };
    Ok((model, rev))
}

/// A Preisach operator with its memory; see the module doc.
#[derive(Debug, Clone)]
pub struct Hysteresis {
    core: Arc<HysteresisCore>,
    mem_i: InterpMemory,
    mem_s: StepMemory,
}

impl Hysteresis {
    pub fn new(core: Arc<HysteresisCore>) -> Self {
        let mut h = Hysteresis { mem_i: core.model.interp_memory(), mem_s: core.model.memory(), core };
        h.reset();
        h
    }

    /// The block of a model (shared, not copied), memory at negative saturation.
    pub fn of_model(model: Arc<PreisachModel>, output: Output) -> Self {
        Hysteresis::new(Arc::new(HysteresisCore { model, output, rev: None, extrema: Vec::new() }))
    }

    pub fn core(&self) -> &HysteresisCore {
        &self.core
    }

    #[inline]
    pub fn step(&mut self, u: f64) -> f64 {
        let m = &self.core.model;
        let y = match self.core.output {
            Output::Interpolated => m.step_interpolated(&mut self.mem_i, u),
            Output::Stepwise => m.step(&mut self.mem_s, u),
        };
        match &self.core.rev {
            Some(r) => y + r.offset + r.slope * (u - r.lo) + r.sat * ((u - r.centre) * r.inv_width).tanh(),
            None => y,
        }
    }

    /// At rest with `u`: the initial history, then `u`; returns the output then.
    pub fn settle(&mut self, u: f64) -> f64 {
        self.reset();
        self.step(u)
    }

    /// Memory back to the initial history (no allocation).
    pub fn reset(&mut self) {
        self.mem_i.reset();
        self.mem_s.reset();
        let m = &self.core.model;
        for &v in &self.core.extrema {
            match self.core.output {
                Output::Interpolated => self.mem_i.apply(m.grid().position(v), &m.e_interp()),
                Output::Stepwise => self.mem_s.apply(m.grid().quantize(v), &m.e_step()),
            }
        }
    }
}
