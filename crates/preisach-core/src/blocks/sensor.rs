//! Measurement-side blocks: Butterworth low-pass, pure (fractional) delay, white
//! noise, ADC quantizer, and the [`Sensor`] that chains them behind a gain
//! (capacitive gauge: 1/5 V/µm in the paper's setup, §3.1). `lowpass`, `delay`,
//! `noise` and `quantizer` are also blocks of their own.
//!
//! A record starts at rest: the low-pass and the delay start in equilibrium with the
//! first sample (constant in, constant out from the first sample); noise and
//! quantizer have no state to settle.

use super::rng::Rng;
use super::{below_nyquist, finite, non_negative};
use crate::error::{PreisachError, Result};
use serde::{Deserialize, Serialize};

// ---------------------------------------------------------------- low-pass

fn default_order() -> usize {
    2
}

/// Parameters of [`Lowpass`] (the JSON form).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LowpassParams {
    /// −3 dB frequency, Hz (> 0, below Nyquist).
    pub cutoff_hz: f64,
    /// Butterworth order, 1–4 (default 2).
    #[serde(default = "default_order")]
    pub order: usize,
}

/// One second-order section, transposed direct form II (a first-order section has
/// `b2 = a2 = 0`).
#[derive(Debug, Clone, Copy, Default)]
struct Biquad {
    b0: f64,
    b1: f64,
    b2: f64,
    a1: f64,
    a2: f64,
    s1: f64,
    s2: f64,
}

impl Biquad {
    #[inline(always)]
    fn step(&mut self, x: f64) -> f64 {
        let y = self.b0 * x + self.s1;
        self.s1 = self.b1 * x - self.a1 * y + self.s2;
        self.s2 = self.b2 * x - self.a2 * y;
        y
    }

    /// DC gain `(b0 + b1 + b2) / (1 + a1 + a2)`.
    fn dc_gain(&self) -> f64 {
        (self.b0 + self.b1 + self.b2) / (1.0 + self.a1 + self.a2)
    }

    /// States of the steady state for a constant input `x`: the output is
    /// `dc_gain · x`. Returns that output.
    fn settle(&mut self, x: f64) -> f64 {
        let y = self.dc_gain() * x;
        self.s1 = y - self.b0 * x;
        self.s2 = self.b2 * x - self.a2 * y;
        y
    }
}

/// Butterworth low-pass by the bilinear transform with the cutoff prewarped, so the
/// digital filter has DC gain 1 and exactly −3 dB at `cutoff_hz`.
///
/// Starts at rest with its first input: on the first `step` after construction or
/// `reset` the states are set to the steady state for that input (as if it had been
/// applied forever), so a constant input gives a constant output from the first sample.
#[derive(Debug, Clone)]
pub struct Lowpass {
    params: LowpassParams,
    sections: [Biquad; 2],
    n: usize,
    /// Whether the states are set (false until the first `step` after a reset).
    settled: bool,
}

impl Lowpass {
    pub fn new(params: LowpassParams, sample_rate_hz: f64) -> Result<Self> {
        let fc = below_nyquist("cutoff_hz", params.cutoff_hz, sample_rate_hz)?;
        let order = params.order;
        if !(1..=4).contains(&order) {
            return Err(PreisachError::invalid("order", format!("must be 1, 2, 3 or 4, got {order}")));
        }
        let k = (std::f64::consts::PI * fc / sample_rate_hz).tan();
        let mut sections = [Biquad::default(); 2];
        let mut n = 0;
        if order % 2 == 1 {
            let b0 = k / (k + 1.0);
            sections[n] = Biquad { b0, b1: b0, a1: (k - 1.0) / (k + 1.0), ..Biquad::default() };
            n += 1;
        }
        // Pole pairs of the analog prototype: Q_m = 1 / (2 sin((2m − 1)π / 2N)).
        for m in 1..=order / 2 {
            let q = 1.0 / (2.0 * ((2 * m - 1) as f64 * std::f64::consts::PI / (2 * order) as f64).sin());
            let norm = 1.0 / (1.0 + k / q + k * k);
            let b0 = k * k * norm;
            sections[n] = Biquad {
                b0,
                b1: 2.0 * b0,
                b2: b0,
                a1: 2.0 * (k * k - 1.0) * norm,
                a2: (1.0 - k / q + k * k) * norm,
                ..Biquad::default()
            };
            n += 1;
        }
        Ok(Lowpass { params, sections, n, settled: false })
    }

