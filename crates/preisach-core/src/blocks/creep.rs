//! Creep: a Kelvin–Voigt chain of first-order elements,
//! `y = x + Σ_k c_k LP_k[x]`, `LP_k = 1 / (1 + s τ_k)`, so the static gain is `1 + Σ c_k`
//! and the response to a step keeps growing over the time constants (0.01–100 s for
//! piezo creep). Equal gains `γ` on time constants one decade apart approximate the log
//! law `y = x (1 + γ log10(t / t0))` between the shortest and longest τ
//! ([`CreepParams::log_law`]).
//!
//! `normalized`: `y = x + Σ_k c_k (LP_k[x] − x)`, the same dynamics with static gain 1
//! (a fit whose masses carry the static gain).
//!
//! As partial fractions (one section): `direct = 1` (or `1 − Σ c_k`), a pole `−1/τ_k`
//! with residue `c_k / τ_k` per element; equal time constants merge.

use super::lti::{Lti, Section, C};
use super::{finite_all, non_negative, positive};
use crate::error::{PreisachError, Result};
use serde::{Deserialize, Serialize};

fn is_false(b: &bool) -> bool {
    !*b
}

/// Parameters of a creep block (the JSON form).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CreepParams {
    /// Time constants `τ_k`, seconds (> 0).
    pub taus_s: Vec<f64>,
    /// Gains `c_k` of the elements (>= 0, dimensionless: fraction of the input).
    pub amplitudes: Vec<f64>,
    /// Static gain 1 (see the module doc); default false.
    #[serde(default, skip_serializing_if = "is_false")]
    pub normalized: bool,
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
        let taus_s = (0..n).map(|k| tau_min_s * ratio.powi(k as i32)).collect();
        CreepParams { taus_s, amplitudes: vec![gamma; n], normalized: false }
    }

    /// The continuous description (validates the parameters).
    pub fn lti(&self) -> Result<Lti> {
        if self.amplitudes.len() != self.taus_s.len() {
            return Err(PreisachError::invalid(
                "amplitudes",
                format!(
                    "expected one amplitude per time constant ({}), got {}",
                    self.taus_s.len(),
                    self.amplitudes.len()
                ),
            ));
        }
        finite_all("amplitudes", &self.amplitudes)?;
        for (k, (&tau, &c)) in self.taus_s.iter().zip(&self.amplitudes).enumerate() {
            positive(&format!("taus_s[{k}]"), tau)?;
            non_negative(&format!("amplitudes[{k}]"), c)?;
        }
        let direct = if self.normalized { 1.0 - self.amplitudes.iter().sum::<f64>() } else { 1.0 };
        let terms =
            self.taus_s.iter().zip(&self.amplitudes).map(|(&tau, &c)| (C::new(-1.0 / tau, 0.0), C::new(c / tau, 0.0)));
        Ok(Lti::series(vec![Section::new(direct, terms)?]))
    }
}
