//! Chain inverse per-sample cost (`docs/method/inversion.md`, "Inverting a chain"): the
//! streaming inverter of a chain hysteresis (n_h = 100, continuous) → creep (two
//! elements) → one mode (780 Hz) → 2nd-order low-pass (5 kHz) → delay (0.3 ms), at
//! 100 kHz, on a 1 s, 5 Hz sine reference over 10–90 % of the output range.
//! Criterion reports time per 100 000-sample run; ns/sample = that / 1e5.
//!
//! `cargo bench --bench chain_inverse`

use std::hint::black_box;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use preisach_core::blocks::{
    BlockSpec, Chain, CreepParams, DelayParams, HysteresisParams, IdentifiedHysteresis, LowpassParams, Mode, Output,
    VibrationParams,
};
use preisach_core::chain_invert::{ChainInverter, Plan};
use preisach_core::invert::Method;

const FS: f64 = 100_000.0;
const T: usize = 100_000;

#[path = "common.rs"]
mod common;
use common::smooth_model;

fn bench_chain_inverse(c: &mut Criterion) {
    let model = smooth_model(100);
    let total = model.everett().total();
    let (ymin, ymax) = (model.offset() - total, model.offset() + total);
    let chain = Chain::new(vec![
        BlockSpec::Hysteresis(HysteresisParams::Identified(IdentifiedHysteresis::of_model(
            &model,
            Output::Interpolated,
        ))),
        BlockSpec::Creep(CreepParams { taus_s: vec![0.05, 2.0], amplitudes: vec![0.02, 0.03], normalized: false }),
        BlockSpec::Vibration(VibrationParams { modes: vec![Mode { frequency_hz: 780.0, damping: 0.02 }] }),
        BlockSpec::Lowpass(LowpassParams { cutoff_hz: 5000.0, order: 2 }),
        BlockSpec::Delay(DelayParams { delay_s: 3e-4 }),
    ])
    .unwrap();
    let gain = 1.05; // the creep's static gain
    let r: Vec<f64> = (0..T)
        .map(|k| gain * (ymin + (ymax - ymin) * (0.5 + 0.4 * (std::f64::consts::TAU * 5.0 * k as f64 / FS).sin())))
        .collect();
    let plan = Plan::new(&chain, FS, None).unwrap();
    let mut inv = ChainInverter::new(&plan, Method::Continuous, None).unwrap();
    let mut u = vec![0.0; T];
    let mut g = c.benchmark_group("chain_inverse");
    g.throughput(Throughput::Elements(T as u64));
    g.sample_size(10).warm_up_time(Duration::from_millis(500)).measurement_time(Duration::from_secs(3));
    g.bench_function("hysteresis100+creep+mode+lowpass+delay/continuous", |b| {
        b.iter(|| {
            inv.reset();
            inv.process(black_box(&r), &mut u).unwrap();
            black_box(u[T - 1])
        })
    });
    g.finish();
}

criterion_group!(benches, bench_chain_inverse);
criterion_main!(benches);
