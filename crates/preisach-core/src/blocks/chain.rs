//! A chain of blocks: the plant simulator, an identified model (a chain of one
//! hysteresis block), a model plus effects, or a diagnosis candidate. Blocks run in list
//! order. Serialized as JSON, version 2:
//!
//! ```json
//! {"format": "preisach-chain", "version": 2, "sample_rate_hz": 100000.0,
//!  "blocks": [
//!   {"type": "hysteresis", "source": "identified", "u_range": [0, 10], "n_h": 2,
//!    "weights": [[0.1, 0.2], [0.0, 0.3]], "offset": 0.1, "output": "interpolated"},
//!   {"type": "rate", "gain_s": 1e-4, "tau_s": 1e-3},
//!   {"type": "vibration", "modes": [{"frequency_hz": 780.0, "damping": 0.02}]}
//!  ]}
//! ```
//!
//! `sample_rate_hz` (the stage's own rate, for per-sample runs), `initial_input` and
//! `report` (a model's fit report, passed through) are optional. Files of version 1 (a
//! `preisach-model`, a `preisach-chain` of a model and effects, a stage) are read too and
//! converted. Errors name the block and the field
//! (`blocks[2] (vibration): modes[0].damping: must be > 0, got 0`).
//!
//! The description compiles to a [`Runtime`] for one sample rate and one [`Sampling`];
//! checks against that rate (a cutoff at or above Nyquist in a per-sample run) happen
//! then. [`Chain::predict`] and [`Chain::simulate`] run a record `(t, u)` at the rate of
//! its time column.

use std::sync::Arc;

use serde::{Deserialize, Serialize};
use serde_json::Value;

use super::amplifier::{Amplifier, AmplifierParams};
use super::creep::CreepParams;
use super::drift::DriftParams;
use super::hysteresis::{HysteresisCore, HysteresisParams};
use super::lti::{Lti, Sampling, Section, C};
use super::rate::RateParams;
use super::runtime::{sample_period, Runtime};
use super::sensor::{DelayParams, LowpassParams, NoiseParams, Quantizer, QuantizerParams, SensorParams};
use super::vibration::VibrationParams;
use super::{finite, positive, v1};
use crate::error::{check_signal, PreisachError, Result};

/// Version of the chain format written by this build.
pub const CHAIN_VERSION: u32 = 2;
/// The `format` field of a chain file.
pub const FORMAT: &str = "preisach-chain";

/// Block type names.
pub const BLOCK_TYPES: &[&str] = &[
    "amplifier",
    "hysteresis",
    "rate",
    "creep",
    "vibration",
    "lowpass",
    "delay",
    "sensor",
    "drift",
    "noise",
    "quantizer",
];

/// The parameters of one block, tagged by `"type"` (the JSON form).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "lowercase")]
pub enum BlockSpec {
    Amplifier(AmplifierParams),
    Hysteresis(HysteresisParams),
    Rate(RateParams),
    Creep(CreepParams),
    Vibration(VibrationParams),
    Lowpass(LowpassParams),
    Delay(DelayParams),
    Sensor(SensorParams),
    Drift(DriftParams),
    Noise(NoiseParams),
    Quantizer(QuantizerParams),
}

impl BlockSpec {
    /// The block's `"type"` name.
    pub fn kind(&self) -> &'static str {
        match self {
            BlockSpec::Amplifier(_) => "amplifier",
            BlockSpec::Hysteresis(_) => "hysteresis",
            BlockSpec::Rate(_) => "rate",
            BlockSpec::Creep(_) => "creep",
            BlockSpec::Vibration(_) => "vibration",
            BlockSpec::Lowpass(_) => "lowpass",
            BlockSpec::Delay(_) => "delay",
            BlockSpec::Sensor(_) => "sensor",
            BlockSpec::Drift(_) => "drift",
            BlockSpec::Noise(_) => "noise",
            BlockSpec::Quantizer(_) => "quantizer",
        }
    }

    /// Parse one block of a version-2 file; errors name the field (not yet the block).
    pub fn from_value(v: Value) -> Result<Self> {
        if let Some(t) = v.get("type").and_then(Value::as_str) {
            if !BLOCK_TYPES.contains(&t) {
                return Err(PreisachError::corrupt(
                    "chain",
                    format!("unknown block type '{t}' (known: {})", BLOCK_TYPES.join(", ")),
                ));
            }
        }
        serde_json::from_value(v).map_err(|e| PreisachError::corrupt("chain", e.to_string()))
    }

    /// The continuous description of a series block (creep, vibration, lowpass, delay,
    /// the sensor's gain, filter and delay); `None` for the others. Validates it.
    pub fn lti(&self) -> Option<Result<Lti>> {
        Some(match self {
            BlockSpec::Creep(p) => p.lti(),
            BlockSpec::Vibration(p) => p.lti(),
            BlockSpec::Lowpass(p) => p.lti(),
            BlockSpec::Delay(p) => p.lti(),
            BlockSpec::Sensor(p) => {
                p.check().and_then(|_| Ok(Lti::series(vec![Section::gain(p.gain)?]).then(p.lti()?)))
            }
            _ => return None,
        })
    }

    /// Everything that does not depend on the sample rate.
    fn check(&self) -> Result<()> {
        match self {
            BlockSpec::Amplifier(p) => Amplifier::new(p, 1.0).map(|_| ()),
            BlockSpec::Hysteresis(_) => Ok(()), // built once by the chain
            BlockSpec::Rate(p) => p.lti().map(|_| ()),
            BlockSpec::Drift(p) => p.check(),
            BlockSpec::Noise(p) => p.check(),
            BlockSpec::Quantizer(p) => Quantizer::new(p).map(|_| ()),
            other => other.lti().map_or(Ok(()), |r| r.map(|_| ())),
        }
    }
}

