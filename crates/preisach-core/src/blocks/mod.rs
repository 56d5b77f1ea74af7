//! Plant blocks (`docs/method/blocks.md`): one vocabulary for the simulated stage, an
//! identified model plus effects, and the diagnoser.
//!
//! Each block has parameters (a serde struct, the JSON form), per-sample state,
//! `step(x) -> y`, `reset()`, and is built by validating its parameters against the
//! chain's sample rate. [`Chain`] composes them and (de)serializes as versioned JSON.
//!
//! Signal units along the `paper` preset (see [`presets`]): DAC volts → amplifier
//! volts (piezo) → hysteresis µm → creep/vibration µm → sensor volts (1/5 V/µm).
//! Blocks themselves are unit-agnostic except where a doc comment says otherwise.
//!
//! A record starts at rest: blocks start in equilibrium with the first sample. On
//! the first `step` after construction, `reset` or `reset_state`, every stateful
//! linear block sets its state to the steady state for that input (low-pass and
//! vibration at DC gain, creep fully crept, the delay line filled with it, the
//! amplifier's slew limiter at its first value), so a constant input gives a constant
//! output from the first sample. The hysteresis memory starts as before (all relays
//! down, then the first input); drift and noise have nothing to settle.
//!
//! No per-sample path allocates: buffers are sized at construction (a flag is
//! checked per sample for the settling).

pub mod amplifier;
pub mod chain;
pub mod creep;
pub mod drift;
pub mod hysteresis;
pub mod presets;
pub mod rng;
pub mod sensor;
pub mod vibration;

pub use amplifier::{Amplifier, AmplifierParams};
pub use chain::{Block, BlockSpec, Chain, ChainSpec, CHAIN_VERSION};
pub use creep::{Creep, CreepParams};
pub use drift::{Drift, DriftParams};
pub use hysteresis::{Hysteresis, HysteresisParams, IdentifiedHysteresis, ParametricHysteresis};
pub use presets::{paper, preset, PaperOptions};
pub use rng::Rng;
pub use sensor::{
    Delay, DelayParams, Lowpass, LowpassParams, Noise, NoiseParams, Quantizer, QuantizerParams, Sensor, SensorParams,
};
pub use vibration::{Mode, Vibration, VibrationParams};

use crate::error::{PreisachError, Result};

/// `x` must be finite.
pub(crate) fn finite(name: &str, x: f64) -> Result<f64> {
    if !x.is_finite() {
        return Err(PreisachError::invalid(name, format!("must be finite, got {x}")));
    }
    Ok(x)
}

/// `x` must be finite and > 0.
pub(crate) fn positive(name: &str, x: f64) -> Result<f64> {
    finite(name, x)?;
    if x <= 0.0 {
        return Err(PreisachError::invalid(name, format!("must be > 0, got {x}")));
    }
    Ok(x)
}

/// `x` must be finite and >= 0.
pub(crate) fn non_negative(name: &str, x: f64) -> Result<f64> {
    finite(name, x)?;
    if x < 0.0 {
        return Err(PreisachError::invalid(name, format!("must be >= 0, got {x}")));
    }
    Ok(x)
}

/// A frequency must be finite, > 0 and below Nyquist.
pub(crate) fn below_nyquist(name: &str, f: f64, fs: f64) -> Result<f64> {
    positive(name, f)?;
    if f >= 0.5 * fs {
        return Err(PreisachError::invalid(name, format!("must be below Nyquist ({} Hz), got {f}", 0.5 * fs)));
    }
    Ok(f)
}
