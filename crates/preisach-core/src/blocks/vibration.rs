//! Vibration: lightly damped second-order modes in series, each with unit DC gain,
//! `G(s) = ω² / (s² + 2ζω s + ω²)`, discretized exactly for a zero-order-held input
//! (`A_d = exp(A T)`, `B_d = A⁻¹ (A_d − I) B`; nalgebra 2×2 maths). The output of a
//! sample is the mode's position at the end of its hold interval.
//!
//! A record starts at rest: on the first `step` after construction or `reset` every
//! mode starts in equilibrium with that input (the discrete fixed point
//! `x = (I − A_d)⁻¹ B_d u`: position = DC gain · u, velocity 0), so a constant input
//! gives a constant output from the first sample and no ringing.

use super::{below_nyquist, positive};
use crate::error::Result;
use nalgebra::{Matrix2, Vector2};
use serde::{Deserialize, Serialize};

/// One mode: natural frequency and damping ratio.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Mode {
    /// Natural (undamped) frequency, Hz (> 0, below Nyquist).
    pub freq_hz: f64,
    /// Damping ratio ζ (> 0).
    pub damping: f64,
}

/// Parameters of [`Vibration`] (the JSON form).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VibrationParams {
    /// Modes applied in series (the DC gain stays 1).
    pub modes: Vec<Mode>,
}

#[derive(Debug, Clone)]
struct DiscreteMode {
    ad: Matrix2<f64>,
    bd: Vector2<f64>,
    /// Steady state per unit input, `(I − A_d)⁻¹ B_d` (≈ [1, 0]).
    xss: Vector2<f64>,
    x: Vector2<f64>,
}

/// Modes in series; see the module doc (starts at rest with its first input).
#[derive(Debug, Clone)]
pub struct Vibration {
    params: VibrationParams,
    modes: Vec<DiscreteMode>,
    /// Whether the states are set (false until the first `step` after a reset).
    settled: bool,
}

impl Vibration {
    pub fn new(params: VibrationParams, sample_rate_hz: f64) -> Result<Self> {
        let t = 1.0 / sample_rate_hz;
        let mut modes = Vec::with_capacity(params.modes.len());
        for (k, m) in params.modes.iter().enumerate() {
            let f = below_nyquist(&format!("modes[{k}].freq_hz"), m.freq_hz, sample_rate_hz)?;
            let z = positive(&format!("modes[{k}].damping"), m.damping)?;
            let w = std::f64::consts::TAU * f;
            let a = Matrix2::new(0.0, 1.0, -w * w, -2.0 * z * w);
            let b = Vector2::new(0.0, w * w);
            let ad = (a * t).exp();
            // A is invertible for ω > 0 (det = ω²).
            let a_inv = Matrix2::new(-2.0 * z * w, -1.0, w * w, 0.0) / (w * w);
            let bd = a_inv * (ad - Matrix2::identity()) * b;
            // I − A_d is invertible: the eigenvalues of A_d lie inside the unit circle.
            let xss = (Matrix2::identity() - ad).try_inverse().unwrap_or_else(Matrix2::zeros) * bd;
            modes.push(DiscreteMode { ad, bd, xss, x: Vector2::zeros() });
        }
        Ok(Vibration { params, modes, settled: false })
    }

    pub fn params(&self) -> &VibrationParams {
        &self.params
    }

    #[inline]
    pub fn step(&mut self, x: f64) -> f64 {
        if !self.settled {
            self.settle(x);
        }
        let mut u = x;
        for m in &mut self.modes {
            m.x = m.ad * m.x + m.bd * u;
            u = m.x[0];
        }
        u
    }

    /// Every mode at its steady state for a constant input `x`.
    #[cold]
    fn settle(&mut self, x: f64) {
        let mut u = x;
        for m in &mut self.modes {
            m.x = m.xss * u;
            u = m.x[0];
        }
        self.settled = true;
    }

    /// Back to rest: the next `step` starts in equilibrium with its input.
    pub fn reset(&mut self) {
        self.modes.iter_mut().for_each(|m| m.x = Vector2::zeros());
        self.settled = false;
    }
}