/// An error of block `k`, named by it.
fn in_block(k: usize, kind: &str, e: PreisachError) -> PreisachError {
    match e {
        PreisachError::Invalid { name, problem } => {
            PreisachError::Invalid { name: format!("blocks[{k}] ({kind}): {name}"), problem }
        }
        PreisachError::Corrupt { what, problem } => {
            PreisachError::Corrupt { what, problem: format!("blocks[{k}] ({kind}): {problem}") }
        }
        other => other,
    }
}

/// A validated chain description; see the module doc.
#[derive(Debug, Clone)]
pub struct Chain {
    blocks: Vec<BlockSpec>,
    /// Per block: the built model of a hysteresis block (shared by every run).
    cores: Vec<Option<Arc<HysteresisCore>>>,
    sample_rate_hz: Option<f64>,
    initial_input: Option<f64>,
    report: Option<Value>,
}

/// The file form (version 2).
#[derive(Serialize)]
struct ChainFile<'a> {
    format: &'static str,
    version: u32,
    #[serde(skip_serializing_if = "Option::is_none")]
    sample_rate_hz: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    initial_input: Option<f64>,
    blocks: &'a [BlockSpec],
    #[serde(skip_serializing_if = "Option::is_none")]
    report: Option<&'a Value>,
}

/// Top-level fields of a version-2 file.
const FIELDS: &[&str] = &["format", "version", "sample_rate_hz", "initial_input", "blocks", "report"];

impl Chain {
    /// Validate the blocks (everything that does not depend on a sample rate). Errors
    /// name the block (`blocks[2] (vibration): modes[0].damping: must be > 0, got 0`).
    pub fn new(blocks: Vec<BlockSpec>) -> Result<Self> {
        let mut cores = Vec::with_capacity(blocks.len());
        let mut hysteresis_seen = false;
        for (k, b) in blocks.iter().enumerate() {
            let named = |e| in_block(k, b.kind(), e);
            b.check().map_err(named)?;
            match b {
                BlockSpec::Hysteresis(p) => {
                    cores.push(Some(Arc::new(p.core().map_err(named)?)));
                    hysteresis_seen = true;
                }
                BlockSpec::Rate(_) if !hysteresis_seen => {
                    return Err(PreisachError::invalid(
                        format!("blocks[{k}] (rate)"),
                        "needs a hysteresis block before it (the rate term acts on the hysteresis input)",
                    ))
                }
                _ => cores.push(None),
            }
        }
        Ok(Chain { blocks, cores, sample_rate_hz: None, initial_input: None, report: None })
    }

    /// The stage's own sample rate (for per-sample runs), Hz.
    pub fn with_sample_rate(mut self, fs: Option<f64>) -> Result<Self> {
        if let Some(f) = fs {
            positive("sample_rate_hz", f)?;
        }
        self.sample_rate_hz = fs;
        Ok(self)
    }

    /// The input the stage rested at before a record (default: the record's first input).
    pub fn with_initial_input(mut self, x: Option<f64>) -> Result<Self> {
        if let Some(v) = x {
            finite("initial_input", v)?;
        }
        self.initial_input = x;
        Ok(self)
    }

    /// A fit report or any JSON, written with the chain.
    pub fn with_report(mut self, report: Option<Value>) -> Self {
        self.report = report;
        self
    }

