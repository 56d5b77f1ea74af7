//! A chain of blocks: the plant simulator, an identified model plus effects, or a
//! diagnosis candidate. Serialized as versioned JSON:
//!
//! ```json
//! {"version": 1, "sample_rate_hz": 100000.0, "blocks": [
//!   {"type": "amplifier", "gain": 20.0, "saturation": [-30.0, 180.0], "slew_v_per_s": null},
//!   {"type": "hysteresis", "source": "parametric", "lo": -30.0, "hi": 180.0, "n_h": 500, ...},
//!   {"type": "creep", "gains": [0.01, 0.01], "time_constants_s": [0.1, 1.0]},
//!   {"type": "vibration", "modes": [{"freq_hz": 780.0, "damping": 0.02}]},
//!   {"type": "sensor", "gain": 0.2, "lowpass": {"cutoff_hz": 20000.0, "order": 4}, ...}
//! ]}
//! ```
//!
//! Block types: `amplifier`, `hysteresis`, `creep`, `vibration`, `sensor`, `lowpass`,
//! `delay`, `noise`, `quantizer`, `drift`.
//!
//! A record starts at rest: blocks start in equilibrium with the first sample (after
//! construction, [`Chain::reset`] and [`Chain::reset_state`]), so a constant input
//! gives a constant output from the first sample, apart from noise and drift.

use serde::{Deserialize, Serialize};

use super::amplifier::{Amplifier, AmplifierParams};
use super::creep::{Creep, CreepParams};
use super::drift::{Drift, DriftParams};
use super::hysteresis::{Hysteresis, HysteresisParams};
use super::positive;
use super::sensor::{
    Delay, DelayParams, Lowpass, LowpassParams, Noise, NoiseParams, Quantizer, QuantizerParams, Sensor, SensorParams,
};
use super::vibration::{Vibration, VibrationParams};
use crate::error::{PreisachError, Result};

/// Version of the chain format written by this build.
pub const CHAIN_VERSION: u32 = 1;

/// The parameters of one block, tagged by `"type"` (the JSON form of a [`Block`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "lowercase")]
pub enum BlockSpec {
    Amplifier(AmplifierParams),
    Hysteresis(HysteresisParams),
    Creep(CreepParams),
    Vibration(VibrationParams),
    Sensor(SensorParams),
    Lowpass(LowpassParams),
    Delay(DelayParams),
    Noise(NoiseParams),
    Quantizer(QuantizerParams),
    Drift(DriftParams),
}

impl BlockSpec {
    /// The block's `"type"` name.
    pub fn kind(&self) -> &'static str {
        match self {
            BlockSpec::Amplifier(_) => "amplifier",
            BlockSpec::Hysteresis(_) => "hysteresis",
            BlockSpec::Creep(_) => "creep",
            BlockSpec::Vibration(_) => "vibration",
            BlockSpec::Sensor(_) => "sensor",
            BlockSpec::Lowpass(_) => "lowpass",
            BlockSpec::Delay(_) => "delay",
            BlockSpec::Noise(_) => "noise",
            BlockSpec::Quantizer(_) => "quantizer",
            BlockSpec::Drift(_) => "drift",
        }
    }

    /// Validate the parameters against the sample rate and build the block.
    pub fn build(self, sample_rate_hz: f64) -> Result<Block> {
        let fs = sample_rate_hz;
        Ok(match self {
            BlockSpec::Amplifier(p) => Block::Amplifier(Amplifier::new(p, fs)?),
            BlockSpec::Hysteresis(p) => Block::Hysteresis(Hysteresis::new(p, fs)?),
            BlockSpec::Creep(p) => Block::Creep(Creep::new(p, fs)?),
            BlockSpec::Vibration(p) => Block::Vibration(Vibration::new(p, fs)?),
            BlockSpec::Sensor(p) => Block::Sensor(Sensor::new(p, fs)?),
            BlockSpec::Lowpass(p) => Block::Lowpass(Lowpass::new(p, fs)?),
            BlockSpec::Delay(p) => Block::Delay(Delay::new(p, fs)?),
            BlockSpec::Noise(p) => Block::Noise(Noise::new(p, fs)?),
            BlockSpec::Quantizer(p) => Block::Quantizer(Quantizer::new(p, fs)?),
            BlockSpec::Drift(p) => Block::Drift(Drift::new(p, fs)?),
        })
    }
}

