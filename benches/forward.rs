//! Forward model per-sample timing: `cargo bench --bench forward`.
//! The staircase over a block (the batch path), stepwise and interpolated, at
//! n_h ∈ {10, 100, 1000}. Throughput is reported per sample; divide 1e9 by it for ns.

use std::hint::black_box;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};

#[path = "common.rs"]
mod common;
use common::smooth_model;

/// 5 Hz sine with slowly varying amplitude plus small noise, 100 kHz, 0.5 s.
pub fn test_input(n: usize) -> Vec<f64> {
    let mut s = 0x12345678u64;
    (0..n)
        .map(|k| {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            let noise = (s >> 11) as f64 / (1u64 << 53) as f64 - 0.5;
            let t = k as f64 / 1e5;
            50.0 + (30.0 + 15.0 * (0.7 * t).sin()) * (2.0 * std::f64::consts::PI * 5.0 * t).sin() + 0.2 * noise
        })
        .collect()
}

fn forward(c: &mut Criterion) {
    let u = test_input(50_000);
    let mut out = vec![0.0; u.len()];
    let mut g = c.benchmark_group("forward");
    g.throughput(Throughput::Elements(u.len() as u64));
    g.measurement_time(Duration::from_secs(3)).warm_up_time(Duration::from_millis(500)).sample_size(20);
    for n_h in [10usize, 100, 1000] {
        let model = smooth_model(n_h);
        g.bench_with_input(BenchmarkId::new("stepwise", n_h), &n_h, |b, _| {
            b.iter(|| {
                let mut mem = model.memory();
                model.run(&mut mem, black_box(&u), &mut out);
                black_box(out[out.len() - 1])
            })
        });
        g.bench_with_input(BenchmarkId::new("interpolated", n_h), &n_h, |b, _| {
            b.iter(|| {
                let mut mem = model.interp_memory();
                model.run_interpolated(&mut mem, black_box(&u), &mut out);
                black_box(out[out.len() - 1])
            })
        });
    }
    g.finish();
}

criterion_group!(benches, forward);
criterion_main!(benches);
