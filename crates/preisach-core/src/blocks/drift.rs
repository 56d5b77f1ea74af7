//! Thermal drift: slow gain and offset change with absolute time,
//! `y = (1 + gain_per_s · t) · x + offset + offset_per_s · t`, `t` in seconds since the
//! chain's time origin (sample n is at `t = t0 + n / f_s`). Absolute time runs on
//! across records: `Chain::reset_state` keeps it, `Chain::reset` returns it to 0.

use super::finite;
use crate::error::Result;
use serde::{Deserialize, Serialize};

/// Parameters of [`Drift`] (the JSON form). All default to 0.
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

/// See the module doc.
#[derive(Debug, Clone)]
pub struct Drift {
    params: DriftParams,
    dt: f64,
    t0: f64,
    n: u64,
}

impl Drift {
    pub fn new(params: DriftParams, sample_rate_hz: f64) -> Result<Self> {
        finite("gain_per_s", params.gain_per_s)?;
        finite("offset", params.offset)?;
        finite("offset_per_s", params.offset_per_s)?;
        Ok(Drift { params, dt: 1.0 / sample_rate_hz, t0: 0.0, n: 0 })
    }

    pub fn params(&self) -> &DriftParams {
        &self.params
    }

    /// Time of the next sample, seconds.
    pub fn time_s(&self) -> f64 {
        self.t0 + self.n as f64 * self.dt
    }

    /// Set the time of the next sample.
    pub fn set_time(&mut self, t: f64) {
        self.t0 = t;
        self.n = 0;
    }

    #[inline]
    pub fn step(&mut self, x: f64) -> f64 {
        // t from a sample count, not an accumulated sum: no drift of the clock itself.
        let t = self.t0 + self.n as f64 * self.dt;
        self.n += 1;
        let p = &self.params;
        (1.0 + p.gain_per_s * t) * x + p.offset + p.offset_per_s * t
    }
}
