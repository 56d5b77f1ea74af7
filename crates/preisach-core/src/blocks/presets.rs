//! Named stages. `paper` mirrors the paper's setup (§3.1, §4.2):
//!
//! | block | what | units |
//! |---|---|---|
//! | quantizer | 16-bit DAC, ±10 V | DAC V → DAC V |
//! | lowpass | reconstruction filter, 2nd-order Butterworth, 20 kHz | DAC V |
//! | amplifier | 20 V/V, saturation [−30, 180] V | DAC V → piezo V |
//! | hysteresis | parametric Preisach, 500 levels on [−30, 180] V | piezo V → µm |
//! | creep | Kelvin–Voigt, 1 %/decade from 0.1 s to 100 s (below 5 Hz) | µm |
//! | vibration | one mode at 780 Hz, ζ = 0.02 | µm |
//! | sensor | 0.2 V/µm, anti-aliasing 4th-order Butterworth 20 kHz, optional 4.58e-4 s delay, 1 nm noise, 16-bit ±10 V ADC | µm → sensor V |
//!
//! The usable input is DAC 0–7.5 V (0–150 V at the piezo), giving roughly 0–40 µm,
//! i.e. 0–8 V at the sensor.

use serde::{Deserialize, Serialize};

use super::amplifier::AmplifierParams;
use super::chain::{BlockSpec, Chain};
use super::creep::CreepParams;
use super::hysteresis::{HysteresisParams, Output, ParametricHysteresis};
use super::sensor::{LowpassParams, QuantizerParams, SensorParams};
use super::vibration::{Mode, VibrationParams};
use crate::error::{PreisachError, Result};

/// The paper's measurement delay (§4), seconds.
pub const PAPER_DELAY_S: f64 = 4.58e-4;

/// `delay` override: `true`/`false` for the paper's delay on/off, or seconds.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum DelayOption {
    Switch(bool),
    Seconds(f64),
}

/// Overrides of the `paper` preset (all optional; unknown names are an error).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PaperOptions {
    pub sample_rate_hz: f64,
    /// Sensor delay: off by default; `true` = 4.58e-4 s; a number = seconds.
    pub delay: DelayOption,
    /// Seed of the sensor noise.
    pub seed: u64,
    /// Sensor noise standard deviation, sensor V (default 2e-4 V = 1 nm).
    pub noise_std: f64,
    /// Levels of the true hysteresis grid.
    pub n_h: usize,
    pub resonance_hz: f64,
    pub damping: f64,
    /// Creep on/off.
    pub creep: bool,
    /// Creep per decade of time (fraction).
    pub creep_per_decade: f64,
    /// Anti-aliasing cutoff and order.
    pub lowpass_hz: f64,
    pub lowpass_order: usize,
    /// DAC and ADC resolution (0 = ideal, no quantization).
    pub dac_bits: u32,
    pub adc_bits: u32,
    /// Output drift (thermal), see `drift`; off by default.
    pub drift_gain_per_s: f64,
    pub drift_offset_per_s: f64,
}

impl Default for PaperOptions {
    fn default() -> Self {
        PaperOptions {
            sample_rate_hz: 100_000.0,
            delay: DelayOption::Switch(false),
            seed: 0,
            noise_std: 2e-4,
            n_h: 500,
            resonance_hz: 780.0,
            damping: 0.02,
            creep: true,
            creep_per_decade: 0.01,
            lowpass_hz: 20_000.0,
            lowpass_order: 4,
            dac_bits: 16,
            adc_bits: 16,
            drift_gain_per_s: 0.0,
            drift_offset_per_s: 0.0,
        }
    }
}

/// The `paper` preset's "true" hysteresis on `n_h` levels: a stroke of about 30 µm over
/// −30…180 V, log-normal coercivity around 12 V, Gaussian interaction, plus a reversible
/// part.
pub fn paper_hysteresis(n_h: usize) -> ParametricHysteresis {
    ParametricHysteresis {
        u_range: [-30.0, 180.0],
        n_h,
        hysteretic_stroke: 30.0,
        coercivity_median: 12.0,
        coercivity_sigma: 0.7,
        interaction_mean: Some(75.0),
        interaction_sigma: 45.0,
        reversible_slope: 0.06,
        reversible_saturation: 1.5,
        reversible_width: Some(90.0),
        offset: 0.0,
        output: Output::Interpolated,
        initial_extrema: None,
    }
}

/// The `paper` stage (see the module doc).
pub fn paper(o: &PaperOptions) -> Result<Chain> {
    let delay_s = match o.delay {
        DelayOption::Switch(true) => PAPER_DELAY_S,
        DelayOption::Switch(false) => 0.0,
        DelayOption::Seconds(s) => s,
    };
    let quant = |bits: u32| QuantizerParams { bits, range: [-10.0, 10.0] };
    let mut blocks = Vec::new();
    if o.dac_bits > 0 {
        blocks.push(BlockSpec::Quantizer(quant(o.dac_bits)));
    }
    blocks.push(BlockSpec::Lowpass(LowpassParams { cutoff_hz: o.lowpass_hz, order: 2 }));
    blocks.push(BlockSpec::Amplifier(AmplifierParams {
        gain: 20.0,
        saturation: Some([-30.0, 180.0]),
        slew_v_per_s: None,
    }));
    blocks.push(BlockSpec::Hysteresis(HysteresisParams::Parametric(paper_hysteresis(o.n_h))));
    if o.creep {
        blocks.push(BlockSpec::Creep(CreepParams::log_law(o.creep_per_decade, 0.1, 100.0)));
    }
    blocks.push(BlockSpec::Vibration(VibrationParams {
        modes: vec![Mode { frequency_hz: o.resonance_hz, damping: o.damping }],
    }));
    blocks.push(BlockSpec::Sensor(SensorParams {
        gain: 0.2,
        lowpass: Some(LowpassParams { cutoff_hz: o.lowpass_hz, order: o.lowpass_order }),
        delay_s,
        noise_std: o.noise_std,
        seed: o.seed,
        adc: if o.adc_bits > 0 { Some(quant(o.adc_bits)) } else { None },
    }));
    if o.drift_gain_per_s != 0.0 || o.drift_offset_per_s != 0.0 {
        blocks.push(BlockSpec::Drift(super::drift::DriftParams {
            gain_per_s: o.drift_gain_per_s,
            offset: 0.0,
            offset_per_s: o.drift_offset_per_s,
        }));
    }
    Chain::new(blocks)?.with_sample_rate(Some(o.sample_rate_hz))
}

/// Names of the presets.
pub const PRESETS: &[&str] = &["paper"];

/// A preset by name with overrides given as a JSON object (`"{}"` for none), e.g.
/// `{"delay": true, "seed": 3}`.
pub fn preset(name: &str, overrides_json: &str) -> Result<Chain> {
    match name {
        "paper" => {
            let o: PaperOptions = serde_json::from_str(overrides_json)
                .map_err(|e| PreisachError::invalid("overrides", format!("for preset 'paper': {e}")))?;
            paper(&o)
        }
        other => Err(PreisachError::invalid("name", format!("unknown preset '{other}', expected one of {PRESETS:?}"))),
    }
}
