//! Files of version 1, read and converted to a version-2 [`Chain`]:
//!
//! - a `preisach-model`: `{"format": "preisach-model", "version": 1, "n_h", "u_range",
//!   "offset", "output", "weights": [ragged upper rows], "report"?}`: one identified
//!   hysteresis block;
//! - a `preisach-chain` of version 1: `{"model": <a model>, "effects": [{"name",
//!   "params"}]}`, the effects in their fixed order (rate, creep, vibration, lowpass,
//!   delay, drift) whatever the list's order; parameters other than the pinned ones are
//!   ignored, as they were;
//! - a stage: `{"version": 1, "sample_rate_hz", "blocks"}` whose blocks name a mode's
//!   frequency `freq_hz`, creep's `gains` and `time_constants_s`, and an identified
//!   hysteresis by `lo`, `hi`, packed `weights` (row by row, `i <= j`) and
//!   `interpolated: bool` ([`upgrade_block`]).

use serde_json::{json, Map, Value};

use super::chain::{parse_blocks, BlockSpec, Chain};
use super::hysteresis::{HysteresisParams, IdentifiedHysteresis, Output};
use crate::error::{PreisachError, Result};

type Obj = Map<String, Value>;

/// The effects of a version-1 chain, in the order they are applied.
pub const EFFECTS: &[&str] = &["rate", "creep", "vibration", "lowpass", "delay", "drift"];

fn number(v: &Value) -> Option<f64> {
    v.as_f64()
}

/// A version-1 model file.
pub(super) fn model(obj: Obj) -> Result<Chain> {
    let (block, report) = model_block(&obj)?;
    Ok(Chain::new(vec![block])?.with_report(report))
}

/// The identified hysteresis block of a version-1 model (and its report).
fn model_block(obj: &Obj) -> Result<(BlockSpec, Option<Value>)> {
    let bad = |m: String| PreisachError::corrupt("model", m);
    if obj.get("format").and_then(Value::as_str) != Some("preisach-model") {
        return Err(bad(format!(
            "'format' must be 'preisach-model', got {}",
            obj.get("format").unwrap_or(&Value::Null)
        )));
    }
    if obj.get("version").and_then(Value::as_u64) != Some(1) {
        let v = obj.get("version").unwrap_or(&Value::Null);
        return Err(bad(format!("unsupported 'version' {v} (this build reads 1 and 2)")));
    }
    let n_h = match obj.get("n_h").and_then(Value::as_u64) {
        Some(n) if n >= 1 => n as usize,
        _ => return Err(bad(format!("'n_h' must be an integer >= 1, got {}", obj.get("n_h").unwrap_or(&Value::Null)))),
    };
    let rows = match obj.get("weights") {
        Some(Value::Array(r)) if r.len() == n_h => r,
        _ => return Err(bad(format!("'weights' must be a list of {n_h} rows"))),
    };
    let mut weights = vec![vec![0.0; n_h]; n_h];
    for (i, row) in rows.iter().enumerate() {
        let row = match row {
            Value::Array(r) if r.len() == n_h - i => r,
            _ => return Err(bad(format!("'weights' row {i} must hold {} values", n_h - i))),
        };
        for (j, v) in row.iter().enumerate() {
            weights[i][i + j] = number(v).ok_or_else(|| bad(format!("'weights' row {i} holds non-numbers")))?;
        }
    }
    let u_range = match obj.get("u_range") {
        Some(Value::Array(r)) if r.len() == 2 && r.iter().all(Value::is_number) => {
            [number(&r[0]).unwrap_or(f64::NAN), number(&r[1]).unwrap_or(f64::NAN)]
        }
        other => return Err(bad(format!("'u_range' must be a pair [lo, hi], got {}", other.unwrap_or(&Value::Null)))),
    };
    let offset = match obj.get("offset") {
        None => 0.0,
        Some(v) => number(v).ok_or_else(|| bad(format!("'offset' must be a number, got {v}")))?,
    };
    let output = match obj.get("output").map(|v| v.as_str()) {
        None | Some(Some("stepwise")) => Output::Stepwise,
        Some(Some("interpolated")) => Output::Interpolated,
        Some(_) => {
            return Err(bad(format!("'output' must be 'stepwise' or 'interpolated', got {}", obj["output"])));
        }
    };
    let p = HysteresisParams::Identified(IdentifiedHysteresis {
        u_range,
        n_h,
        weights,
        offset,
        output,
        initial_extrema: None,
    });
    // The values' own checks (masses >= 0, the range), named without a block index.
    p.core().map_err(|e| bad(e.to_string()))?;
    let report = obj.get("report").filter(|r| r.is_object()).cloned();
    Ok((BlockSpec::Hysteresis(p), report))
}

