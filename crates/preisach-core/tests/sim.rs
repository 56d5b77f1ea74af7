//! Blocks and chains: each block against an analytic formula, the samplings'
//! conventions, the chain's JSON (version 2, and version-1 files converted), initial
//! conditions, every bad parameter rejected by name, and the sample loop.
//!
//! Blocks start in equilibrium with their first sample, so the analytic step
//! responses feed one sample of 0 (rest at 0) and step to 1 from the second sample.

use std::f64::consts::{PI, TAU};

use preisach_core::blocks::lti::C;
use preisach_core::blocks::*;
use preisach_core::sim::{run_loop, Identity, LinearGain, Timing};
use preisach_core::{PreisachError, PreisachModel};

const FS: f64 = 100_000.0;

fn err_name(e: PreisachError) -> String {
    match e {
        PreisachError::Invalid { name, .. } => name,
        other => panic!("expected Invalid, got {other:?}"),
    }
}

/// A chain of `blocks` run per sample at `fs` (with noise and quantization).
fn stage_at(fs: f64, blocks: Vec<BlockSpec>) -> Runtime {
    Chain::new(blocks).unwrap().compile(fs, Sampling::Zoh, false).unwrap()
}

fn stage(block: BlockSpec) -> Runtime {
    stage_at(FS, vec![block])
}

/// Amplitude of the component at `f` in `x` (least-squares projection on sin/cos over
/// a whole number of periods).
fn amplitude_at(x: &[f64], f: f64, fs: f64) -> f64 {
    let (mut s, mut c) = (0.0, 0.0);
    for (k, v) in x.iter().enumerate() {
        let ph = TAU * f * k as f64 / fs;
        s += v * ph.sin();
        c += v * ph.cos();
    }
    2.0 * (s * s + c * c).sqrt() / x.len() as f64
}

fn mode(f: f64, z: f64) -> Mode {
    Mode { frequency_hz: f, damping: z }
}

fn vibration(modes: Vec<Mode>) -> BlockSpec {
    BlockSpec::Vibration(VibrationParams { modes })
}

fn lowpass(cutoff_hz: f64, order: usize) -> BlockSpec {
    BlockSpec::Lowpass(LowpassParams { cutoff_hz, order })
}

fn creep(taus_s: Vec<f64>, amplitudes: Vec<f64>) -> BlockSpec {
    BlockSpec::Creep(CreepParams { taus_s, amplitudes, normalized: false })
}

// ------------------------------------------------------------------ the description

#[test]
fn sections_check_poles_and_merge_equal_ones() {
    let s = Section::new(1.0, [(C::new(-2.0, 0.0), C::new(1.0, 0.0)), (C::new(-2.0, 0.0), C::new(0.5, 0.0))]).unwrap();
    assert_eq!(s.poles().len(), 1);
    assert_eq!(s.residues()[0], C::new(1.5, 0.0));
    // A pole below the real axis stands for its conjugate: the same section.
    let a = Section::new(0.0, [(C::new(-1.0, 3.0), C::new(0.2, -0.4))]).unwrap();
    let b = Section::new(0.0, [(C::new(-1.0, -3.0), C::new(0.2, 0.4))]).unwrap();
    assert_eq!(a, b);
    assert!((a.at(C::new(0.0, 0.7)) - b.at(C::new(0.0, 0.7))).norm() < 1e-15);
    for bad in [
        (C::new(0.0, 1.0), C::new(1.0, 0.0)),      // not stable
        (C::new(-1.0, 0.0), C::new(1.0, 1.0)),     // complex residue of a real pole
        (C::new(f64::NAN, 0.0), C::new(1.0, 0.0)), // not finite
    ] {
        assert!(Section::new(0.0, [bad]).is_err(), "{bad:?}");
    }
}

#[test]
fn mode_response_is_the_second_order_transfer_function() {
    for (f, z) in [(780.0, 0.02), (1500.0, 0.7), (300.0, 1.0), (300.0, 2.5)] {
        let l = VibrationParams { modes: vec![mode(f, z)] }.lti().unwrap();
        let w = TAU * f;
        for fq in [0.0, 10.0, f, 3.0 * f] {
            let s = C::new(0.0, TAU * fq);
            let want = w * w / (s * s + 2.0 * z * w * s + w * w);
            assert!((l.response(fq) - want).norm() < 1e-12, "f={f} z={z} at {fq}");
        }
        assert!((l.dc_gain() - 1.0).abs() < 1e-12);
    }
}

// ------------------------------------------------------------------ vibration

#[test]
fn zoh_mode_matches_the_analytic_step_response() {
    for &(f, z) in &[(780.0, 0.02), (780.0, 0.3), (5000.0, 0.05)] {
        let mut v = stage(vibration(vec![mode(f, z)]));
        assert_eq!(v.step(0.0), 0.0, "at rest at 0");
        let w = TAU * f;
        let wd = w * (1.0 - z * z).sqrt();
        for n in 0..5000 {
            let y = v.step(1.0);
            // Output after sample n is the position at the end of the hold interval.
            let t = (n + 1) as f64 / FS;
            let exact = 1.0 - (-z * w * t).exp() * ((wd * t).cos() + z / (1.0 - z * z).sqrt() * (wd * t).sin());
            assert!((y - exact).abs() < 1e-9, "f={f} z={z} n={n}: {y} vs {exact}");
        }
    }
}