    pub fn params(&self) -> &LowpassParams {
        &self.params
    }

    #[inline]
    pub fn step(&mut self, x: f64) -> f64 {
        if !self.settled {
            self.settle(x);
        }
        let mut y = x;
        for s in &mut self.sections[..self.n] {
            y = s.step(y);
        }
        y
    }

    /// Set the states to the steady state for a constant input `x`.
    #[cold]
    fn settle(&mut self, x: f64) {
        let mut y = x;
        for s in &mut self.sections[..self.n] {
            y = s.settle(y);
        }
        self.settled = true;
    }

    /// Back to rest: the next `step` starts in equilibrium with its input.
    pub fn reset(&mut self) {
        for s in &mut self.sections {
            s.s1 = 0.0;
            s.s2 = 0.0;
        }
        self.settled = false;
    }
}

// ---------------------------------------------------------------- delay

/// Largest delay accepted, in samples (keeps the ring buffer at most 128 MB).
pub const MAX_DELAY_SAMPLES: f64 = 16_000_000.0;

/// Parameters of [`Delay`] (the JSON form).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DelayParams {
    /// Pure delay, seconds (>= 0; fractional samples allowed).
    pub delay_s: f64,
}

/// Pure delay `y[n] = x(n − D)`, `D = delay_s · f_s` samples: an integer ring buffer
/// plus linear interpolation for the fractional part (exact on ramps). Starts at
/// rest with its first input: on the first `step` after construction or `reset` the
/// line is filled with that input (the signal held it before the first sample).
#[derive(Debug, Clone)]
pub struct Delay {
    params: DelayParams,
    /// Whether the line is filled (false until the first `step` after a reset).
    settled: bool,
    buf: Vec<f64>,
    mask: usize,
    head: usize,
    n_int: usize,
    frac: f64,
}

impl Delay {
    pub fn new(params: DelayParams, sample_rate_hz: f64) -> Result<Self> {
        let d = non_negative("delay_s", params.delay_s)? * sample_rate_hz;
        if d > MAX_DELAY_SAMPLES {
            return Err(PreisachError::invalid(
                "delay_s",
                format!("{} s is {d:.0} samples, above the limit of {MAX_DELAY_SAMPLES:.0}", params.delay_s),
            ));
        }
        let mut n_int = d.floor() as usize;
        let mut frac = d - n_int as f64;
        // Snap delays within rounding of an integer (e.g. 3e-5 s · 1e5 Hz) to it.
        if frac > 1.0 - 1e-9 {
            n_int += 1;
            frac = 0.0;
        } else if frac < 1e-9 {
            frac = 0.0;
        }
        // Power-of-two length: the index wraps with a mask, no division per sample.
        let len = (n_int + 2).next_power_of_two();
        Ok(Delay { params, settled: false, buf: vec![0.0; len], mask: len - 1, head: 0, n_int, frac })
    }

    pub fn params(&self) -> &DelayParams {
        &self.params
    }

    /// Delay in samples (integer + fractional part).
    pub fn samples(&self) -> f64 {
        self.n_int as f64 + self.frac
    }

    #[inline]
    pub fn step(&mut self, x: f64) -> f64 {
        if !self.settled {
            self.settle(x);
        }
        self.head = (self.head + 1) & self.mask;
        self.buf[self.head] = x;
        let a = self.buf[(self.head.wrapping_sub(self.n_int)) & self.mask];
        let b = self.buf[(self.head.wrapping_sub(self.n_int + 1)) & self.mask];
        a + self.frac * (b - a)
    }

    /// Fill the line with `x`.
    #[cold]
    fn settle(&mut self, x: f64) {
        self.buf.iter_mut().for_each(|v| *v = x);
        self.settled = true;
    }