    pub fn blocks(&self) -> &[BlockSpec] {
        &self.blocks
    }
    pub fn sample_rate_hz(&self) -> Option<f64> {
        self.sample_rate_hz
    }
    pub fn initial_input(&self) -> Option<f64> {
        self.initial_input
    }
    pub fn report(&self) -> Option<&Value> {
        self.report.as_ref()
    }

    /// The built model of hysteresis block `k`.
    pub fn hysteresis(&self, k: usize) -> Option<&HysteresisCore> {
        self.cores.get(k).and_then(|c| c.as_deref())
    }

    /// Parse any chain, model or stage file (version 1 or 2). Malformed JSON, an unknown
    /// field or block is `Corrupt`; a bad value `Invalid`, naming the block and field.
    pub fn from_json(text: &str) -> Result<Self> {
        let v: Value = serde_json::from_str(text).map_err(|e| PreisachError::corrupt("chain", e.to_string()))?;
        Chain::from_value(v)
    }

    /// [`Chain::from_json`] on parsed JSON.
    pub fn from_value(v: Value) -> Result<Self> {
        let Value::Object(mut obj) = v else {
            return Err(PreisachError::corrupt("chain", "expected a JSON object"));
        };
        match obj.get("format").and_then(Value::as_str) {
            Some("preisach-model") => return v1::model(obj),
            Some(FORMAT) => {}
            Some(other) => {
                return Err(PreisachError::corrupt(
                    "chain",
                    format!("'format' must be '{FORMAT}' or 'preisach-model', got '{other}'"),
                ))
            }
            None if obj.contains_key("format") => {
                return Err(PreisachError::corrupt("chain", "'format' must be a string"));
            }
            None if obj.get("version").and_then(Value::as_u64) == Some(1) => return v1::stage(obj),
            None => {
                return Err(PreisachError::corrupt(
                    "chain",
                    "missing 'format' (a version-2 chain, a preisach-model or a version-1 stage file expected)",
                ))
            }
        }
        match obj.get("version").and_then(Value::as_u64) {
            Some(1) => return v1::chain(obj),
            Some(2) => {}
            _ => {
                return Err(PreisachError::corrupt(
                    "chain",
                    format!(
                        "unsupported version {}, this build reads versions 1 and 2",
                        obj.get("version").unwrap_or(&Value::Null)
                    ),
                ))
            }
        }
        if let Some(k) = obj.keys().find(|k| !FIELDS.contains(&k.as_str())) {
            return Err(PreisachError::corrupt("chain", format!("unknown field '{k}' (known: {})", FIELDS.join(", "))));
        }
        let number = |obj: &serde_json::Map<String, Value>, k: &str| -> Result<Option<f64>> {
            match obj.get(k) {
                None | Some(Value::Null) => Ok(None),
                Some(x) => x
                    .as_f64()
                    .map(Some)
                    .ok_or_else(|| PreisachError::corrupt("chain", format!("'{k}' must be a number, got {x}"))),
            }
        };
        let fs = number(&obj, "sample_rate_hz")?;
        let x0 = number(&obj, "initial_input")?;
        let Some(Value::Array(blocks)) = obj.remove("blocks") else {
            return Err(PreisachError::corrupt("chain", "'blocks' must be a list of blocks"));
        };
        let report = obj.remove("report").filter(|r| !r.is_null());
        let specs = parse_blocks(blocks, BlockSpec::from_value)?;
        Ok(Chain::new(specs)?.with_sample_rate(fs)?.with_initial_input(x0)?.with_report(report))
    }

    /// The version-2 JSON text: one block per line.
    pub fn to_json(&self) -> String {
        // Plain data with finite numbers: serializing cannot fail.
        let block = |b: &BlockSpec| serde_json::to_string(b).expect("a block serializes");
        let head = ChainFile {
            format: FORMAT,
            version: CHAIN_VERSION,
            sample_rate_hz: self.sample_rate_hz,
            initial_input: self.initial_input,
            blocks: &[],
            report: self.report.as_ref(),
        };
        let head = serde_json::to_string(&head).expect("a chain serializes");
        let lines: Vec<String> = self.blocks.iter().map(|b| format!("  {}", block(b))).collect();
        let blocks = if lines.is_empty() { "[]".to_string() } else { format!("[\n{}\n]", lines.join(",\n")) };
        head.replacen("\"blocks\":[]", &format!("\"blocks\":{blocks}"), 1)
    }