#[test]
fn foh_mode_is_exact_for_a_ramp() {
    // A record run is exact for an input linear between samples: a step spread over the
    // first interval (0 at the sample before, 1 at the first) is a ramp, whose response is
    // the integral of the step response.
    let (f, z) = (780.0, 0.05);
    let chain = Chain::new(vec![vibration(vec![mode(f, z)])]).unwrap().with_initial_input(Some(0.0)).unwrap();
    let fs = 20e3;
    let t: Vec<f64> = (0..2000).map(|k| k as f64 / fs).collect();
    let y = chain.predict(&t, &vec![1.0; t.len()], None).unwrap();
    let (w, wd) = (TAU * f, TAU * f * (1.0 - z * z).sqrt());
    // Step response s(t) and its integral S(t); the ramp over [−T, 0] gives (S(t + T) − S(t)) / T.
    let big_s = |t: f64| {
        let a = z * w;
        let e = (-a * t).exp();
        let ic = (e * (-a * (wd * t).cos() + wd * (wd * t).sin()) + a) / (a * a + wd * wd);
        let is = (e * (-a * (wd * t).sin() - wd * (wd * t).cos()) + wd) / (a * a + wd * wd);
        t - ic - z / (1.0 - z * z).sqrt() * is
    };
    let dt = 1.0 / fs;
    for (k, &v) in y.iter().enumerate() {
        let exact = (big_s(t[k] + dt) - big_s(t[k])) / dt;
        assert!((v - exact).abs() < 1e-9, "k={k}: {v} vs {exact}");
    }
}

#[test]
fn modes_in_series_keep_unit_dc_gain() {
    let mut v = stage(vibration(vec![mode(780.0, 0.2), mode(2300.0, 0.1)]));
    let mut y = v.step(0.0); // at rest at 0, then a step
    for _ in 0..100_000 {
        y = v.step(2.5);
    }
    assert!((y - 2.5).abs() < 1e-9);
}

// ------------------------------------------------------------------ low-pass

#[test]
fn butterworth_dc_gain_one_and_minus_3_db_at_cutoff() {
    for order in 1..=4 {
        for &fc in &[500.0, 10_000.0, 30_000.0] {
            let mut lp = stage(lowpass(fc, order));
            let mut y = lp.step(0.0); // at rest at 0, then a unit step
            assert_eq!(y, 0.0);
            for _ in 0..20_000 {
                y = lp.step(1.0);
            }
            assert!((y - 1.0).abs() < 1e-9, "order {order} fc {fc}: DC {y}");

            lp.reset();
            // Whole number of periods: fc/FS·n integer for n = 100_000 (fc integer Hz).
            let n = 100_000;
            let x: Vec<f64> = (0..2 * n).map(|k| (TAU * fc * k as f64 / FS).sin()).collect();
            let y: Vec<f64> = x.iter().map(|&v| lp.step(v)).collect();
            let a = amplitude_at(&y[n..], fc, FS);
            assert!((a - 0.5f64.sqrt()).abs() < 1e-6, "order {order} fc {fc}: |H(fc)| = {a}");
        }
    }
}

#[test]
fn butterworth_rolls_off_at_the_order_rate() {
    // |H(f)| of a Butterworth = 1/sqrt(1 + (f/fc)^(2N)) in the prewarped frequency.
    let fc = 200.0;
    let f = 2000.0;
    for order in 1..=4 {
        let mut lp = stage(lowpass(fc, order));
        let n = 100_000;
        let y: Vec<f64> = (0..2 * n).map(|k| lp.step((TAU * f * k as f64 / FS).sin())).collect();
        let a = amplitude_at(&y[n..], f, FS);
        let ratio = (PI * f / FS).tan() / (PI * fc / FS).tan();
        let exact = 1.0 / (1.0 + ratio.powi(2 * order as i32)).sqrt();
        assert!((a / exact - 1.0).abs() < 1e-4, "order {order}: {a} vs {exact}");
    }
}

// ------------------------------------------------------------------ delay

#[test]
fn delay_is_exact_on_integer_samples() {
    let x: Vec<f64> = (0..500).map(|k| ((k * 7919) % 101) as f64 - 50.0).collect();
    for d in [0usize, 1, 3, 46, 100] {
        let mut del = stage(BlockSpec::Delay(DelayParams { delay_s: d as f64 / FS }));
        for (k, &v) in x.iter().enumerate() {
            let y = del.step(v);
            // At rest before the first sample: the line holds x[0].
            let exact = if k >= d { x[k - d] } else { x[0] };
            assert_eq!(y, exact, "d={d} k={k}");
        }
    }
}

#[test]
fn fractional_delay_is_exact_on_a_ramp() {
    for d in [0.25, 1.5, 45.8, 7.001] {
        let mut del = stage(BlockSpec::Delay(DelayParams { delay_s: d / FS }));
        for k in 0..300 {
            let y = del.step(k as f64 * 0.1);
            if k as f64 >= d + 1.0 {
                let exact = (k as f64 - d) * 0.1;
                assert!((y - exact).abs() < 1e-9, "d={d} k={k}: {y} vs {exact}");
            }
        }
    }
    assert!((lti::DelayLine::new(4.58e-4, FS).unwrap().samples() - 45.8).abs() < 1e-9);
}

// ------------------------------------------------------------------ creep

#[test]
fn creep_follows_the_kelvin_voigt_step_response_and_dc_gain() {
    let mut c = stage(creep(vec![0.01, 0.1], vec![0.02, 0.05]));
    let mut y = c.step(0.0); // at rest at 0, then a unit step
    assert_eq!(y, 0.0);
    for n in 0..200_000 {
        y = c.step(1.0);
        if n % 997 == 0 {
            let t = (n + 1) as f64 / FS;
            let exact = 1.0 + 0.02 * (1.0 - (-t / 0.01).exp()) + 0.05 * (1.0 - (-t / 0.1).exp());
            assert!((y - exact).abs() < 1e-9, "n={n}: {y} vs {exact}");
        }
    }
    assert!((y - 1.07).abs() < 1e-9);
    let p = CreepParams { taus_s: vec![0.01, 0.1], amplitudes: vec![0.02, 0.05], normalized: false };
    assert!((p.lti().unwrap().dc_gain() - 1.07).abs() < 1e-12);
    let n = CreepParams { normalized: true, ..p };
    assert!((n.lti().unwrap().dc_gain() - 1.0).abs() < 1e-12);
}

#[test]
fn creep_log_law_grows_about_gamma_per_decade() {
    let mut c = stage_at(1000.0, vec![BlockSpec::Creep(CreepParams::log_law(0.01, 0.01, 100.0))]);
    c.step(0.0); // at rest at 0, then a unit step
    let y: Vec<f64> = (0..100_000).map(|_| c.step(1.0)).collect(); // 100 s at 1 kHz
                                                                   // Between 0.1 s and 10 s (inside the τ span) the growth is ~2 decades · 1 %.
    let g = y[9_999] - y[99];
    assert!((g - 0.02).abs() < 0.004, "growth over two decades {g}");
}

