//! A chain compiled for one sample rate and one sampling: the per-sample path.
//!
//! Every block is in equilibrium with the chain's initial input before the first sample
//! (by default the first sample itself: each block settles on its first input), then
//! `step` runs the blocks in list order. The rate branch takes the input of the nearest
//! preceding hysteresis block; drift takes the sample's absolute time. Nothing here
//! allocates per sample.

use std::sync::Arc;

use super::amplifier::Amplifier;
use super::chain::BlockSpec;
use super::drift::DriftParams;
use super::hysteresis::{Hysteresis, HysteresisCore};
use super::lti::{Linear, Sampling};
use super::sensor::{Noise, Quantizer, Sensor};
use super::{below_nyquist, finite};
use crate::error::{check_signal, PreisachError, Result};

impl BlockSpec {
    /// The run-time block at `fs`; `deterministic` turns noise and quantization off.
    pub(super) fn build(
        &self,
        fs: f64,
        sampling: Sampling,
        deterministic: bool,
        core: Option<&Arc<HysteresisCore>>,
    ) -> Result<Block> {
        let plain = sampling.plain();
        Ok(match self {
            BlockSpec::Amplifier(p) => Block::Amplifier(Amplifier::new(p, fs)?),
            BlockSpec::Hysteresis(_) => {
                let core =
                    core.cloned().ok_or_else(|| PreisachError::invalid("hysteresis", "its model is not built"))?;
                Block::Hysteresis(Hysteresis::new(core))
            }
            BlockSpec::Rate(p) => Block::Rate(Linear::new(&p.lti()?, fs, plain)?),
            BlockSpec::Creep(p) => Block::Linear(Linear::new(&p.lti()?, fs, plain)?),
            BlockSpec::Vibration(p) => {
                if sampling == Sampling::Zoh {
                    for (k, m) in p.modes.iter().enumerate() {
                        below_nyquist(&format!("modes[{k}].frequency_hz"), m.frequency_hz, fs)?;
                    }
                }
                Block::Linear(Linear::new(&p.lti()?, fs, plain)?)
            }
            BlockSpec::Lowpass(p) => Block::Linear(Linear::new(&p.lti()?, fs, p.discretization(sampling, fs)?)?),
            BlockSpec::Delay(p) => Block::Linear(Linear::new(&p.lti()?, fs, plain)?),
            BlockSpec::Sensor(p) => Block::Sensor(Sensor::new(p, fs, sampling, deterministic)?),
            BlockSpec::Drift(p) => Block::Drift(p.clone()),
            BlockSpec::Noise(_) | BlockSpec::Quantizer(_) if deterministic => Block::Pass,
            BlockSpec::Noise(p) => Block::Noise(Noise::new(p)?),
            BlockSpec::Quantizer(p) => Block::Quantizer(Quantizer::new(p)?),
        })
    }
}

/// The sample period of a time column, seconds: `t` must increase strictly and be
/// regular (every sample within a quarter period of the line through its ends, so one
/// missing sample is caught while the rounding of a stored time axis is not). Errors
/// name the row (0-based).
pub fn sample_period(t: &[f64]) -> Result<f64> {
    check_signal("t", t)?;
    if t.len() < 2 {
        return Err(PreisachError::invalid("t", "need at least 2 samples to know the sample rate"));
    }
    if let Some(i) = (1..t.len()).find(|&i| t[i] <= t[i - 1]) {
        return Err(PreisachError::invalid(
            "t",
            format!("time must increase strictly (row {i}: {} after {})", t[i], t[i - 1]),
        ));
    }
    let n = t.len() - 1;
    let period = (t[n] - t[0]) / n as f64;
    let off = |k: usize| (t[k] - (t[0] + k as f64 * period)).abs() > 0.25 * period;
    if let Some(k) = (0..t.len()).find(|&k| off(k)) {
        // Name the first step that is off by as much (else the first sample off the grid).
        let i = (1..t.len()).find(|&i| (t[i] - t[i - 1] - period).abs() > 0.25 * period).unwrap_or(k);
        let step = t[i] - t[i - 1];
        return Err(PreisachError::invalid(
            "t",
            format!("irregular sampling at row {i} (a step of {step:.6e} s; the record's period is {period:.6e} s)"),
        ));
    }
    Ok(period)
}

/// A run-time block: coefficients and state.
#[derive(Debug, Clone)]
pub enum Block {
    Amplifier(Amplifier),
    Hysteresis(Hysteresis),
    /// The rate branch: its filter runs on the nearest preceding hysteresis input.
    Rate(Linear),
    /// Creep, vibration, low-pass, delay.
    Linear(Linear),
    Sensor(Sensor),
    Drift(DriftParams),
    Noise(Noise),
    Quantizer(Quantizer),
    /// A block left out (noise or a quantizer in a deterministic run).
    Pass,
}