/// A built block: parameters, coefficients and state.
#[derive(Debug, Clone)]
pub enum Block {
    Amplifier(Amplifier),
    Hysteresis(Hysteresis),
    Creep(Creep),
    Vibration(Vibration),
    Sensor(Sensor),
    Lowpass(Lowpass),
    Delay(Delay),
    Noise(Noise),
    Quantizer(Quantizer),
    Drift(Drift),
}

impl Block {
    /// One sample through the block. Never allocates.
    #[inline]
    pub fn step(&mut self, x: f64) -> f64 {
        match self {
            Block::Amplifier(b) => b.step(x),
            Block::Hysteresis(b) => b.step(x),
            Block::Creep(b) => b.step(x),
            Block::Vibration(b) => b.step(x),
            Block::Sensor(b) => b.step(x),
            Block::Lowpass(b) => b.step(x),
            Block::Delay(b) => b.step(x),
            Block::Noise(b) => b.step(x),
            Block::Quantizer(b) => b.step(x),
            Block::Drift(b) => b.step(x),
        }
    }

    /// Back to rest and to the start of its noise stream and clock (a replay).
    pub fn reset(&mut self) {
        match self {
            Block::Amplifier(b) => b.reset(),
            Block::Hysteresis(b) => b.reset(),
            Block::Creep(b) => b.reset(),
            Block::Vibration(b) => b.reset(),
            Block::Sensor(b) => b.reset(),
            Block::Lowpass(b) => b.reset(),
            Block::Delay(b) => b.reset(),
            Block::Noise(b) => b.reset(),
            Block::Quantizer(_) => {}
            Block::Drift(b) => b.set_time(0.0),
        }
    }

    /// Back to rest keeping noise streams and absolute time (a new record).
    pub fn reset_state(&mut self) {
        match self {
            Block::Sensor(b) => b.reset_state(),
            Block::Noise(_) | Block::Drift(_) | Block::Quantizer(_) => {}
            other => other.reset(),
        }
    }

    /// The block's parameters (its JSON form).
    pub fn spec(&self) -> BlockSpec {
        match self {
            Block::Amplifier(b) => BlockSpec::Amplifier(b.params().clone()),
            Block::Hysteresis(b) => BlockSpec::Hysteresis(b.params()),
            Block::Creep(b) => BlockSpec::Creep(b.params().clone()),
            Block::Vibration(b) => BlockSpec::Vibration(b.params().clone()),
            Block::Sensor(b) => BlockSpec::Sensor(b.params().clone()),
            Block::Lowpass(b) => BlockSpec::Lowpass(b.params().clone()),
            Block::Delay(b) => BlockSpec::Delay(b.params().clone()),
            Block::Noise(b) => BlockSpec::Noise(b.params().clone()),
            Block::Quantizer(b) => BlockSpec::Quantizer(b.params().clone()),
            Block::Drift(b) => BlockSpec::Drift(b.params().clone()),
        }
    }

    /// The block's `"type"` name.
    pub fn kind(&self) -> &'static str {
        match self {
            Block::Amplifier(_) => "amplifier",
            Block::Hysteresis(_) => "hysteresis",
            Block::Creep(_) => "creep",
            Block::Vibration(_) => "vibration",
            Block::Sensor(_) => "sensor",
            Block::Lowpass(_) => "lowpass",
            Block::Delay(_) => "delay",
            Block::Noise(_) => "noise",
            Block::Quantizer(_) => "quantizer",
            Block::Drift(_) => "drift",
        }
    }
}

/// The serialized form of a [`Chain`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ChainSpec {
    /// Format version ([`CHAIN_VERSION`]).
    pub version: u32,
    /// Sample rate, Hz; every block is discretized for it.
    pub sample_rate_hz: f64,
    /// Blocks in signal order.
    pub blocks: Vec<BlockSpec>,
}

/// Blocks in series at one sample rate.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(try_from = "ChainSpec", into = "ChainSpec")]
pub struct Chain {
    pub version: u32,
    pub sample_rate_hz: f64,
    pub blocks: Vec<Block>,
    /// Samples since the time origin, and the origin (seconds).
    n: u64,
    t0: f64,
}