// ------------------------------------------------------------------ rate

#[test]
fn rate_branch_adds_the_filtered_velocity_of_the_hysteresis_input() {
    // A ramp of slope a from rest into `gain s/(1 + s tau)`: gain a (1 − e^{−t/tau})
    // behind a hysteresis block without mass (output 0).
    let model = PreisachModel::from_dense(-10.0, 10.0, 1, &[0.0], 0.0).unwrap();
    let h = IdentifiedHysteresis::of_model(&model, Output::Interpolated);
    let (gain, tau, a, fs) = (2e-3, 4e-3, 3.0, 10e3);
    let chain = Chain::new(vec![
        BlockSpec::Hysteresis(HysteresisParams::Identified(h)),
        BlockSpec::Rate(RateParams { gain_s: gain, tau_s: tau }),
    ])
    .unwrap();
    let t: Vec<f64> = (0..400).map(|k| k as f64 / fs).collect();
    let u: Vec<f64> = t.iter().map(|&tk| a * tk).collect();
    let y = chain.predict(&t, &u, None).unwrap();
    for (k, &v) in y.iter().enumerate() {
        let exact = gain * a * (1.0 - (-t[k] / tau).exp());
        assert!((v - exact).abs() < 1e-12, "k={k}: {v} vs {exact}");
    }
    // A rate needs a hysteresis block before it.
    let e = Chain::new(vec![BlockSpec::Rate(RateParams { gain_s: gain, tau_s: tau })]).unwrap_err();
    assert_eq!(err_name(e), "blocks[0] (rate)");
}

// ------------------------------------------------------------------ drift

#[test]
fn drift_follows_its_formula_in_absolute_time() {
    let p = DriftParams { gain_per_s: 1e-3, offset: 0.5, offset_per_s: -2e-3 };
    let mut chain = stage(BlockSpec::Drift(p.clone()));
    let x = |k: usize| (k as f64 * 0.01).sin();
    for k in 0..1000 {
        let t = k as f64 / FS;
        let y = chain.step(x(k));
        let exact = (1.0 + 1e-3 * t) * x(k) + 0.5 - 2e-3 * t;
        assert!((y - exact).abs() < 1e-12);
    }
    // A new record keeps absolute time; a full reset returns to t = 0.
    chain.reset_state();
    let t = 1000.0 / FS;
    assert!((chain.step(1.0) - ((1.0 + 1e-3 * t) + 0.5 - 2e-3 * t)).abs() < 1e-12);
    chain.set_time(3600.0).unwrap();
    assert!((chain.step(2.0) - ((1.0 + 3.6) * 2.0 + 0.5 - 7.2)).abs() < 1e-9);
    chain.reset();
    assert!((chain.step(1.0) - 1.5).abs() < 1e-12);
    // On a record, drift runs on the record's own time column.
    let c = Chain::new(vec![BlockSpec::Drift(p)]).unwrap();
    let y = c.predict(&[100.0, 100.5, 101.0], &[1.0, 1.0, 1.0], None).unwrap();
    assert!((y[2] - ((1.0 + 0.101) + 0.5 - 0.202)).abs() < 1e-12);
}

// ------------------------------------------------------------------ amplifier, quantizer, noise

#[test]
fn amplifier_gain_saturation_and_slew() {
    let p = AmplifierParams { gain: 20.0, saturation: Some([-30.0, 150.0]), slew_v_per_s: Some(1e6) };
    let mut a = Amplifier::new(&p, FS).unwrap();
    assert_eq!(a.step(0.0), 0.0); // at rest at 0, then a step: 1e6 V/s at 100 kHz = 10 V per sample
    let ys: Vec<f64> = (0..20).map(|_| a.step(10.0)).collect();
    for (k, y) in ys.iter().enumerate() {
        assert_eq!(*y, (10.0 * (k + 1) as f64).min(150.0));
    }
    let mut a = Amplifier::new(&AmplifierParams::default(), FS).unwrap();
    assert_eq!(a.step(0.37), 20.0 * 0.37);
    // The slew limiter starts at the first (saturated) value: no ramp up from 0 V.
    let mut a = Amplifier::new(&p, FS).unwrap();
    assert_eq!(a.step(10.0), 150.0);
    assert_eq!(a.step(10.0), 150.0);
    a.reset();
    assert_eq!(a.step(2.0), 40.0);
    assert_eq!(a.step(-10.0), 30.0);
}

#[test]
fn quantizer_rounds_to_codes_and_clips() {
    let q = Quantizer::new(&QuantizerParams { bits: 3, range: [0.0, 7.0] }).unwrap();
    assert_eq!(q.lsb(), 1.0);
    assert_eq!(q.step(2.49), 2.0);
    assert_eq!(q.step(2.51), 3.0);
    assert_eq!(q.step(-5.0), 0.0);
    assert_eq!(q.step(9.0), 7.0);
    let q16 = Quantizer::new(&QuantizerParams { bits: 16, range: [-10.0, 10.0] }).unwrap();
    for k in 0..1000 {
        let x = -9.9 + k as f64 * 0.0199;
        assert!((q16.step(x) - x).abs() <= 0.5 * 20.0 / 65535.0 + 1e-12);
    }
}

#[test]
fn noise_is_white_gaussian_with_its_std() {
    let mut n = Noise::new(&NoiseParams { std: 0.3, seed: 11 }).unwrap();
    let x: Vec<f64> = (0..200_000).map(|_| n.step(1.0) - 1.0).collect();
    let mean = x.iter().sum::<f64>() / x.len() as f64;
    let var = x.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / x.len() as f64;
    let lag1 = x.windows(2).map(|w| w[0] * w[1]).sum::<f64>() / x.len() as f64 / var;
    assert!(mean.abs() < 0.005, "mean {mean}");
    assert!((var.sqrt() - 0.3).abs() < 0.003, "std {}", var.sqrt());
    assert!(lag1.abs() < 0.01, "lag-1 correlation {lag1}");
}

