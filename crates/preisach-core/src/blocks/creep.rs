//! Creep: a Kelvin–Voigt chain of first-order elements,
//! `y = x + Σ_k c_k z_k`, `τ_k z_k' = x − z_k`, so the DC gain is `1 + Σ c_k` and the
//! response to a step keeps growing over the time constants (0.01–100 s for piezo
//! creep). Equal gains `γ` on time constants one decade apart approximate the log law
//! `y = x (1 + γ log10(t / t0))` between the shortest and longest τ
//! ([`CreepParams::log_law`]).
//!
//! Discretized exactly for a zero-order-held input: `z ← a z + (1 − a) x`,
//! `a = exp(−T/τ)`; the output is taken after the update (end of the hold interval).
//!
//! A record starts at rest: on the first `step` after construction or `reset` every
//! element starts at its steady state for that input (`z_k = x`, fully crept), so a
//! constant input gives the constant output `dc_gain · x` from the first sample.

use super::{non_negative, positive};
use crate::error::{PreisachError, Result};
use serde::{Deserialize, Serialize};

/// Parameters of [`Creep`] (the JSON form).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CreepParams {
    /// Gains `c_k` of the elements (>= 0, dimensionless: fraction of the input).
    pub gains: Vec<f64>,
    /// Time constants `τ_k`, seconds (> 0).
    pub time_constants_s: Vec<f64>,
}

impl CreepParams {
    /// Log-law approximation: `gamma` per decade of time from `tau_min_s` to
    /// `tau_max_s` (one element per decade, rounded to at least one).
    pub fn log_law(gamma: f64, tau_min_s: f64, tau_max_s: f64) -> Self {
        let decades = (tau_max_s / tau_min_s).log10().round().max(0.0) as usize;
        let n = decades + 1;
        let ratio = (tau_max_s / tau_min_s).powf(1.0 / decades.max(1) as f64);
        // Whole decades as 10^k (clean numbers in the JSON), otherwise the even ratio.
        let ratio = if (ratio - 10.0).abs() < 1e-9 { 10.0 } else { ratio };
        let time_constants_s = (0..n).map(|k| tau_min_s * ratio.powi(k as i32)).collect();
        CreepParams { gains: vec![gamma; n], time_constants_s }
    }
}

/// Kelvin–Voigt creep chain; see the module doc.
#[derive(Debug, Clone)]
pub struct Creep {
    params: CreepParams,
    a: Vec<f64>,
    z: Vec<f64>,
    /// Whether the states are set (false until the first `step` after a reset).
    settled: bool,
}

impl Creep {
    pub fn new(params: CreepParams, sample_rate_hz: f64) -> Result<Self> {
        if params.gains.len() != params.time_constants_s.len() {
            return Err(PreisachError::invalid(
                "gains",
                format!(
                    "expected one gain per time constant ({}), got {}",
                    params.time_constants_s.len(),
                    params.gains.len()
                ),
            ));
        }
        for (k, &c) in params.gains.iter().enumerate() {
            non_negative(&format!("gains[{k}]"), c)?;
        }
        let mut a = Vec::with_capacity(params.gains.len());
        for (k, &tau) in params.time_constants_s.iter().enumerate() {
            positive(&format!("time_constants_s[{k}]"), tau)?;
            a.push((-1.0 / (tau * sample_rate_hz)).exp());
        }
        let z = vec![0.0; a.len()];
        Ok(Creep { params, a, z, settled: false })
    }

    pub fn params(&self) -> &CreepParams {
        &self.params
    }

    /// Static gain `1 + Σ c_k`.
    pub fn dc_gain(&self) -> f64 {
        1.0 + self.params.gains.iter().sum::<f64>()
    }

    #[inline]
    pub fn step(&mut self, x: f64) -> f64 {
        if !self.settled {
            self.z.iter_mut().for_each(|z| *z = x);
            self.settled = true;
        }
        let mut y = x;
        for ((z, &a), &c) in self.z.iter_mut().zip(&self.a).zip(&self.params.gains) {
            *z = a * *z + (1.0 - a) * x;
            y += c * *z;
        }
        y
    }

    /// Back to rest: the next `step` starts in equilibrium with its input.
    pub fn reset(&mut self) {
        self.z.iter_mut().for_each(|z| *z = 0.0);
        self.settled = false;
    }
}
