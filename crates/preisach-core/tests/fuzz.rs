//! Property-based fuzzing of the core's entry points (proptest): chain JSON parsing,
//! presets, model constructors, identification, inversion and compiled chains, on
//! random and hostile inputs. Each call returns `Ok` or a `PreisachError` whose message
//! names the argument or the file; none panics (a panic fails the test). The number of
//! cases is proptest's `PROPTEST_CASES` (default 256 each here is too slow for CI, so
//! the config below sets a small budget; benches/fuzz_campaign.py runs the long one).

use std::sync::Arc;

use preisach_core::blocks::{self, Chain};
use preisach_core::identify::{fit, FitOptions, Solver, DEFAULT_DIAGONAL_FLOOR};
use preisach_core::invert::{invert, Inverter, InverterState, Method};
use preisach_core::{Grid, PreisachError, PreisachModel};
use proptest::prelude::*;
use serde_json::{json, Value};

/// Cases per property: `PROPTEST_CASES` if set, else a budget that keeps CI short.
fn config() -> ProptestConfig {
    let cases = std::env::var("PROPTEST_CASES").ok().and_then(|s| s.parse().ok()).unwrap_or(48);
    ProptestConfig { cases, failure_persistence: None, ..ProptestConfig::default() }
}

/// Values that break naive numerics.
fn hostile() -> impl Strategy<Value = f64> {
    prop_oneof![
        Just(f64::NAN),
        Just(f64::INFINITY),
        Just(f64::NEG_INFINITY),
        Just(f64::MAX),
        Just(f64::MIN),
        Just(1e300),
        Just(5e-324),
        Just(-5e-324),
        Just(f64::MIN_POSITIVE),
        Just(0.0),
        Just(-0.0),
        -1e6..1e6f64,
        any::<f64>(),
    ]
}

fn signal(max: usize) -> impl Strategy<Value = Vec<f64>> {
    prop_oneof![prop::collection::vec(-10.0..10.0f64, 0..max), prop::collection::vec(hostile(), 0..max)]
}

/// An error message names one of `names`.
fn names(e: &PreisachError, names: &[&str]) -> bool {
    let msg = e.to_string();
    names.iter().any(|n| msg.contains(n))
}

fn ok_or_named<T>(r: Result<T, PreisachError>, allowed: &[&str]) -> Result<Option<T>, TestCaseError> {
    match r {
        Ok(v) => Ok(Some(v)),
        Err(e) => {
            prop_assert!(names(&e, allowed), "error names none of {allowed:?}: {e}");
            Ok(None)
        }
    }
}

fn small_model(n_h: usize) -> Arc<PreisachModel> {
    let dense: Vec<f64> =
        (0..n_h * n_h).map(|k| if k / n_h <= k % n_h { 0.01 * (1 + k % 7) as f64 } else { 0.0 }).collect();
    Arc::new(PreisachModel::from_dense(0.0, 10.0, n_h, &dense, 0.5).unwrap())
}

/// A valid version-2 chain of every kind of block, to mutate.
fn every_block() -> Value {
    let model = small_model(3);
    let chain = Chain::new(vec![blocks::BlockSpec::Hysteresis(blocks::HysteresisParams::Identified(
        blocks::IdentifiedHysteresis::of_model(&model, blocks::Output::Interpolated),
    ))])
    .unwrap();
    let mut v: Value = serde_json::from_str(&chain.to_json()).unwrap();
    let preset = blocks::preset("paper", "{}").unwrap();
    let stage: Value = serde_json::from_str(&preset.to_json()).unwrap();
    let list = v["blocks"].as_array_mut().unwrap();
    list.extend(stage["blocks"].as_array().unwrap().iter().filter(|b| b["type"] != "hysteresis").cloned());
    list.push(json!({"type": "delay", "delay_s": 1e-3}));
    list.push(json!({"type": "drift", "gain_per_s": 1e-3, "offset": 0.1, "offset_per_s": 0.0}));
    v["sample_rate_hz"] = json!(1e4);
    v
}

fn wrong_value() -> impl Strategy<Value = Value> {
    prop_oneof![
        Just(Value::Null),
        Just(json!("text")),
        Just(json!(-1)),
        Just(json!(0)),
        Just(json!(1e308)),
        Just(json!(-1e308)),
        Just(json!(u64::MAX)),
        Just(json!(i64::MIN)),
        Just(json!([])),
        Just(json!({})),
        Just(json!(true)),
        Just(json!([1e300, 1e300])),
        Just(json!(1_000_000_000_000u64)),
        Just(json!(5e-324)),
    ]
}