#[test]
fn predictions_leave_noise_and_quantizers_out() {
    let blocks = vec![
        BlockSpec::Quantizer(QuantizerParams { bits: 4, range: [0.0, 1.0] }),
        BlockSpec::Noise(NoiseParams { std: 0.1, seed: 1 }),
        BlockSpec::Sensor(SensorParams {
            noise_std: 0.1,
            adc: Some(QuantizerParams { bits: 4, range: [0.0, 1.0] }),
            ..SensorParams::default()
        }),
    ];
    let c = Chain::new(blocks).unwrap();
    let t: Vec<f64> = (0..50).map(|k| k as f64 * 1e-3).collect();
    let u: Vec<f64> = (0..50).map(|k| 0.3 + 0.01 * k as f64).collect();
    let y = c.predict(&t, &u, None).unwrap();
    for (a, b) in y.iter().zip(&u) {
        assert!((a - 0.2 * b).abs() < 1e-15);
    }
    let s = c.simulate(&t, &u, None).unwrap();
    assert!(s.iter().zip(&y).any(|(a, b)| (a - b).abs() > 1e-3));
}

// ------------------------------------------------------------------ hysteresis

fn parametric() -> ParametricHysteresis {
    presets::paper_hysteresis(500)
}

#[test]
fn parametric_hysteresis_is_continuous_and_hysteretic() {
    let core = HysteresisParams::Parametric(parametric()).core().unwrap();
    assert_eq!(core.model().n_h(), 500);
    let mut h = Hysteresis::new(std::sync::Arc::new(core));
    // Continuous: a 7.5 mV step of the piezo voltage moves the output by far less than a
    // level's worth of a coarse model.
    let n = 20_000;
    let up: Vec<f64> = (0..=n).map(|k| 150.0 * k as f64 / n as f64).collect();
    let yu: Vec<f64> = up.iter().map(|&u| h.step(u)).collect();
    let max_jump = yu.windows(2).map(|w| (w[1] - w[0]).abs()).fold(0.0, f64::max);
    assert!(max_jump < 0.01, "largest jump {max_jump} µm for a 7.5 mV step");
    assert!(yu.windows(2).all(|w| w[1] >= w[0] - 1e-12), "ascending branch is monotone");
    let yd: Vec<f64> = up.iter().rev().map(|&u| h.step(u)).collect();
    // Descending branch lies above the ascending one at mid-range (counter-clockwise).
    let mid = n / 2;
    let width = yd[n - mid] - yu[mid];
    let stroke = yu[n] - yu[0];
    assert!(stroke > 25.0 && stroke < 50.0, "stroke {stroke} µm");
    assert!(width > 0.05 * stroke && width < 0.3 * stroke, "loop width {width} of stroke {stroke}");
}

#[test]
fn identified_block_equals_its_model_and_round_trips() {
    let n_h = 12;
    let masses: Vec<f64> = (0..n_h * (n_h + 1) / 2).map(|k| 0.1 + (k % 5) as f64 * 0.03).collect();
    let model = PreisachModel::new(preisach_core::Grid::new(-1.0, 2.0, n_h).unwrap(), masses.clone(), 0.4).unwrap();
    for output in [Output::Interpolated, Output::Stepwise] {
        let spec = BlockSpec::Hysteresis(HysteresisParams::Identified(IdentifiedHysteresis::of_model(&model, output)));
        let chain = Chain::new(vec![spec]).unwrap();
        let mut h = chain.compile(FS, Sampling::Zoh, false).unwrap();
        let mut mi = model.interp_memory();
        let mut ms = model.memory();
        for k in 0..2000 {
            let u = 1.5 * (k as f64 * 0.013).sin() * (k as f64 * 0.0011).cos() + 0.3;
            let want = match output {
                Output::Interpolated => model.step_interpolated(&mut mi, u),
                Output::Stepwise => model.step(&mut ms, u),
            };
            assert_eq!(h.step(u), want);
        }
        // JSON round trip carries the masses, as a square matrix.
        let back = Chain::from_json(&chain.to_json()).unwrap();
        assert_eq!(back, chain);
        assert_eq!(back.to_json(), chain.to_json());
        assert_eq!(back.hysteresis(0).unwrap().model().masses(), &masses[..]);
    }
}

#[test]
fn initial_extrema_and_initial_input_set_the_rest_state() {
    let n_h = 10;
    let masses: Vec<f64> = (0..n_h * (n_h + 1) / 2).map(|k| 0.05 + (k % 7) as f64 * 0.02).collect();
    let model = PreisachModel::new(preisach_core::Grid::new(0.0, 10.0, n_h).unwrap(), masses, 0.0).unwrap();
    let mut p = IdentifiedHysteresis::of_model(&model, Output::Interpolated);
    let history = vec![9.0, 1.5, 7.0];
    p.initial_extrema = Some(history.clone());
    let chain = Chain::new(vec![BlockSpec::Hysteresis(HysteresisParams::Identified(p))]).unwrap();
    let u = [5.0, 6.0, 4.0];
    let t = [0.0, 1e-3, 2e-3];
    let mut mem = model.interp_memory();
    let want: Vec<f64> =
        history.iter().chain(&u).map(|&x| model.step_interpolated(&mut mem, x)).skip(history.len()).collect();
    assert_eq!(chain.predict(&t, &u, None).unwrap(), want);
    // At rest at another input: the memory went there before the record.
    let mut mem = model.interp_memory();
    let want: Vec<f64> =
        history.iter().chain(&[2.0]).chain(&u).map(|&x| model.step_interpolated(&mut mem, x)).skip(4).collect();
    assert_eq!(chain.predict(&t, &u, Some(2.0)).unwrap(), want);
}