impl Block {
    /// Back to rest; `replay` also restarts noise streams from their seeds.
    fn reset(&mut self, replay: bool) {
        match self {
            Block::Amplifier(b) => b.reset(),
            Block::Hysteresis(b) => b.reset(),
            Block::Rate(b) | Block::Linear(b) => b.reset(),
            Block::Sensor(b) => b.reset(replay),
            Block::Noise(b) if replay => b.reset(),
            _ => {}
        }
    }
}

/// A chain compiled for one sample rate: the per-sample path. `step` never allocates.
#[derive(Debug, Clone)]
pub struct Runtime {
    blocks: Vec<Block>,
    sample_rate_hz: f64,
    dt: f64,
    /// Samples since the time origin, and the origin (seconds).
    n: u64,
    t0: f64,
    initial_input: Option<f64>,
    /// Blocks to be settled at the initial input before the next sample.
    pending: bool,
}

impl Runtime {
    pub(super) fn new(blocks: Vec<Block>, sample_rate_hz: f64, initial_input: Option<f64>) -> Self {
        let dt = 1.0 / sample_rate_hz;
        Runtime { blocks, sample_rate_hz, dt, n: 0, t0: 0.0, initial_input, pending: initial_input.is_some() }
    }

    pub fn sample_rate_hz(&self) -> f64 {
        self.sample_rate_hz
    }

    /// Absolute time of the next sample, seconds.
    pub fn time_s(&self) -> f64 {
        self.t0 + self.n as f64 * self.dt
    }

    /// Set the absolute time of the next sample (drift blocks follow).
    pub fn set_time(&mut self, t: f64) -> Result<()> {
        self.t0 = finite("time_s", t)?;
        self.n = 0;
        Ok(())
    }

    /// The input the blocks rest at before the next record (`None`: its first input).
    pub fn set_initial_input(&mut self, x: Option<f64>) -> Result<()> {
        if let Some(v) = x {
            finite("initial_input", v)?;
        }
        self.initial_input = x;
        self.reset_state();
        Ok(())
    }

    /// One sample at the chain's clock. Never allocates.
    #[inline]
    pub fn step(&mut self, x: f64) -> f64 {
        let t = self.time_s();
        self.n += 1;
        self.step_at(t, x)
    }

    /// One sample at absolute time `t` (for drift), the clock untouched.
    #[inline]
    pub fn step_at(&mut self, t: f64, x: f64) -> f64 {
        if self.pending {
            self.settle(t);
        }
        let (mut y, mut hin) = (x, x);
        for b in &mut self.blocks {
            y = match b {
                Block::Hysteresis(h) => {
                    hin = y;
                    h.step(y)
                }
                Block::Rate(r) => y + r.step(hin),
                Block::Linear(l) => l.step(y),
                Block::Amplifier(a) => a.step(y),
                Block::Sensor(s) => s.step(y),
                Block::Drift(d) => d.apply(y, t),
                Block::Noise(n) => n.step(y),
                Block::Quantizer(q) => q.step(y),
                Block::Pass => y,
            };
        }
        y
    }

    /// Every block at rest with the initial input (its output passed down the chain
    /// without noise).
    #[cold]
    fn settle(&mut self, t: f64) {
        self.pending = false;
        let Some(x) = self.initial_input else { return };
        let (mut y, mut hin) = (x, x);
        for b in &mut self.blocks {
            y = match b {
                Block::Hysteresis(h) => {
                    hin = y;
                    h.settle(y)
                }
                Block::Rate(r) => y + r.settle(hin),
                Block::Linear(l) => l.settle(y),
                Block::Amplifier(a) => a.settle(y),
                Block::Sensor(s) => s.settle(y),
                Block::Drift(d) => d.apply(y, t),
                Block::Quantizer(q) => q.step(y),
                Block::Noise(_) | Block::Pass => y,
            };
        }
    }

    /// Run a block of samples at the chain's clock (`out.len() == u.len()`).
    pub fn run(&mut self, u: &[f64], out: &mut [f64]) {
        for (o, &x) in out.iter_mut().zip(u) {
            *o = self.step(x);
        }
    }

    /// Full reset: rest (in equilibrium with the initial input, or the next sample), time
    /// 0, noise streams from their seeds (a replay gives the same output).
    pub fn reset(&mut self) {
        self.n = 0;
        self.t0 = 0.0;
        self.blocks.iter_mut().for_each(|b| b.reset(true));
        self.pending = self.initial_input.is_some();
    }

    /// Back to rest for a new record: absolute time and noise streams run on.
    pub fn reset_state(&mut self) {
        self.blocks.iter_mut().for_each(|b| b.reset(false));
        self.pending = self.initial_input.is_some();
    }
}
