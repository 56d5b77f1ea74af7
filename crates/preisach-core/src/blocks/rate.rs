//! Rate branch: `gain_s · s / (1 + s τ)` applied to the input of the nearest preceding
//! hysteresis block and added to the signal (the input's velocity, low-passed: a loop
//! that widens with the input rate).
//!
//! As partial fractions: `direct = gain_s / τ`, one pole `−1/τ` with residue
//! `−gain_s / τ²`.

use super::lti::{Lti, Section, C};
use super::{finite, positive};
use crate::error::Result;
use serde::{Deserialize, Serialize};

/// Parameters of a rate block (the JSON form).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RateParams {
    /// Gain on the input's velocity, seconds (output units per input unit per second).
    pub gain_s: f64,
    /// Time constant of the low-pass on the velocity, seconds (> 0).
    pub tau_s: f64,
}

impl RateParams {
    /// The continuous description (validates the parameters).
    pub fn lti(&self) -> Result<Lti> {
        let g = finite("gain_s", self.gain_s)?;
        let tau = positive("tau_s", self.tau_s)?;
        let term = (C::new(-1.0 / tau, 0.0), C::new(-g / (tau * tau), 0.0));
        Ok(Lti::series(vec![Section::new(g / tau, [term])?]))
    }
}
