//! Measurement-side blocks: Butterworth low-pass, pure (fractional) delay, white
//! noise, ADC quantizer, and the [`Sensor`] that chains them behind a gain
//! (capacitive gauge: 1/5 V/µm in the paper's setup, §3.1). `lowpass`, `delay`,
//! `noise` and `quantizer` are also blocks of their own.
//!
//! A record starts at rest: the low-pass and the delay start in equilibrium with the
//! first sample (constant in, constant out from the first sample); noise and
//! quantizer have no state to settle.

use super::lti::{Discretization, Linear, Lti, Sampling, Section, C};
use super::rng::Rng;
use super::{below_nyquist, finite, non_negative, positive};
use crate::error::{PreisachError, Result};
use serde::{Deserialize, Serialize};

// ---------------------------------------------------------------- low-pass

fn default_order() -> usize {
    2
}

/// Parameters of a Butterworth low-pass (the JSON form).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LowpassParams {
    /// −3 dB frequency, Hz (> 0; below Nyquist for a per-sample run).
    pub cutoff_hz: f64,
    /// Butterworth order, 1–4 (default 2).
    #[serde(default = "default_order")]
    pub order: usize,
}

impl LowpassParams {
    /// The analog Butterworth filter (static gain 1) as one section: poles
    /// `ωc e^{jπ(2k + N + 1)/2N}`, residues `Π(−p_j) / Π_{j≠k}(p_k − p_j)`.
    pub fn lti(&self) -> Result<Lti> {
        let fc = positive("cutoff_hz", self.cutoff_hz)?;
        let n = self.order;
        if !(1..=4).contains(&n) {
            return Err(PreisachError::invalid("order", format!("must be 1, 2, 3 or 4, got {n}")));
        }
        let wc = std::f64::consts::TAU * fc;
        let ps: Vec<C> =
            (0..n).map(|k| C::from_polar(wc, std::f64::consts::PI * (2 * k + n + 1) as f64 / (2 * n) as f64)).collect();
        let num: C = ps.iter().map(|&p| -p).product();
        let mut terms = Vec::new();
        for (k, &p) in ps.iter().enumerate() {
            if p.im < -1e-9 * wc {
                continue; // the conjugate of a pole already taken
            }
            let p = if p.im.abs() <= 1e-9 * wc { C::new(p.re, 0.0) } else { p };
            let den: C = ps.iter().enumerate().filter(|&(j, _)| j != k).map(|(_, &q)| p - q).product();
            let r = num.re / den;
            terms.push((p, if p.im == 0.0 { C::new(r.re, 0.0) } else { r }));
        }
        Ok(Lti::series(vec![Section::new(0.0, terms)?]))
    }

    /// How the filter is sampled: per sample, Tustin's transform prewarped at the cutoff
    /// (checked below Nyquist), so the digital filter has static gain 1 and exactly
    /// −3 dB at `cutoff_hz`; over records, the first-order hold.
    pub fn discretization(&self, sampling: Sampling, sample_rate_hz: f64) -> Result<Discretization> {
        Ok(match sampling {
            Sampling::Zoh => {
                Discretization::Bilinear { prewarp_hz: below_nyquist("cutoff_hz", self.cutoff_hz, sample_rate_hz)? }
            }
            Sampling::Foh => Discretization::Foh,
        })
    }
}

// ---------------------------------------------------------------- delay

/// Parameters of a pure delay (the JSON form).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DelayParams {
    /// Pure delay, seconds (>= 0; fractional samples allowed).
    pub delay_s: f64,
}

impl DelayParams {
    pub fn lti(&self) -> Result<Lti> {
        Ok(Lti::delay(non_negative("delay_s", self.delay_s)?))
    }
}

// ---------------------------------------------------------------- noise

/// Parameters of [`Noise`] (the JSON form).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NoiseParams {
    /// Standard deviation of the additive white Gaussian noise, output units (>= 0).
    pub std: f64,
    /// Seed of the noise stream.
    #[serde(default)]
    pub seed: u64,
}

impl NoiseParams {
    pub fn check(&self) -> Result<()> {
        non_negative("std", self.std).map(|_| ())
    }
}

/// Additive white Gaussian noise, deterministic for a seed; `reset` restarts the
/// stream from the seed.
#[derive(Debug, Clone)]
pub struct Noise {
    std: f64,
    seed: u64,
    rng: Rng,
}

impl Noise {
    pub fn new(p: &NoiseParams) -> Result<Self> {
        p.check()?;
        Ok(Noise { std: p.std, seed: p.seed, rng: Rng::new(p.seed) })
    }

    #[inline]
    pub fn step(&mut self, x: f64) -> f64 {
        if self.std == 0.0 {
            return x;
        }
        x + self.std * self.rng.normal()
    }

    pub fn reset(&mut self) {
        self.rng = Rng::new(self.seed);
    }
}

// ---------------------------------------------------------------- quantizer

