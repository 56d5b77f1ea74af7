//! Vibration: lightly damped second-order modes in series, each with unit static gain,
//! `G(s) = ω² / (s² + 2ζω s + ω²)`.
//!
//! One section per mode: below critical damping (ζ < 1) the pole pair
//! `−ζω ± jω√(1 − ζ²)` with residue `ω² / (2jω√(1 − ζ²))`; at or above it (a mode that
//! does not ring) two first-order sections `−p_k / (s − p_k)`, `p_{1,2} = −ζω ± ω√(ζ² − 1)`.

use super::lti::{Lti, Section, C};
use super::positive;
use crate::error::Result;
use serde::{Deserialize, Serialize};

/// One mode: natural frequency and damping ratio.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Mode {
    /// Natural (undamped) frequency, Hz (> 0; below Nyquist for a per-sample run).
    pub frequency_hz: f64,
    /// Damping ratio ζ (> 0).
    pub damping: f64,
}

/// Parameters of a vibration block (the JSON form).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VibrationParams {
    /// Modes applied in series (the static gain stays 1).
    pub modes: Vec<Mode>,
}

impl VibrationParams {
    /// The continuous description (validates the parameters).
    pub fn lti(&self) -> Result<Lti> {
        let mut sections = Vec::with_capacity(self.modes.len());
        for (k, m) in self.modes.iter().enumerate() {
            let f = positive(&format!("modes[{k}].frequency_hz"), m.frequency_hz)?;
            let z = positive(&format!("modes[{k}].damping"), m.damping)?;
            let w = std::f64::consts::TAU * f;
            if z < 1.0 {
                let wd = w * (1.0 - z * z).sqrt();
                let p = C::new(-z * w, wd);
                sections.push(Section::new(0.0, [(p, C::new(0.0, -w * w / (2.0 * wd)))])?);
            } else {
                let s = w * (z * z - 1.0).sqrt();
                for p in [-z * w + s, -z * w - s] {
                    sections.push(Section::new(0.0, [(C::new(p, 0.0), C::new(-p, 0.0))])?);
                }
            }
        }
        Ok(Lti::series(sections))
    }
}
