//! Per-sample cost of every plant block and of the full 100 kHz loop (inverse + all
//! plant blocks of the `paper` preset) at n_h ∈ {10, 100, 1000}. Throughput is per
//! sample, so criterion's "time" per element is ns/sample; the budget is 10 µs.
//!
//! `cargo bench --bench sim` (short measurement times: a few seconds in all).

use std::hint::black_box;
use std::sync::Arc;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use preisach_core::blocks::*;
use preisach_core::invert::{Inverter, Method};
use preisach_core::sim::{run_loop, Compensator};
use preisach_core::{Grid, PreisachModel};

const FS: f64 = 100_000.0;
const N: usize = 20_000;

/// DAC-volt input: a 20 Hz sine with growing amplitude over the usable range.
fn dac_input() -> Vec<f64> {
    (0..N)
        .map(|k| {
            let t = k as f64 / FS;
            3.75 + 3.5 * (0.2 + 0.8 * k as f64 / N as f64) * (std::f64::consts::TAU * 20.0 * t).sin()
        })
        .collect()
}

/// Reference in sensor volts: a 5 Hz sine, 2 V (10 µm) amplitude around 4 V.
fn reference() -> Vec<f64> {
    (0..N).map(|k| 4.0 + 2.0 * (std::f64::consts::TAU * 5.0 * k as f64 / FS).sin()).collect()
}

/// A smooth model of the stage in DAC volts → sensor volts (output ≈ 0–8 V).
fn model(n_h: usize) -> Arc<PreisachModel> {
    let grid = Grid::new(0.0, 7.5, n_h).unwrap();
    let mut masses = vec![0.0; grid.n_q()];
    for i in 0..n_h {
        for j in i..n_h {
            let h = (j - i) as f64 / n_h as f64;
            masses[preisach_core::grid::cell_index(n_h, i, j)] = (-(h * 8.0)).exp() * if i == j { 3.0 } else { 1.0 };
        }
    }
    let s: f64 = masses.iter().sum();
    masses.iter_mut().for_each(|w| *w *= 4.0 / s);
    Arc::new(PreisachModel::new(grid, masses, 4.0).unwrap())
}

fn configure(c: &mut Criterion) -> criterion::BenchmarkGroup<'_, criterion::measurement::WallTime> {
    let mut g = c.benchmark_group("sim");
    g.warm_up_time(Duration::from_millis(300))
        .measurement_time(Duration::from_secs(1))
        .sample_size(20)
        .throughput(Throughput::Elements(N as u64));
    g
}

/// A runtime of `blocks` per sample at the bench's rate.
fn runtime(blocks: Vec<BlockSpec>) -> Runtime {
    Chain::new(blocks).unwrap().compile(FS, Sampling::Zoh, false).unwrap()
}

fn blocks(c: &mut Criterion) {
    let u = dac_input();
    let paper = preset("paper", "{}").unwrap();
    let specs = paper.blocks().to_vec();
    // Each block fed the signal it sees in the paper chain (piezo V, µm, …): the output
    // of the blocks before it.
    let signal = |k: usize| -> Vec<f64> {
        let mut pre = runtime(specs[..k].to_vec());
        u.iter().map(|&x| pre.step(x)).collect()
    };
    let mut stepwise = match &specs[3] {
        BlockSpec::Hysteresis(HysteresisParams::Parametric(p)) => p.clone(),
        _ => unreachable!("the paper preset's fourth block is its hysteresis"),
    };
    stepwise.output = Output::Stepwise;
    let extra: Vec<(&str, BlockSpec, usize)> = vec![
        ("delay_45.8", BlockSpec::Delay(DelayParams { delay_s: 4.58e-4 }), 6),
        ("noise", BlockSpec::Noise(NoiseParams { std: 1e-3, seed: 1 }), 6),
        ("drift", BlockSpec::Drift(DriftParams { gain_per_s: 1e-4, offset: 0.0, offset_per_s: 1e-4 }), 6),
        ("hysteresis_stepwise_500", BlockSpec::Hysteresis(HysteresisParams::Parametric(stepwise)), 3),
    ];
    let mut g = configure(c);
    let named = specs.iter().enumerate().map(|(k, b)| (format!("{k}_{}", b.kind()), b.clone(), k));
    let all: Vec<(String, BlockSpec, usize)> =
        named.chain(extra.into_iter().map(|(n, b, k)| (n.to_string(), b, k))).collect();
    for (name, spec, k) in all {
        let x = signal(k);
        let mut b = runtime(vec![spec]);
        g.bench_function(format!("block/{name}"), |bch| {
            bch.iter(|| {
                let mut acc = 0.0;
                for &v in &x {
                    acc += b.step(black_box(v));
                }
                acc
            })
        });
    }
    let mut ch = paper.stage().unwrap();
    g.bench_function("chain/paper", |bch| {
        bch.iter(|| {
            let mut acc = 0.0;
            for &v in &u {
                acc += ch.step(black_box(v));
            }
            acc
        })
    });
    g.finish();
}

fn full_loop(c: &mut Criterion) {
    let r = reference();
    let paper = preset("paper", "{}").unwrap().stage().unwrap();
    let mut g = configure(c);
    for &n_h in &[10usize, 100, 1000] {
        let m = model(n_h);
        for (name, method, la) in
            [("continuous", Method::Continuous, None), ("interpolated", Method::Interpolated, Some(2000))]
        {
            let mut inv = Inverter::new(m.clone(), method, la).unwrap();
            let mut plant = paper.clone();
            g.bench_with_input(BenchmarkId::new(format!("loop/{name}"), n_h), &n_h, |bch, _| {
                bch.iter(|| {
                    let mut acc = 0.0;
                    for &x in &r {
                        acc += plant.step(inv.step(black_box(x)));
                    }
                    acc
                })
            });
            let mut inv = Inverter::new(m.clone(), method, la).unwrap();
            g.bench_with_input(BenchmarkId::new(format!("inverse_only/{name}"), n_h), &n_h, |bch, _| {
                bch.iter(|| {
                    let mut acc = 0.0;
                    for &x in &r {
                        acc += inv.step(black_box(x));
                    }
                    acc
                })
            });
        }
    }
    // The timed loop itself (one Instant per sample, buffers, reset): its overhead.
    let m = model(100);
    let mut inv = Inverter::new(m, Method::Continuous, None).unwrap();
    let mut plant = paper.clone();
    g.bench_function("run_loop_timed/continuous/100", |bch| {
        bch.iter(|| run_loop(&mut inv as &mut dyn Compensator, &mut plant, black_box(&r)).unwrap().timing.mean_ns)
    });
    g.finish();
}

criterion_group!(benches, blocks, full_loop);
criterion_main!(benches);
