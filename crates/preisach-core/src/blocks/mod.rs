//! Plant blocks (`docs/method/blocks.md`): one vocabulary for the simulated stage, an
//! identified model, an identified model plus effects, and the diagnoser.
//!
//! A [`Chain`] is a *description*: blocks with continuous parameters (a serde struct per
//! block, the JSON form), run in list order. Compiled for one sample rate and one
//! [`Sampling`] it becomes a [`Runtime`]: per-sample state, `step(x) -> y`, never
//! allocating. Linear blocks share one continuous description ([`lti`]) sampled by a
//! zero-order hold (per sample), a first-order hold (over records) or, for a per-sample
//! low-pass, Tustin's transform.
//!
//! Signal units along the `paper` preset (see [`presets`]): DAC volts → amplifier
//! volts (piezo) → hysteresis µm → creep/vibration µm → sensor volts (1/5 V/µm).
//! Blocks themselves are unit-agnostic except where a doc comment says otherwise.
//!
//! A record starts at rest: blocks start in equilibrium with the chain's initial input
//! (by default the first sample), so a constant input gives a constant output from the
//! first sample (linear blocks at steady state, the delay line filled, the amplifier's
//! slew limiter at its value, the hysteresis memory after its initial history then the
//! input); drift and noise have nothing to settle.

pub mod amplifier;
pub mod chain;
pub mod creep;
pub mod drift;
pub mod hysteresis;
pub mod inverse;
pub mod lti;
pub mod presets;
pub mod rate;
pub mod rng;
pub mod runtime;
pub mod sensor;
mod v1;
pub mod vibration;

pub use amplifier::{Amplifier, AmplifierParams};
pub use chain::{BlockSpec, Chain, BLOCK_TYPES, CHAIN_VERSION};
pub use creep::CreepParams;
pub use drift::DriftParams;
pub use hysteresis::{
    Hysteresis, HysteresisCore, HysteresisParams, IdentifiedHysteresis, Output, ParametricHysteresis,
};
pub use lti::{Discretization, Filter, Linear, Lti, Sampling, Section};
pub use presets::{paper, preset, PaperOptions};
pub use rate::RateParams;
pub use rng::Rng;
pub use runtime::{sample_period, Block, Runtime};
pub use sensor::{DelayParams, LowpassParams, Noise, NoiseParams, Quantizer, QuantizerParams, Sensor, SensorParams};
pub use v1::{effect_blocks, stage_blocks};
pub use vibration::{Mode, VibrationParams};

use crate::error::{PreisachError, Result};

/// `x` must be finite.
pub(crate) fn finite(name: &str, x: f64) -> Result<f64> {
    if !x.is_finite() {
        return Err(PreisachError::invalid(name, format!("must be finite, got {x}")));
    }
    Ok(x)
}

/// Every value must be finite (the error names the first bad index).
pub(crate) fn finite_all(name: &str, xs: &[f64]) -> Result<()> {
    for (k, &x) in xs.iter().enumerate() {
        finite(&format!("{name}[{k}]"), x)?;
    }
    Ok(())
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

/// A frequency must be finite, > 0 and below Nyquist (in a per-sample run).
pub(crate) fn below_nyquist(name: &str, f: f64, fs: f64) -> Result<f64> {
    positive(name, f)?;
    if f >= 0.5 * fs {
        return Err(PreisachError::invalid(
            name,
            format!(
                "must be below Nyquist ({} Hz) of the run's rate ({fs} Hz) to run per sample, got {f} \
                 (predict has no such limit)",
                0.5 * fs
            ),
        ));
    }
    Ok(f)
}