/// Every path into the document (object keys, array indices).
fn paths(v: &Value, here: Vec<Value>, out: &mut Vec<Vec<Value>>) {
    match v {
        Value::Object(m) => {
            for (k, x) in m {
                let mut p = here.clone();
                p.push(json!(k));
                out.push(p.clone());
                paths(x, p, out);
            }
        }
        Value::Array(a) => {
            for (i, x) in a.iter().enumerate() {
                let mut p = here.clone();
                p.push(json!(i));
                out.push(p.clone());
                paths(x, p, out);
            }
        }
        _ => {}
    }
}

fn at<'a>(v: &'a mut Value, path: &[Value]) -> &'a mut Value {
    path.iter().fold(v, |v, k| match k {
        Value::String(s) => &mut v[s.as_str()],
        Value::Number(i) => &mut v[i.as_u64().unwrap() as usize],
        _ => unreachable!(),
    })
}

/// `doc` with the value at one path removed or replaced.
fn mutate(doc: &Value, pick: usize, remove: bool, with: Value) -> Value {
    let mut out = Vec::new();
    paths(doc, Vec::new(), &mut out);
    let mut v = doc.clone();
    let path = &out[pick % out.len()];
    let (last, parent) = path.split_last().unwrap();
    let parent = at(&mut v, parent);
    match (parent, last, remove) {
        (Value::Object(m), Value::String(k), true) => {
            m.remove(k);
        }
        (Value::Array(a), Value::Number(i), true) => {
            a.remove(i.as_u64().unwrap() as usize);
        }
        (p, _, _) => *at(p, std::slice::from_ref(last)) = with,
    }
    v
}

const CHAIN_NAMES: &[&str] = &["chain", "blocks", "sample_rate_hz", "initial_input", "n_h", "u_range"];

proptest! {
    #![proptest_config(config())]

    #[test]
    fn chain_json_with_a_field_removed_or_mistyped(pick in 0usize..10_000, remove in any::<bool>(),
                                                   with in wrong_value()) {
        let text = serde_json::to_string(&mutate(&every_block(), pick, remove, with)).unwrap();
        if let Some(c) = ok_or_named(Chain::from_json(&text), CHAIN_NAMES)? {
            // What loads compiles at its rate or says why, and writes back as JSON.
            let _ = serde_json::from_str::<Value>(&c.to_json()).unwrap();
            if let Some(mut rt) = ok_or_named(c.stage(), CHAIN_NAMES)? {
                let mut y = vec![0.0; 64];
                rt.run(&[1.0; 64], &mut y);
            }
            let t: Vec<f64> = (0..64).map(|k| k as f64 * 1e-3).collect();
            ok_or_named(c.predict(&t, &[1.0; 64], None), &["t", "u", "blocks"])?;
        }
    }

    #[test]
    fn chain_json_truncated_nested_or_garbage(cut in 0usize..4000, depth in 1usize..100_000,
                                              junk in prop::collection::vec(any::<u8>(), 0..64)) {
        let text = serde_json::to_string(&every_block()).unwrap();
        let cut = cut.min(text.len());
        let truncated = String::from_utf8_lossy(&text.as_bytes()[..cut]).into_owned();
        ok_or_named(Chain::from_json(&truncated), CHAIN_NAMES)?;
        let nested = format!("{}{}", "[".repeat(depth), "]".repeat(depth));
        ok_or_named(Chain::from_json(&nested), CHAIN_NAMES)?;
        let mut garbled = text.into_bytes();
        garbled.splice(cut.min(garbled.len())..cut.min(garbled.len()), junk);
        ok_or_named(Chain::from_json(&String::from_utf8_lossy(&garbled)), CHAIN_NAMES)?;
    }

    #[test]
    fn presets_with_hostile_overrides(key in prop::sample::select(vec![
        "delay", "seed", "noise_std", "n_h", "resonance_hz", "damping", "creep", "creep_per_decade", "lowpass_hz",
        "lowpass_order", "dac_bits", "adc_bits", "drift_gain_per_s", "drift_offset_per_s", "sample_rate_hz", "x"]),
                                      value in wrong_value()) {
        let over = json!({ key: value }).to_string();
        if let Some(c) = ok_or_named(blocks::preset("paper", &over), &[key, "preset", "overrides", "chain", "blocks"])? {
            ok_or_named(c.stage(), &[key, "blocks", "sample_rate_hz"])?;
        }
    }

    #[test]
    fn model_constructors(lo in hostile(), hi in hostile(), n_h in prop_oneof![0usize..20, Just(usize::MAX),
                                                                               Just(1usize << 40)],
                          offset in hostile(), w in hostile()) {
        ok_or_named(Grid::new(lo, hi, n_h), &["u_range", "n_h"])?;
        let n = n_h.min(20);
        let dense = vec![w; n * n];
        ok_or_named(PreisachModel::from_dense(lo, hi, n_h, &dense, offset), &["u_range", "n_h", "weights", "offset"])?;
    }

    #[test]
    fn identify(u in signal(300), y in signal(300), n_h in prop_oneof![0usize..30, Just(100_000usize)],
                lo in hostile(), hi in hostile(), reg in hostile(), interpolated in any::<bool>(),
                solver in prop::sample::select(vec![Solver::Auto, Solver::Active, Solver::Structured]),
                diagonal_floor in prop_oneof![Just(0.0), Just(DEFAULT_DIAGONAL_FLOOR), hostile()]) {
        let u_range = if lo.to_bits() % 3 == 0 { None } else { Some((lo, hi)) };
        let opts = FitOptions { n_h, u_range, reg, solver, interpolated, diagonal_floor };
        let named = ["u", "y", "n_h", "u_range", "reg", "diagonal_floor"];
        if let Some((m, rep)) = ok_or_named(fit(&u, &y, &opts), &named)? {
            prop_assert!(m.masses().iter().all(|w| w.is_finite() && *w >= 0.0));
            prop_assert!(rep.rmse.is_finite());
        }
    }

    #[test]
    fn invert_and_stream(r in signal(200), n_h in 1usize..12, look in prop_oneof![Just(None),
                                                                                   (0usize..50).prop_map(Some),
                                                                                   Just(Some(usize::MAX))],
                         method in prop::sample::select(vec![Method::Closest, Method::Interpolated,
                                                             Method::Continuous]),
                         memory in prop::collection::vec(hostile(), 0..6), r_prev in hostile()) {
        let m = small_model(n_h);
        if let Some((u, _)) = ok_or_named(invert(&m, &r, method, look), &["r", "lookahead", "method"])? {
            prop_assert!(u.iter().all(|x| x.is_finite()));
        }
        if let Some(mut inv) = ok_or_named(Inverter::new(m, method, look), &["lookahead", "method"])? {
            let mut out = vec![0.0; r.len()];
            ok_or_named(inv.process(&r, &mut out), &["r", "block"])?;
            let s = InverterState { memory, saturated: 0, t: 0, u_prev: 0.0, last_cm: 0.0, knots: vec![], r_prev };
            ok_or_named(inv.set_state(&s), &["state"])?;
            prop_assert!(inv.step(1.0).is_finite());
        }
    }

    #[test]
    fn records_on_hostile_time(t in signal(100), u in signal(100), x0 in prop::option::of(hostile())) {
        let chain = blocks::preset("paper", "{}").unwrap();
        ok_or_named(chain.predict(&t, &u, x0), &["t", "u", "initial_input"])?;
        ok_or_named(chain.simulate(&t, &u, x0), &["t", "u", "initial_input"])?;
        ok_or_named(blocks::sample_period(&t), &["t"])?;
    }
}