/// A version-1 chain file: a model and effects.
pub(super) fn chain(obj: Obj) -> Result<Chain> {
    let model = match obj.get("model") {
        Some(Value::Object(m)) => m,
        _ => return Err(PreisachError::corrupt("chain", "'model' must be a preisach-model object")),
    };
    let (hyst, _) = model_block(model).map_err(|e| match e {
        PreisachError::Corrupt { problem, .. } => PreisachError::corrupt("chain", format!("model: {problem}")),
        other => other,
    })?;
    let effects = obj.get("effects").cloned().unwrap_or(Value::Array(Vec::new()));
    let mut blocks = vec![hyst];
    blocks.extend(effect_blocks(&effects)?);
    Chain::new(blocks)
}

/// The blocks of version-1 effects (a list of `{"name", "params"}` or an object name →
/// params), in the fixed order.
pub fn effect_blocks(effects: &Value) -> Result<Vec<BlockSpec>> {
    let bad = |m: String| PreisachError::corrupt("chain", m);
    let mut named: Vec<(String, &Value)> = Vec::new();
    match effects {
        Value::Array(list) => {
            for e in list {
                let name = e.get("name").and_then(Value::as_str);
                match (name, e.get("params")) {
                    (Some(n), Some(p)) => named.push((n.to_string(), p)),
                    _ => return Err(bad(format!("an effect must be {{\"name\": ..., \"params\": {{...}}}}, got {e}"))),
                }
            }
        }
        Value::Object(m) => named.extend(m.iter().map(|(k, v)| (k.clone(), v))),
        other => return Err(bad(format!("'effects' must be a list of objects, got {other}"))),
    }
    for (i, (n, _)) in named.iter().enumerate() {
        if !EFFECTS.contains(&n.as_str()) {
            return Err(bad(format!("unknown effect '{n}' (known: {})", EFFECTS.join(", "))));
        }
        if named[..i].iter().any(|(m, _)| m == n) {
            return Err(bad(format!("effect '{n}' given twice")));
        }
    }
    let mut blocks = Vec::new();
    for name in EFFECTS {
        let Some((_, p)) = named.iter().find(|(n, _)| n == name) else { continue };
        let b = BlockSpec::from_value(effect_block(name, p)?).map_err(|e| match e {
            PreisachError::Corrupt { problem, .. } => bad(format!("effect '{name}': {problem}")),
            other => other,
        })?;
        blocks.push(b);
    }
    Ok(blocks)
}

/// One effect as a version-2 block (only the pinned parameters, as before).
fn effect_block(name: &str, p: &Value) -> Result<Value> {
    let Value::Object(p) = p else {
        return Err(PreisachError::corrupt("chain", format!("params of effect '{name}' must be an object")));
    };
    let keys: &[&str] = match name {
        "rate" => &["gain_s", "tau_s"],
        "creep" => &["taus_s", "amplitudes", "normalized"],
        "vibration" => &["frequency_hz", "damping", "modes"],
        "lowpass" => &["cutoff_hz", "order"],
        "delay" => &["delay_s"],
        _ => &["gain_per_s", "offset", "offset_per_s"],
    };
    let mut b: Obj = keys.iter().filter_map(|&k| p.get(k).map(|v| (k.to_string(), v.clone()))).collect();
    if name == "vibration" && !b.contains_key("modes") {
        let mode: Obj = b.clone();
        b = Map::new();
        b.insert("modes".into(), json!([mode]));
    }
    b.insert("type".into(), json!(name));
    Ok(Value::Object(b))
}