/// Parameters of [`Quantizer`] (the JSON form).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct QuantizerParams {
    /// Resolution, 1–32 bits.
    pub bits: u32,
    /// Full-scale range `[lo, hi]` in signal units (e.g. ±10 V).
    pub range: [f64; 2],
}

/// A DAC/ADC: `2^bits` codes spread evenly over `range` (code 0 at `lo`, the last code
/// at `hi`), round to nearest, clipped at the ends.
#[derive(Debug, Clone)]
pub struct Quantizer {
    lo: f64,
    q: f64,
    max_code: f64,
}

impl Quantizer {
    pub fn new(p: &QuantizerParams) -> Result<Self> {
        let bits = p.bits;
        if !(1..=32).contains(&bits) {
            return Err(PreisachError::invalid("bits", format!("must be in 1..=32, got {bits}")));
        }
        let [lo, hi] = p.range;
        finite("range", lo)?;
        finite("range", hi)?;
        if lo >= hi {
            return Err(PreisachError::invalid("range", format!("lo must be below hi, got [{lo}, {hi}]")));
        }
        let max_code = ((1u64 << bits) - 1) as f64;
        Ok(Quantizer { lo, q: (hi - lo) / max_code, max_code })
    }

    /// Step between codes.
    pub fn lsb(&self) -> f64 {
        self.q
    }

    #[inline]
    pub fn step(&self, x: f64) -> f64 {
        let code = ((x - self.lo) / self.q).round().clamp(0.0, self.max_code);
        self.lo + code * self.q
    }
}

// ---------------------------------------------------------------- sensor

fn default_sensor_gain() -> f64 {
    0.2
}

/// Parameters of [`Sensor`] (the JSON form).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SensorParams {
    /// Sensitivity, output units per input unit (default 0.2 V/µm).
    #[serde(default = "default_sensor_gain")]
    pub gain: f64,
    /// Anti-aliasing low-pass; `None` = none.
    #[serde(default)]
    pub lowpass: Option<LowpassParams>,
    /// Pure delay, seconds (default 0).
    #[serde(default)]
    pub delay_s: f64,
    /// White noise standard deviation, output units (default 0).
    #[serde(default)]
    pub noise_std: f64,
    /// Seed of the noise stream.
    #[serde(default)]
    pub seed: u64,
    /// ADC quantization; `None` = none.
    #[serde(default)]
    pub adc: Option<QuantizerParams>,
}

impl Default for SensorParams {
    fn default() -> Self {
        SensorParams { gain: default_sensor_gain(), lowpass: None, delay_s: 0.0, noise_std: 0.0, seed: 0, adc: None }
    }
}

impl SensorParams {
    /// The low-pass and the delay as one linear description (validates them).
    pub fn lti(&self) -> Result<Lti> {
        finite("gain", self.gain)?;
        let lp = match &self.lowpass {
            Some(p) => p.lti()?,
            None => Lti::default(),
        };
        Ok(lp.then(DelayParams { delay_s: self.delay_s }.lti()?))
    }

    /// Everything but the sampling (noise and ADC included).
    pub fn check(&self) -> Result<()> {
        self.lti()?;
        NoiseParams { std: self.noise_std, seed: self.seed }.check().map_err(|_| {
            PreisachError::invalid("noise_std", format!("must be finite and >= 0, got {}", self.noise_std))
        })?;
        self.adc.as_ref().map(Quantizer::new).transpose().map(|_| ())
    }
}

/// gain → low-pass → delay → noise → ADC.
#[derive(Debug, Clone)]
pub struct Sensor {
    gain: f64,
    linear: Linear,
    noise: Noise,
    adc: Option<Quantizer>,
}

impl Sensor {
    /// Sampled at `fs`; `deterministic` leaves the noise and the ADC out.
    pub fn new(p: &SensorParams, fs: f64, sampling: Sampling, deterministic: bool) -> Result<Self> {
        p.check()?;
        let d = match &p.lowpass {
            Some(lp) => lp.discretization(sampling, fs)?,
            None => sampling.plain(),
        };
        let linear = Linear::new(&p.lti()?, fs, d)?;
        let std = if deterministic { 0.0 } else { p.noise_std };
        let noise = Noise::new(&NoiseParams { std, seed: p.seed })?;
        let adc = if deterministic { None } else { p.adc.as_ref().map(Quantizer::new).transpose()? };
        Ok(Sensor { gain: p.gain, linear, noise, adc })
    }

    #[inline]
    pub fn step(&mut self, x: f64) -> f64 {
        let y = self.noise.step(self.linear.step(self.gain * x));
        match &self.adc {
            Some(q) => q.step(y),
            None => y,
        }
    }

    /// At rest with `x` (no noise); returns the output then.
    pub fn settle(&mut self, x: f64) -> f64 {
        let y = self.linear.settle(self.gain * x);
        match &self.adc {
            Some(q) => q.step(y),
            None => y,
        }
    }

    /// Back to rest; `replay` restarts the noise stream from its seed.
    pub fn reset(&mut self, replay: bool) {
        self.linear.reset();
        if replay {
            self.noise.reset();
        }
    }
}
