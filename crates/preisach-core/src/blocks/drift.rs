//! Thermal drift: slow gain and offset change with absolute time,
//! `y = (1 + gain_per_s · t) · x + offset + offset_per_s · t`, `t` in seconds (a record's
//! own time column, or the chain's clock `t0 + n / f_s` per sample). Absolute time runs
//! on across records.

use super::finite;
use crate::error::Result;
use serde::{Deserialize, Serialize};

/// Parameters of a drift block (the JSON form). All default to 0.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DriftParams {
    /// Relative gain change per second, 1/s.
    pub gain_per_s: f64,
    /// Constant offset, output units.
    pub offset: f64,
    /// Offset change per second, output units/s.
    pub offset_per_s: f64,
}

impl DriftParams {
    pub fn check(&self) -> Result<()> {
        finite("gain_per_s", self.gain_per_s)?;
        finite("offset", self.offset)?;
        finite("offset_per_s", self.offset_per_s)?;
        Ok(())
    }

    /// The output for input `x` at time `t`.
    #[inline]
    pub fn apply(&self, x: f64, t: f64) -> f64 {
        (1.0 + self.gain_per_s * t) * x + self.offset + self.offset_per_s * t
    }
}