    /// Compile for `sample_rate_hz`: every block sampled by `sampling` and checked
    /// against that rate; `deterministic` leaves noise and quantizers out.
    pub fn compile(&self, sample_rate_hz: f64, sampling: Sampling, deterministic: bool) -> Result<Runtime> {
        positive("sample_rate_hz", sample_rate_hz)?;
        let mut blocks = Vec::with_capacity(self.blocks.len());
        for (k, (b, core)) in self.blocks.iter().zip(&self.cores).enumerate() {
            blocks.push(
                b.build(sample_rate_hz, sampling, deterministic, core.as_ref())
                    .map_err(|e| in_block(k, b.kind(), e))?,
            );
        }
        Ok(Runtime::new(blocks, sample_rate_hz, self.initial_input))
    }

    /// The stage at its own rate, per sample, with noise and quantization.
    pub fn stage(&self) -> Result<Runtime> {
        let fs = self.sample_rate_hz.ok_or_else(|| {
            PreisachError::invalid(
                "sample_rate_hz",
                "the chain has none: give the stage's rate, or run a record with predict/simulate(t, u)",
            )
        })?;
        self.compile(fs, Sampling::Zoh, false)
    }

    /// The deterministic output for the record `(t, u)` (noise and quantizers off; the
    /// linear blocks by the first-order hold, exact for an input linear between samples)
    /// at the rate of `t`. `initial_input` overrides the chain's own.
    pub fn predict(&self, t: &[f64], u: &[f64], initial_input: Option<f64>) -> Result<Vec<f64>> {
        self.run_record(t, u, initial_input, Sampling::Foh, true)
    }

    /// The simulated measurement for the record `(t, u)`: per sample (zero-order hold),
    /// with noise and quantization, at the rate of `t`.
    pub fn simulate(&self, t: &[f64], u: &[f64], initial_input: Option<f64>) -> Result<Vec<f64>> {
        self.run_record(t, u, initial_input, Sampling::Zoh, false)
    }

    fn run_record(
        &self,
        t: &[f64],
        u: &[f64],
        initial_input: Option<f64>,
        sampling: Sampling,
        deterministic: bool,
    ) -> Result<Vec<f64>> {
        check_signal("u", u)?;
        if t.len() != u.len() {
            return Err(PreisachError::invalid(
                "t",
                format!("length {} does not match u (length {})", t.len(), u.len()),
            ));
        }
        let fs = match (t.len(), sampling) {
            (1, Sampling::Foh) => 1.0, // at rest: the output does not depend on the rate
            _ => 1.0 / sample_period(t)?,
        };
        let mut rt = self.compile(fs, sampling, deterministic)?;
        if initial_input.is_some() {
            rt.set_initial_input(initial_input)?;
        }
        Ok(t.iter().zip(u).map(|(&tk, &x)| rt.step_at(tk, x)).collect())
    }

    /// The series blocks' continuous descriptions (creep, vibration, lowpass, delay,
    /// sensor); any other block is an error naming it.
    pub fn ltis(&self) -> Result<Vec<Lti>> {
        self.blocks
            .iter()
            .enumerate()
            .map(|(k, b)| {
                b.lti().unwrap_or_else(|| {
                    Err(PreisachError::invalid(
                        format!("blocks[{k}] ({})", b.kind()),
                        "not a linear block in series (expected creep, vibration, lowpass, delay or sensor)",
                    ))
                })
            })
            .collect()
    }

    /// The frequency response of the chain's series blocks at `f_hz` (all blocks must be
    /// series linear ones, see [`Chain::ltis`]).
    pub fn response(&self, f_hz: &[f64]) -> Result<Vec<C>> {
        let ltis = self.ltis()?;
        Ok(f_hz.iter().map(|&f| ltis.iter().fold(C::new(1.0, 0.0), |h, l| h * l.response(f))).collect())
    }
}

/// Parse a list of blocks with `parse`, naming the block in errors.
pub(super) fn parse_blocks(blocks: Vec<Value>, parse: impl Fn(Value) -> Result<BlockSpec>) -> Result<Vec<BlockSpec>> {
    blocks
        .into_iter()
        .enumerate()
        .map(|(k, v)| {
            let kind = v.get("type").and_then(Value::as_str).unwrap_or("?").to_string();
            parse(v).map_err(|e| in_block(k, &kind, e))
        })
        .collect()
}

impl PartialEq for Chain {
    fn eq(&self, other: &Self) -> bool {
        self.blocks == other.blocks
            && self.sample_rate_hz == other.sample_rate_hz
            && self.initial_input == other.initial_input
            && self.report == other.report
    }
}

impl Serialize for Chain {
    fn serialize<S: serde::Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        let v: Value = serde_json::from_str(&self.to_json()).map_err(serde::ser::Error::custom)?;
        v.serialize(s)
    }
}

impl<'de> Deserialize<'de> for Chain {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        Chain::from_value(Value::deserialize(d)?).map_err(serde::de::Error::custom)
    }
}
