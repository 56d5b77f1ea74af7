//! Hysteresis: a Preisach operator (`preisach_core::PreisachModel`).
//!
//! Two sources:
//! - `parametric`: the simulator's "true" hysteresis. A fine grid (default 500 levels,
//!   unlike any identification grid) filled from a density that is log-normal in the
//!   coercivity `h = (α − β)/2` and Gaussian in the interaction `m = (α + β)/2`, plus a
//!   reversible (anhysteretic) part `slope · (u − lo) + sat · tanh((u − centre)/width)`.
//!   Serialized by these parameters, never by its masses.
//! - `identified`: an explicit model (packed masses, range, offset), so a chain can be
//!   "identified model + effects".
//!
//! Units: input in the operator's input units (piezo volts in the `paper` preset),
//! output in its output units (µm in the preset). The interpolated output (continuous
//! in `u`, `docs/method/fast-paths.md`) is the default: a real stage has no steps.

use std::sync::Arc;

use super::{finite, non_negative, positive};
use crate::error::{PreisachError, Result};
use crate::grid::{cell_index, Grid};
use crate::model::{InterpMemory, PreisachModel, StepMemory};
use serde::{Deserialize, Serialize};

fn yes() -> bool {
    true
}
fn default_n_h() -> usize {
    500
}

/// The true hysteresis of a simulated stage (see the module doc).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ParametricHysteresis {
    /// Lower end of the operator's input range (β_m), input units.
    pub lo: f64,
    /// Upper end of the operator's input range (α_m), input units.
    pub hi: f64,
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
    #[serde(default)]
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
    #[serde(default)]
    pub reversible_width: Option<f64>,
    /// Output offset, output units (default 0).
    #[serde(default)]
    pub offset: f64,
    /// Interpolated (continuous) output; `false` = stepwise staircase output.
    #[serde(default = "yes")]
    pub interpolated: bool,
}

/// An explicit (e.g. identified) model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct IdentifiedHysteresis {
    pub lo: f64,
    pub hi: f64,
    pub n_h: usize,
    /// Packed masses of the upper triangle, row by row: cell (i, j), i <= j < n_h
    /// (`grid::cell_index` order), n_h (n_h + 1) / 2 values, all >= 0.
    pub weights: Vec<f64>,
    /// Offset η0, output units.
    #[serde(default)]
    pub offset: f64,
    /// Interpolated (continuous) output; `false` = stepwise staircase output.
    #[serde(default = "yes")]
    pub interpolated: bool,
}

/// Parameters of [`Hysteresis`] (the JSON form, tagged by `"source"`).
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

/// A Preisach operator with its memory; see the module doc.
#[derive(Debug, Clone)]
pub struct Hysteresis {
    /// For `identified`, `weights` is left empty here and rebuilt from the model.
    params: HysteresisParams,
    model: Arc<PreisachModel>,
    interpolated: bool,
    mem_i: InterpMemory,
    mem_s: StepMemory,
    rev: Option<Reversible>,
}

impl Hysteresis {
    pub fn new(params: HysteresisParams, _sample_rate_hz: f64) -> Result<Self> {
        match params {
            HysteresisParams::Parametric(p) => Self::parametric(p),
            HysteresisParams::Identified(mut p) => {
                let grid = Grid::new(p.lo, p.hi, p.n_h)?;
                let masses = std::mem::take(&mut p.weights);
                let model = PreisachModel::new(grid, masses, p.offset)?;
                let interpolated = p.interpolated;
                Ok(Self::build(HysteresisParams::Identified(p), Arc::new(model), interpolated, None))
            }
        }
    }

    /// A block around an existing model (shared, not copied).
    pub fn from_model(model: Arc<PreisachModel>, interpolated: bool) -> Self {
        let g = model.grid();
        let p = IdentifiedHysteresis {
            lo: g.lo(),
            hi: g.hi(),
            n_h: g.n_h(),
            weights: Vec::new(),
            offset: model.offset(),
            interpolated,
        };
        Self::build(HysteresisParams::Identified(p), model, interpolated, None)
    }

    fn build(params: HysteresisParams, model: Arc<PreisachModel>, interpolated: bool, rev: Option<Reversible>) -> Self {
        let mem_i = model.interp_memory();
        let mem_s = model.memory();
        Hysteresis { params, model, interpolated, mem_i, mem_s, rev }
    }

    fn parametric(p: ParametricHysteresis) -> Result<Self> {
        let grid = Grid::new(p.lo, p.hi, p.n_h)?;
        let stroke = positive("hysteretic_stroke", p.hysteretic_stroke)?;
        let h_med = positive("coercivity_median", p.coercivity_median)?;
        let h_sig = positive("coercivity_sigma", p.coercivity_sigma)?;
        let m_mean = finite("interaction_mean", p.interaction_mean.unwrap_or(0.5 * (p.lo + p.hi)))?;
        let m_sig = positive("interaction_sigma", p.interaction_sigma)?;
        finite("reversible_slope", p.reversible_slope)?;
        non_negative("reversible_saturation", p.reversible_saturation)?;
        let width = positive("reversible_width", p.reversible_width.unwrap_or(0.5 * (p.hi - p.lo)))?;
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
                "the density has no mass on the grid: check coercivity and interaction against lo/hi",
            ));
        }
        let scale = 0.5 * stroke / total;
        masses.iter_mut().for_each(|w| *w *= scale);
        // Offset Σw: the hysteretic part is 0 at negative saturation, `stroke` at positive.
        let model = PreisachModel::new(grid, masses, 0.5 * stroke)?;
        let rev = Reversible {
            lo: p.lo,
            slope: p.reversible_slope,
            sat: p.reversible_saturation,
            centre: m_mean,
            inv_width: 1.0 / width,
            offset: p.offset,
        };
        let interpolated = p.interpolated;
        Ok(Self::build(HysteresisParams::Parametric(p), Arc::new(model), interpolated, Some(rev)))
    }

    /// The parameters (for `identified`, with the masses filled in from the model).
    pub fn params(&self) -> HysteresisParams {
        match &self.params {
            HysteresisParams::Parametric(p) => HysteresisParams::Parametric(p.clone()),
            HysteresisParams::Identified(p) => {
                let mut p = p.clone();
                p.weights = self.model.masses().to_vec();
                HysteresisParams::Identified(p)
            }
        }
    }

    /// The Preisach operator inside (for the parametric source, the fine true grid).
    pub fn model(&self) -> &Arc<PreisachModel> {
        &self.model
    }

    #[inline]
    pub fn step(&mut self, u: f64) -> f64 {
        let y = if self.interpolated {
            self.model.step_interpolated(&mut self.mem_i, u)
        } else {
            self.model.step(&mut self.mem_s, u)
        };
        match &self.rev {
            Some(r) => y + r.offset + r.slope * (u - r.lo) + r.sat * ((u - r.centre) * r.inv_width).tanh(),
            None => y,
        }
    }

    pub fn reset(&mut self) {
        self.mem_i.reset();
        self.mem_s.reset();
    }
}