/// A version-1 stage file.
pub(super) fn stage(mut obj: Obj) -> Result<Chain> {
    let fs = obj.get("sample_rate_hz").and_then(Value::as_f64);
    let Some(Value::Array(blocks)) = obj.remove("blocks") else {
        return Err(PreisachError::corrupt("chain", "'blocks' must be a list of blocks"));
    };
    if let Some(k) = obj.keys().find(|k| !["version", "sample_rate_hz"].contains(&k.as_str())) {
        return Err(PreisachError::corrupt("chain", format!("unknown field '{k}' in a version-1 stage file")));
    }
    let fs = fs.ok_or_else(|| PreisachError::corrupt("chain", "'sample_rate_hz' must be a number"))?;
    stage_blocks(blocks)?.with_sample_rate(Some(fs))
}

/// A chain of stage blocks of either version (the blocks of a version-1 stage are
/// upgraded, see [`upgrade_block`]).
pub fn stage_blocks(blocks: Vec<Value>) -> Result<Chain> {
    Chain::new(parse_blocks(blocks, |v| BlockSpec::from_value(upgrade_block(v)?))?)
}

/// A block of a version-1 stage in its version-2 form; a version-2 block is returned
/// as it is.
pub fn upgrade_block(v: Value) -> Result<Value> {
    let Value::Object(mut b) = v else { return Ok(v) };
    let rename = |b: &mut Obj, from: &str, to: &str| {
        if let Some(x) = b.remove(from) {
            b.insert(to.to_string(), x);
        }
    };
    match b.get("type").and_then(Value::as_str) {
        Some("vibration") => {
            if let Some(Value::Array(modes)) = b.get_mut("modes") {
                for m in modes.iter_mut().filter_map(Value::as_object_mut) {
                    rename(m, "freq_hz", "frequency_hz");
                }
            }
        }
        Some("creep") => {
            rename(&mut b, "gains", "amplitudes");
            rename(&mut b, "time_constants_s", "taus_s");
        }
        Some("hysteresis") if b.contains_key("lo") || b.contains_key("hi") || b.contains_key("interpolated") => {
            upgrade_hysteresis(&mut b)?;
        }
        _ => {}
    }
    Ok(Value::Object(b))
}

fn upgrade_hysteresis(b: &mut Obj) -> Result<()> {
    let bad = |m: String| PreisachError::corrupt("chain", m);
    let lo = b.remove("lo").ok_or_else(|| bad("missing field `lo`".into()))?;
    let hi = b.remove("hi").ok_or_else(|| bad("missing field `hi`".into()))?;
    b.insert("u_range".into(), json!([lo, hi]));
    let interpolated = match b.remove("interpolated") {
        None => true,
        Some(Value::Bool(x)) => x,
        Some(other) => return Err(bad(format!("'interpolated' must be true or false, got {other}"))),
    };
    b.insert("output".into(), json!(if interpolated { "interpolated" } else { "stepwise" }));
    if b.get("source").and_then(Value::as_str) != Some("identified") {
        return Ok(());
    }
    let n_h = b.get("n_h").and_then(Value::as_u64).unwrap_or(0) as usize;
    let packed: Vec<Value> = match b.remove("weights") {
        Some(Value::Array(w)) if w.iter().all(Value::is_number) => w,
        Some(_) => return Err(bad("'weights' must be the packed list of masses".into())),
        None => return Err(bad("missing field `weights`".into())),
    };
    if packed.len() != n_h * (n_h + 1) / 2 {
        return Err(PreisachError::invalid(
            "weights",
            format!("expected {} packed masses for n_h = {n_h}, got {}", n_h * (n_h + 1) / 2, packed.len()),
        ));
    }
    let mut it = packed.into_iter();
    let rows: Vec<Value> = (0..n_h)
        .map(|i| {
            let mut row = vec![json!(0.0); i];
            row.extend(it.by_ref().take(n_h - i));
            Value::Array(row)
        })
        .collect();
    b.insert("weights".into(), Value::Array(rows));
    Ok(())
}