    /// Back to rest: the next `step` fills the line with its input.
    pub fn reset(&mut self) {
        self.head = 0;
        self.settled = false;
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

/// Additive white Gaussian noise, deterministic for a seed; `reset` restarts the
/// stream from the seed.
#[derive(Debug, Clone)]
pub struct Noise {
    params: NoiseParams,
    rng: Rng,
}

impl Noise {
    pub fn new(params: NoiseParams, _sample_rate_hz: f64) -> Result<Self> {
        non_negative("std", params.std)?;
        let rng = Rng::new(params.seed);
        Ok(Noise { params, rng })
    }

    pub fn params(&self) -> &NoiseParams {
        &self.params
    }

    #[inline]
    pub fn step(&mut self, x: f64) -> f64 {
        if self.params.std == 0.0 {
            return x;
        }
        x + self.params.std * self.rng.normal()
    }

    pub fn reset(&mut self) {
        self.rng = Rng::new(self.params.seed);
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
    params: QuantizerParams,
    q: f64,
    max_code: f64,
}

impl Quantizer {
    pub fn new(params: QuantizerParams, _sample_rate_hz: f64) -> Result<Self> {
        let bits = params.bits;
        if !(1..=32).contains(&bits) {
            return Err(PreisachError::invalid("bits", format!("must be in 1..=32, got {bits}")));
        }
        let [lo, hi] = params.range;
        finite("range", lo)?;
        finite("range", hi)?;
        if lo >= hi {
            return Err(PreisachError::invalid("range", format!("lo must be below hi, got [{lo}, {hi}]")));
        }
        let max_code = ((1u64 << bits) - 1) as f64;
        Ok(Quantizer { q: (hi - lo) / max_code, max_code, params })
    }

    pub fn params(&self) -> &QuantizerParams {
        &self.params
    }

    /// Step between codes.
    pub fn lsb(&self) -> f64 {
        self.q
    }

    #[inline]
    pub fn step(&self, x: f64) -> f64 {
        let lo = self.params.range[0];
        let code = ((x - lo) / self.q).round().clamp(0.0, self.max_code);
        lo + code * self.q
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

/// gain → low-pass → delay → noise → ADC. Starts at rest with its first input (the
/// low-pass and delay settle on it; see [`Lowpass`], [`Delay`]).
#[derive(Debug, Clone)]
pub struct Sensor {
    params: SensorParams,
    lowpass: Option<Lowpass>,
    delay: Option<Delay>,
    noise: Noise,
    adc: Option<Quantizer>,
}

impl Sensor {
    pub fn new(params: SensorParams, fs: f64) -> Result<Self> {
        finite("gain", params.gain)?;
        let lowpass = params.lowpass.clone().map(|p| Lowpass::new(p, fs)).transpose()?;
        let delay = Delay::new(DelayParams { delay_s: params.delay_s }, fs)?;
        let delay = if delay.samples() > 0.0 { Some(delay) } else { None };
        let noise = Noise::new(NoiseParams { std: params.noise_std, seed: params.seed }, fs).map_err(|_| {
            PreisachError::invalid("noise_std", format!("must be finite and >= 0, got {}", params.noise_std))
        })?;
        let adc = params.adc.clone().map(|p| Quantizer::new(p, fs)).transpose()?;
        Ok(Sensor { params, lowpass, delay, noise, adc })
    }

    pub fn params(&self) -> &SensorParams {
        &self.params
    }

    #[inline]
    pub fn step(&mut self, x: f64) -> f64 {
        let mut y = self.params.gain * x;
        if let Some(f) = &mut self.lowpass {
            y = f.step(y);
        }
        if let Some(d) = &mut self.delay {
            y = d.step(y);
        }
        y = self.noise.step(y);
        if let Some(q) = &self.adc {
            y = q.step(y);
        }
        y
    }

    pub fn reset(&mut self) {
        if let Some(f) = &mut self.lowpass {
            f.reset();
        }
        if let Some(d) = &mut self.delay {
            d.reset();
        }
        self.noise.reset();
    }

    /// Back to rest keeping the noise stream where it is (a new record, not a replay).
    pub fn reset_state(&mut self) {
        if let Some(f) = &mut self.lowpass {
            f.reset();
        }
        if let Some(d) = &mut self.delay {
            d.reset();
        }
    }
}