#[test]
fn a_mode_rings_after_a_step_from_its_initial_input() {
    let chain = Chain::new(vec![vibration(vec![mode(500.0, 0.01)])]).unwrap().with_initial_input(Some(0.0)).unwrap();
    let mut rt = chain.compile(10e3, Sampling::Zoh, false).unwrap();
    let y: Vec<f64> = (0..200).map(|_| rt.step(1.0)).collect();
    assert!(y.iter().fold(0.0f64, |a, &v| a.max(v)) > 1.8, "overshoot of a lightly damped mode");
    // Without it the chain rests at its first input: no ringing.
    let mut rt =
        Chain::new(vec![vibration(vec![mode(500.0, 0.01)])]).unwrap().compile(10e3, Sampling::Zoh, false).unwrap();
    assert!((0..200).all(|_| (rt.step(1.0) - 1.0).abs() < 1e-12));
}

// ------------------------------------------------------------------ chain, preset, JSON

fn sweep(n: usize) -> Vec<f64> {
    (0..n).map(|k| 3.75 + 3.5 * (TAU * 20.0 * k as f64 / FS).sin() * (k as f64 / n as f64)).collect()
}

#[test]
fn paper_preset_units_and_stroke() {
    let c = preset("paper", "{}").unwrap();
    assert_eq!(c.sample_rate_hz(), Some(100_000.0));
    let mut s = c.stage().unwrap();
    // Slow ramp DAC 0 → 7.5 V: sensor 0 → ~8 V (0–40 µm at 1/5 V/µm).
    let n = 100_000;
    let mut y = 0.0;
    for k in 0..=n {
        y = s.step(7.5 * k as f64 / n as f64);
    }
    assert!(y > 5.0 && y < 10.0, "sensor at full stroke {y} V");
    let kinds: Vec<&str> = c.blocks().iter().map(|b| b.kind()).collect();
    assert_eq!(kinds, ["quantizer", "lowpass", "amplifier", "hysteresis", "creep", "vibration", "sensor"]);
    let d = preset("paper", r#"{"delay": true}"#).unwrap();
    match &d.blocks()[6] {
        BlockSpec::Sensor(s) => assert_eq!(s.delay_s, 4.58e-4),
        other => panic!("{other:?}"),
    }
}

#[test]
fn seeded_chain_is_deterministic() {
    let u = sweep(30_000);
    let run = |c: &mut Runtime| u.iter().map(|&x| c.step(x)).collect::<Vec<f64>>();
    let mut a = preset("paper", r#"{"seed": 5}"#).unwrap().stage().unwrap();
    let mut b = preset("paper", r#"{"seed": 5}"#).unwrap().stage().unwrap();
    let ya = run(&mut a);
    assert_eq!(ya, run(&mut b));
    a.reset();
    assert_eq!(ya, run(&mut a), "reset replays exactly");
    let mut c = preset("paper", r#"{"seed": 6}"#).unwrap().stage().unwrap();
    assert_ne!(ya, run(&mut c));
}

#[test]
fn json_round_trip_gives_the_same_chain_and_output() {
    let a = preset("paper", r#"{"delay": true, "seed": 9, "drift_offset_per_s": 1e-3}"#).unwrap();
    let text = a.to_json();
    assert!(text.starts_with(r#"{"format":"preisach-chain","version":2,"sample_rate_hz":100000.0,"blocks":["#));
    assert!(text.contains(r#""type":"hysteresis","source":"parametric""#));
    assert!(text.len() < 5000, "parametric hysteresis is stored by parameters, not masses");
    let b = Chain::from_json(&text).unwrap();
    assert_eq!(a, b);
    let (mut sa, mut sb) = (a.stage().unwrap(), b.stage().unwrap());
    for &x in &sweep(5000) {
        assert_eq!(sa.step(x), sb.step(x));
    }
    // serde on the Chain itself (for embedding in other documents).
    let c: Chain = serde_json::from_str(&serde_json::to_string(&b).unwrap()).unwrap();
    assert_eq!(c, b);
}

#[test]
fn every_block_type_parses_from_hand_written_json_of_either_version() {
    let v1 = r#"{"version": 1, "sample_rate_hz": 100000, "blocks": [
        {"type": "quantizer", "bits": 16, "range": [-10, 10]},
        {"type": "amplifier"},
        {"type": "hysteresis", "source": "identified", "lo": 0, "hi": 1, "n_h": 2, "weights": [1, 0.5, 2]},
        {"type": "creep", "gains": [0.01], "time_constants_s": [1.0]},
        {"type": "vibration", "modes": [{"freq_hz": 780, "damping": 0.02}]},
        {"type": "lowpass", "cutoff_hz": 5000},
        {"type": "delay", "delay_s": 4.58e-4},
        {"type": "noise", "std": 0.001, "seed": 1},
        {"type": "drift", "offset_per_s": 0.001},
        {"type": "sensor"}
    ]}"#;
    let v2 = r#"{"format": "preisach-chain", "version": 2, "sample_rate_hz": 100000, "blocks": [
        {"type": "quantizer", "bits": 16, "range": [-10, 10]},
        {"type": "amplifier"},
        {"type": "hysteresis", "source": "identified", "u_range": [0, 1], "n_h": 2, "weights": [[1, 0.5], [0, 2]],
         "output": "interpolated"},
        {"type": "creep", "amplitudes": [0.01], "taus_s": [1.0]},
        {"type": "vibration", "modes": [{"frequency_hz": 780, "damping": 0.02}]},
        {"type": "lowpass", "cutoff_hz": 5000},
        {"type": "delay", "delay_s": 4.58e-4},
        {"type": "noise", "std": 0.001, "seed": 1},
        {"type": "drift", "offset_per_s": 0.001},
        {"type": "sensor"}
    ]}"#;
    let (a, b) = (Chain::from_json(v1).unwrap(), Chain::from_json(v2).unwrap());
    assert_eq!(a.blocks().len(), 10);
    assert_eq!(a, b, "a version-1 stage file is read as its version-2 form");
    let v2_rate = r#"{"format": "preisach-chain", "version": 2, "initial_input": 0.5, "blocks": [
        {"type": "hysteresis", "source": "identified", "u_range": [0, 1], "n_h": 1, "weights": [[1]],
         "output": "stepwise", "initial_extrema": [1.0, 0.2]},
        {"type": "rate", "gain_s": 1e-4, "tau_s": 1e-3}]}"#;
    let c = Chain::from_json(v2_rate).unwrap();
    assert_eq!((c.sample_rate_hz(), c.initial_input()), (None, Some(0.5)));
    assert_eq!(Chain::from_json(&c.to_json()).unwrap(), c);
}

#[test]
fn version_1_model_and_chain_files_are_converted() {
    let model = r#"{"format": "preisach-model", "version": 1, "n_h": 2, "u_range": [0, 1], "offset": 0.5,
        "output": "interpolated", "weights": [[1, 0.5], [2]], "report": {"rmse": 0.1}}"#;
    let c = Chain::from_json(model).unwrap();
    match &c.blocks()[0] {
        BlockSpec::Hysteresis(HysteresisParams::Identified(p)) => {
            assert_eq!(p.weights, vec![vec![1.0, 0.5], vec![0.0, 2.0]]);
            assert_eq!((p.output, p.offset, p.u_range), (Output::Interpolated, 0.5, [0.0, 1.0]));
        }
        other => panic!("{other:?}"),
    }
    assert_eq!(c.report().unwrap()["rmse"], 0.1);
    let chain = format!(
        r#"{{"format": "preisach-chain", "version": 1, "model": {model}, "effects": [
        {{"name": "drift", "params": {{"gain_per_s": 0.1}}}},
        {{"name": "vibration", "params": {{"frequency_hz": 700, "damping": 0.1, "note": "ignored"}}}},
        {{"name": "rate", "params": {{"gain_s": 1e-3, "tau_s": 1e-3}}}}]}}"#
    );
    let c = Chain::from_json(&chain).unwrap();
    let kinds: Vec<&str> = c.blocks().iter().map(|b| b.kind()).collect();
    assert_eq!(kinds, ["hysteresis", "rate", "vibration", "drift"], "the version-1 fixed order");
    let bad = chain.replace("\"drift\"", "\"warp\"");
    assert!(Chain::from_json(&bad).unwrap_err().to_string().contains("unknown effect 'warp'"));
}

