//! Voltage amplifier: gain, output saturation, slew-rate limit.
//! Input: DAC volts; output: piezo volts (e.g. PDL200, 20 V/V, the paper §3.1).

use super::{finite, positive};
use crate::error::{PreisachError, Result};
use serde::{Deserialize, Serialize};

fn default_gain() -> f64 {
    20.0
}

/// Parameters of an [`Amplifier`] (the JSON form).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AmplifierParams {
    /// Voltage gain, V/V (default 20).
    #[serde(default = "default_gain")]
    pub gain: f64,
    /// Output limits `[lo, hi]` in output volts; `None` = no saturation.
    #[serde(default)]
    pub saturation: Option<[f64; 2]>,
    /// Maximum output rate of change, V/s; `None` = unlimited.
    #[serde(default)]
    pub slew_v_per_s: Option<f64>,
}

impl Default for AmplifierParams {
    fn default() -> Self {
        AmplifierParams { gain: default_gain(), saturation: None, slew_v_per_s: None }
    }
}

/// Gain, then saturation, then slew limit. Starts at rest with its first input: the
/// slew limiter starts at the first (saturated) value, so the first sample is not
/// slew-limited.
#[derive(Debug, Clone)]
pub struct Amplifier {
    gain: f64,
    lo: f64,
    hi: f64,
    max_step: f64,
    last: f64,
    /// Whether `last` is set (false until the first `step` after a reset).
    settled: bool,
}

impl Amplifier {
    pub fn new(params: &AmplifierParams, sample_rate_hz: f64) -> Result<Self> {
        finite("gain", params.gain)?;
        let (lo, hi) = match params.saturation {
            Some([lo, hi]) => {
                finite("saturation", lo)?;
                finite("saturation", hi)?;
                if lo >= hi {
                    return Err(PreisachError::invalid("saturation", format!("lo must be below hi, got [{lo}, {hi}]")));
                }
                (lo, hi)
            }
            None => (f64::NEG_INFINITY, f64::INFINITY),
        };
        let max_step = match params.slew_v_per_s {
            Some(s) => positive("slew_v_per_s", s)? / sample_rate_hz,
            None => f64::INFINITY,
        };
        let last = 0.0f64.clamp(lo, hi);
        Ok(Amplifier { gain: params.gain, lo, hi, max_step, last, settled: false })
    }

    #[inline]
    pub fn step(&mut self, x: f64) -> f64 {
        if !self.settled {
            return self.settle(x);
        }
        let v = (self.gain * x).clamp(self.lo, self.hi);
        let v = self.last + (v - self.last).clamp(-self.max_step, self.max_step);
        self.last = v;
        v
    }

    /// At rest with `x`: the slew limiter at its (saturated) value.
    pub fn settle(&mut self, x: f64) -> f64 {
        self.last = (self.gain * x).clamp(self.lo, self.hi);
        self.settled = true;
        self.last
    }

    /// Back to rest: the next `step` starts at its own (saturated) value.
    pub fn reset(&mut self) {
        self.last = 0.0f64.clamp(self.lo, self.hi);
        self.settled = false;
    }
}