/// Regression: a reference far outside the reachable range rounded the closest match's
/// thresholds past the extreme level, which then indexed past the Everett table.
#[test]
fn closest_match_of_references_far_outside_the_range() {
    for n_h in [3usize, 12, 40] {
        let m = small_model(n_h);
        for e in 0..18 {
            for sign in [1.0, -1.0] {
                let r = [sign * 1.31076 * 10f64.powi(e), 0.0, -sign * 10f64.powi(e), 0.3];
                for method in [Method::Closest, Method::Interpolated, Method::Continuous] {
                    let (u, sat) = invert(&m, &r, method, None).unwrap();
                    assert!(u.iter().all(|x| (0.0..=10.0).contains(x)), "{method:?} {r:?}: {u:?}");
                    assert!(sat <= 4);
                }
            }
        }
    }
}

/// Regression: a version-2 chain without `version` indexed a missing key (a panic).
#[test]
fn a_chain_without_a_version_is_corrupt() {
    let e = Chain::from_json(r#"{"format": "preisach-chain", "blocks": []}"#).unwrap_err();
    assert!(matches!(e, PreisachError::Corrupt { .. }), "{e}");
    assert!(e.to_string().contains("unsupported version null"), "{e}");
}

/// Regression: masses whose sum overflows gave NaN outputs instead of an error.
#[test]
fn masses_that_overflow_are_refused() {
    let e = PreisachModel::from_dense(0.0, 1.0, 2, &[1e308, 1e308, 0.0, 1e308], 0.0).unwrap_err();
    assert!(e.to_string().starts_with("weights: the masses sum to"), "{e}");
    assert!(PreisachModel::from_dense(0.0, 1.0, 2, &[1e300, 1e300, 0.0, 1e300], 0.0).is_ok());
}