#[test]
fn bad_parameters_are_rejected_by_name() {
    let cases: &[(&str, &str)] = &[
        (r#"{"type": "creep", "amplitudes": [0.1], "taus_s": [-1.0]}"#, "blocks[0] (creep): taus_s[0]"),
        (r#"{"type": "creep", "amplitudes": [0.1, 0.2], "taus_s": [1.0]}"#, "blocks[0] (creep): amplitudes"),
        (r#"{"type": "creep", "amplitudes": [-0.1], "taus_s": [1.0]}"#, "blocks[0] (creep): amplitudes[0]"),
        (
            r#"{"type": "vibration", "modes": [{"frequency_hz": 780, "damping": 0}]}"#,
            "blocks[0] (vibration): modes[0].damping",
        ),
        (
            r#"{"type": "vibration", "modes": [{"frequency_hz": -1, "damping": 0.1}]}"#,
            "blocks[0] (vibration): modes[0].frequency_hz",
        ),
        (r#"{"type": "lowpass", "cutoff_hz": 0}"#, "blocks[0] (lowpass): cutoff_hz"),
        (r#"{"type": "lowpass", "cutoff_hz": 1000, "order": 5}"#, "blocks[0] (lowpass): order"),
        (r#"{"type": "sensor", "lowpass": {"cutoff_hz": 0}}"#, "blocks[0] (sensor): cutoff_hz"),
        (r#"{"type": "delay", "delay_s": -1e-5}"#, "blocks[0] (delay): delay_s"),
        (r#"{"type": "sensor", "delay_s": -1e-5}"#, "blocks[0] (sensor): delay_s"),
        (r#"{"type": "sensor", "noise_std": -1}"#, "blocks[0] (sensor): noise_std"),
        (r#"{"type": "noise", "std": -1}"#, "blocks[0] (noise): std"),
        (r#"{"type": "quantizer", "bits": 0, "range": [0, 1]}"#, "blocks[0] (quantizer): bits"),
        (r#"{"type": "quantizer", "bits": 8, "range": [1, 0]}"#, "blocks[0] (quantizer): range"),
        (r#"{"type": "amplifier", "saturation": [5, 1]}"#, "blocks[0] (amplifier): saturation"),
        (r#"{"type": "amplifier", "slew_v_per_s": 0}"#, "blocks[0] (amplifier): slew_v_per_s"),
        (r#"{"type": "rate", "gain_s": 1, "tau_s": 0}"#, "blocks[0] (rate): tau_s"),
        (
            r#"{"type": "hysteresis", "source": "identified", "u_range": [0, 1], "n_h": 2, "weights": [[1, -0.5], [0, 2]], "output": "stepwise"}"#,
            "blocks[0] (hysteresis): weights[0][1]",
        ),
        (
            r#"{"type": "hysteresis", "source": "identified", "u_range": [0, 1], "n_h": 2, "weights": [[1, 0.5], [0.1, 2]], "output": "stepwise"}"#,
            "blocks[0] (hysteresis): weights[1][0]",
        ),
        (
            r#"{"type": "hysteresis", "source": "identified", "u_range": [0, 1], "n_h": 2, "weights": [[1]], "output": "stepwise"}"#,
            "blocks[0] (hysteresis): weights",
        ),
        (
            r#"{"type": "hysteresis", "source": "parametric", "u_range": [0, 150], "hysteretic_stroke": 30,
             "coercivity_median": -1, "coercivity_sigma": 0.5, "interaction_sigma": 40}"#,
            "blocks[0] (hysteresis): coercivity_median",
        ),
    ];
    for (block, name) in cases {
        let text = format!(r#"{{"format": "preisach-chain", "version": 2, "blocks": [{block}]}}"#);
        let e = Chain::from_json(&text).expect_err(block);
        let msg = e.to_string();
        assert_eq!(err_name(e), *name, "{block}: {msg}");
    }
    // Non-finite values (JSON has none: build directly).
    let bad = CreepParams { taus_s: vec![1.0], amplitudes: vec![f64::NAN], normalized: false };
    assert_eq!(err_name(Chain::new(vec![BlockSpec::Creep(bad)]).unwrap_err()), "blocks[0] (creep): amplitudes[0]");
    let bad = vibration(vec![mode(f64::INFINITY, 0.1)]);
    assert_eq!(err_name(Chain::new(vec![bad]).unwrap_err()), "blocks[0] (vibration): modes[0].frequency_hz");
    let bad = BlockSpec::Drift(DriftParams { gain_per_s: f64::INFINITY, ..Default::default() });
    assert_eq!(err_name(Chain::new(vec![bad]).unwrap_err()), "blocks[0] (drift): gain_per_s");
    let c = Chain::new(vec![]).unwrap();
    assert_eq!(err_name(c.clone().with_sample_rate(Some(-1.0)).unwrap_err()), "sample_rate_hz");
    assert_eq!(err_name(c.clone().with_initial_input(Some(f64::NAN)).unwrap_err()), "initial_input");
    // Checks against the run's rate happen when compiling, per sample only.
    let lp = Chain::new(vec![lowpass(600.0, 2)]).unwrap();
    let e = lp.compile(1000.0, Sampling::Zoh, false).unwrap_err();
    assert_eq!(err_name(e.clone()), "blocks[0] (lowpass): cutoff_hz");
    assert!(e.to_string().contains("Nyquist (500 Hz)"), "{e}");
    assert!(lp.compile(1000.0, Sampling::Foh, true).is_ok(), "a record run is exact at any rate");
    let v = Chain::new(vec![vibration(vec![mode(600.0, 0.1)])]).unwrap();
    assert_eq!(
        err_name(v.compile(1000.0, Sampling::Zoh, false).unwrap_err()),
        "blocks[0] (vibration): modes[0].frequency_hz"
    );
    // Presets.
    assert_eq!(err_name(preset("paper", r#"{"damping": 0}"#).unwrap_err()), "blocks[5] (vibration): modes[0].damping");
    assert_eq!(err_name(preset("paper", r#"{"dampin": 0.1}"#).unwrap_err()), "overrides");
    assert_eq!(err_name(preset("papr", "{}").unwrap_err()), "name");
}

#[test]
fn records_need_a_regular_time_column() {
    let c = Chain::new(vec![lowpass(100.0, 1)]).unwrap();
    let t: Vec<f64> = (0..100).map(|k| k as f64 * 1e-3).collect();
    let u = vec![1.0; 100];
    assert!(c.predict(&t, &u, None).is_ok());
    let mut bad = t.clone();
    bad[50] = bad[49];
    let e = c.predict(&bad, &u, None).unwrap_err().to_string();
    assert!(e.starts_with("t: time must increase strictly (row 50"), "{e}");
    let mut gap = t.clone();
    gap.remove(30);
    let e = c.simulate(&gap, &u[1..], None).unwrap_err().to_string();
    assert!(e.starts_with("t: irregular sampling at row 30"), "{e}");
    let e = c.predict(&t[1..], &u, None).unwrap_err().to_string();
    assert!(e.starts_with("t: length 99 does not match u"), "{e}");
    assert!((sample_period(&t).unwrap() - 1e-3).abs() < 1e-15);
}

#[test]
fn corrupt_json_is_reported_as_corrupt() {
    for text in [
        "{not json",
        r#"{"version": 1, "sample_rate_hz": 100000}"#,
        r#"{"version": 1, "sample_rate_hz": 100000, "blocks": [{"type": "warp"}]}"#,
        r#"{"version": 1, "sample_rate_hz": 100000, "blocks": [{"type": "lowpass", "cutof_hz": 10}]}"#,
        r#"{"version": 99, "sample_rate_hz": 100000, "blocks": []}"#,
        r#"{"format": "preisach-chain", "version": 2, "blocks": [], "colour": 1}"#,
        r#"{"format": "preisach-chain", "version": 3, "blocks": []}"#,
        r#"{"format": "something", "version": 2, "blocks": []}"#,
    ] {
        match Chain::from_json(text) {
            Err(PreisachError::Corrupt { what, .. }) => assert_eq!(what, "chain"),
            other => panic!("{text}: {other:?}"),
        }
    }
}

// ------------------------------------------------------------------ loop

#[test]
fn loop_with_identity_equals_the_plant_and_reports_timing() {
    let r = sweep(20_000);
    let mut plant = preset("paper", "{}").unwrap().stage().unwrap();
    let out = run_loop(&mut Identity, &mut plant, &r).unwrap();
    let mut fresh = preset("paper", "{}").unwrap().stage().unwrap();
    let y: Vec<f64> = r.iter().map(|&x| fresh.step(x)).collect();
    assert_eq!(out.u, r);
    assert_eq!(out.y, y);
    for k in 0..r.len() {
        assert_eq!(out.error[k], r[k] - y[k]);
    }
    let t = out.timing;
    assert_eq!(t.samples, 20_000);
    assert_eq!(t.budget_ns, 10_000.0);
    assert!(t.mean_ns > 0.0 && t.mean_ns <= t.max_ns && t.p99_ns <= t.max_ns);

    let mut g = LinearGain { gain: 2.0, offset: 0.5 };
    let out = run_loop(&mut g, &mut plant, &r).unwrap();
    assert_eq!(out.u[7], 2.0 * r[7] + 0.5);
    assert!(run_loop(&mut Identity, &mut plant, &[]).is_err());
    assert_eq!(err_name(run_loop(&mut Identity, &mut plant, &[0.0, f64::NAN]).unwrap_err()), "reference");
}

#[test]
fn timing_statistics() {
    let mut ns: Vec<u64> = (1..=1000).collect();
    let t = Timing::from_samples(&mut ns, 990.0);
    assert_eq!(t.mean_ns, 500.5);
    assert_eq!(t.p99_ns, 990.0);
    assert_eq!(t.max_ns, 1000.0);
    assert_eq!(t.misses, 10);
}

// ------------------------------------------------------------------ rest at the first sample

/// Largest deviation of `y` from its first value.
fn ripple(y: &[f64]) -> f64 {
    y.iter().map(|v| (v - y[0]).abs()).fold(0.0, f64::max)
}

#[test]
fn every_linear_block_starts_in_equilibrium_with_its_first_sample() {
    let specs = vec![
        lowpass(20_000.0, 1),
        lowpass(20_000.0, 2),
        lowpass(500.0, 3),
        lowpass(20_000.0, 4),
        vibration(vec![mode(780.0, 0.02)]),
        vibration(vec![mode(780.0, 0.005), mode(2300.0, 0.1)]),
        vibration(vec![mode(780.0, 1.0), mode(2300.0, 3.0)]),
        BlockSpec::Creep(CreepParams::log_law(0.01, 0.1, 100.0)),
        creep(vec![0.01, 0.1], vec![0.02, 0.05]),
        BlockSpec::Delay(DelayParams { delay_s: 4.58e-4 }),
        BlockSpec::Delay(DelayParams { delay_s: 3.0 / FS }),
        BlockSpec::Amplifier(AmplifierParams { gain: 20.0, saturation: Some([-30.0, 180.0]), slew_v_per_s: Some(1e5) }),
        BlockSpec::Sensor(SensorParams {
            lowpass: Some(LowpassParams { cutoff_hz: 20_000.0, order: 4 }),
            delay_s: 4.58e-4,
            ..SensorParams::default()
        }),
    ];
    for spec in specs {
        let name = format!("{spec:?}");
        let dc = match &spec {
            BlockSpec::Creep(p) => p.lti().unwrap().dc_gain(),
            BlockSpec::Amplifier(_) => 20.0,
            BlockSpec::Sensor(_) => 0.2,
            _ => 1.0,
        };
        for sampling in [Sampling::Zoh, Sampling::Foh] {
            let mut b = Chain::new(vec![spec.clone()]).unwrap().compile(FS, sampling, false).unwrap();
            for x0 in [1.1, -3.7] {
                // Fresh, after reset, and after reset_state (a new record).
                for round in 0..3 {
                    match round {
                        1 => b.reset(),
                        2 => b.reset_state(),
                        _ => {}
                    }
                    let y: Vec<f64> = (0..20_000).map(|_| b.step(x0)).collect();
                    let want = (dc * x0).clamp(-30.0, 180.0);
                    assert!((y[0] - want).abs() < 1e-12 * want.abs().max(1.0), "{name} x0={x0}: {} vs {want}", y[0]);
                    let r = ripple(&y);
                    assert!(r < 1e-10 * want.abs().max(1.0), "{name} x0={x0} round {round}: ripple {r}");
                }
                b.reset();
            }
        }
    }
}

/// The paper stage without noise and quantization.
fn quiet_paper(extra: &str) -> Runtime {
    preset("paper", &format!(r#"{{"noise_std": 0, "dac_bits": 0, "adc_bits": 0{extra}}}"#)).unwrap().stage().unwrap()
}

#[test]
fn paper_stage_is_at_rest_from_the_first_sample() {
    for extra in ["", r#", "delay": true"#] {
        for u0 in [0.0, 3.75] {
            let mut c = quiet_paper(extra);
            let y: Vec<f64> = (0..30_000).map(|_| c.step(u0)).collect();
            // u = 0 gives about 1.1 µm of hysteresis output: 0.22 V at the sensor.
            if u0 == 0.0 {
                assert!(y[0] > 0.1, "first output {}", y[0]);
            }
            let r = ripple(&y);
            assert!(r < 1e-9, "u0={u0} {extra}: ripple {r} V");
            let dev: Vec<f64> = y[..(FS / 780.0 * 20.0) as usize].iter().map(|v| v - y[0]).collect();
            assert!(amplitude_at(&dev, 780.0, FS) < 1e-12);
            // The same after reset and after reset_state.
            c.reset();
            let y2: Vec<f64> = (0..30_000).map(|_| c.step(u0)).collect();
            assert_eq!(y, y2);
            c.reset_state();
            assert!(ripple(&(0..30_000).map(|_| c.step(u0)).collect::<Vec<_>>()) < 1e-9);
        }
    }
    // With the default noise and quantization: nothing at the resonance beyond the
    // noise floor (1 nm noise; a ringing start from rest at 0 is ~1 µm).
    let mut c = preset("paper", "{}").unwrap().stage().unwrap();
    let y: Vec<f64> = (0..(FS / 780.0 * 39.0).round() as usize).map(|_| c.step(0.0)).collect();
    let a = amplitude_at(&y, 780.0, FS) / 0.2;
    assert!(a < 1e-4, "780 Hz content {a} µm");
}

#[test]
fn reset_state_keeps_absolute_time_and_settles_again() {
    let opts = r#"{"noise_std": 0, "dac_bits": 0, "adc_bits": 0, "drift_offset_per_s": 1.0, "creep": false}"#;
    let mut c = preset("paper", opts).unwrap().stage().unwrap();
    let y1: Vec<f64> = (0..1000).map(|k| c.step(2.0 + (k as f64 * 0.01).sin())).collect();
    let t = c.time_s();
    assert!((t - 0.01).abs() < 1e-12);
    c.reset_state();
    assert!((c.time_s() - t).abs() < 1e-12);
    // Constant input: output = rest value + the drift's offset ramp over absolute time.
    let y2: Vec<f64> = (0..1000).map(|_| c.step(1.0)).collect();
    for (k, v) in y2.iter().enumerate() {
        let drift = (k as f64) / FS; // offset_per_s = 1 per second since the first
        assert!((v - y2[0] - drift).abs() < 1e-9, "k={k}: {v} vs {}", y2[0] + drift);
    }
    let mut fresh = preset("paper", opts).unwrap().stage().unwrap();
    assert!((y2[0] - fresh.step(1.0) - t).abs() < 1e-9, "drift offset at t = 0.01 s is included");
    // A full reset replays the first record exactly.
    c.reset();
    let y3: Vec<f64> = (0..1000).map(|k| c.step(2.0 + (k as f64 * 0.01).sin())).collect();
    assert_eq!(y1, y3);
}