impl TryFrom<ChainSpec> for Chain {
    type Error = PreisachError;
    fn try_from(s: ChainSpec) -> Result<Self> {
        Chain::from_spec(s)
    }
}

impl From<Chain> for ChainSpec {
    fn from(c: Chain) -> Self {
        c.spec()
    }
}

impl Chain {
    /// Build and validate every block for `sample_rate_hz`. Errors name the block
    /// (`blocks[2] (vibration): modes[0].damping: must be > 0, got 0`).
    pub fn new(sample_rate_hz: f64, specs: Vec<BlockSpec>) -> Result<Self> {
        positive("sample_rate_hz", sample_rate_hz)?;
        let mut blocks = Vec::with_capacity(specs.len());
        for (k, s) in specs.into_iter().enumerate() {
            let kind = s.kind();
            blocks.push(s.build(sample_rate_hz).map_err(|e| match e {
                PreisachError::Invalid { name, problem } => {
                    PreisachError::invalid(name, format!("{problem} (blocks[{k}], {kind})"))
                }
                other => other,
            })?);
        }
        Ok(Chain { version: CHAIN_VERSION, sample_rate_hz, blocks, n: 0, t0: 0.0 })
    }

    /// From the serialized form (checks the version).
    pub fn from_spec(s: ChainSpec) -> Result<Self> {
        if s.version != CHAIN_VERSION {
            return Err(PreisachError::corrupt(
                "chain",
                format!("unsupported version {}, this build reads version {CHAIN_VERSION}", s.version),
            ));
        }
        Chain::new(s.sample_rate_hz, s.blocks)
    }

    /// Parse JSON: malformed text or an unknown field/type is `Corrupt`; a bad
    /// parameter is `Invalid` naming it.
    pub fn from_json(text: &str) -> Result<Self> {
        let spec: ChainSpec = serde_json::from_str(text).map_err(|e| PreisachError::corrupt("chain", e.to_string()))?;
        Chain::from_spec(spec)
    }

    /// The serialized form.
    pub fn spec(&self) -> ChainSpec {
        ChainSpec {
            version: CHAIN_VERSION,
            sample_rate_hz: self.sample_rate_hz,
            blocks: self.blocks.iter().map(Block::spec).collect(),
        }
    }

    /// Pretty JSON of [`Chain::spec`].
    pub fn to_json(&self) -> String {
        // Serializing plain data with finite numbers cannot fail.
        serde_json::to_string_pretty(&self.spec()).expect("chain spec serializes")
    }

    /// Sample period, seconds.
    pub fn dt(&self) -> f64 {
        1.0 / self.sample_rate_hz
    }

    /// Absolute time of the next sample, seconds.
    pub fn time_s(&self) -> f64 {
        self.t0 + self.n as f64 / self.sample_rate_hz
    }

    /// Set the absolute time of the next sample (drift blocks follow).
    pub fn set_time(&mut self, t: f64) -> Result<()> {
        super::finite("time_s", t)?;
        self.t0 = t;
        self.n = 0;
        for b in &mut self.blocks {
            if let Block::Drift(d) = b {
                d.set_time(t);
            }
        }
        Ok(())
    }

    /// One sample through every block. Never allocates.
    #[inline]
    pub fn step(&mut self, x: f64) -> f64 {
        self.n += 1;
        let mut y = x;
        for b in &mut self.blocks {
            y = b.step(y);
        }
        y
    }

    /// Run a block of samples (`out.len() == u.len()`).
    pub fn run(&mut self, u: &[f64], out: &mut [f64]) {
        for (o, &x) in out.iter_mut().zip(u) {
            *o = self.step(x);
        }
    }

    /// Full reset: rest state (in equilibrium with the next sample), time 0, noise
    /// streams from their seeds (a replay gives the same output).
    pub fn reset(&mut self) {
        self.n = 0;
        self.t0 = 0.0;
        self.blocks.iter_mut().for_each(Block::reset);
    }

    /// Back to rest (in equilibrium with the next sample) for a new record: absolute
    /// time and noise streams run on.
    pub fn reset_state(&mut self) {
        self.blocks.iter_mut().for_each(Block::reset_state);
    }
}
