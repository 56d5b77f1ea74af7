//! Identification timing per fit: `cargo bench --bench identify`.
//! The workload of `benches/compare.py`: a sine of growing amplitude (100 reversals,
//! small input noise) through a smooth density, noisy output, 200 000 samples;
//! `fit` with the default solver (the active-set method) at n_h ∈ {20, 40, 60}, the
//! whole fit and the QP solve alone (from the report).

use std::hint::black_box;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use preisach_core::identify::{fit, FitOptions, Solver, DEFAULT_DIAGONAL_FLOOR};

#[path = "common.rs"]
mod common;
use common::smooth_model;

/// Standard normal deviates (xorshift + Box–Muller), reproducible.
fn normals(n: usize, seed: u64) -> Vec<f64> {
    let mut s = seed.max(1);
    let mut uni = move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        ((s >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    };
    (0..n).map(|_| (-2.0 * uni().ln()).sqrt() * (std::f64::consts::TAU * uni()).cos()).collect()
}

/// (u, y, model range) of the compare.py identification workload.
fn workload(n_h: usize) -> (Vec<f64>, Vec<f64>, (f64, f64)) {
    let n = 200_000;
    let noise = normals(n, 2);
    let u: Vec<f64> = (0..n)
        .map(|k| {
            let t = k as f64 / (n - 1) as f64;
            50.0 + 53.0 * (0.02 + 0.98 * t) * (std::f64::consts::PI * 100.0 * t).sin() + 0.02 * noise[k]
        })
        .collect();
    let truth = smooth_model(n_h);
    let mut y = vec![0.0; n];
    truth.run(&mut truth.memory(), &u, &mut y);
    for (v, e) in y.iter_mut().zip(normals(n, 3)) {
        *v += 0.01 * e;
    }
    let (mn, mx) = u.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| (a.min(x), b.max(x)));
    let pad = 0.005 * (mx - mn);
    (u, y, (mn + pad, mx - pad))
}

fn identify(c: &mut Criterion) {
    let mut g = c.benchmark_group("identify");
    g.measurement_time(Duration::from_secs(4)).warm_up_time(Duration::from_millis(500)).sample_size(30);
    for n_h in [20usize, 40, 60] {
        let (u, y, range) = workload(n_h);
        let opts = FitOptions {
            n_h,
            u_range: Some(range),
            reg: 0.0,
            solver: Solver::Auto,
            interpolated: false,
            diagonal_floor: DEFAULT_DIAGONAL_FLOOR,
        };
        g.bench_with_input(BenchmarkId::new("fit", n_h), &n_h, |b, _| {
            b.iter(|| black_box(fit(black_box(&u), black_box(&y), &opts).unwrap().1.rmse))
        });
        // The QP solve alone, as timed inside `fit` (its report's `time_solve_s`).
        g.bench_with_input(BenchmarkId::new("solve", n_h), &n_h, |b, _| {
            b.iter_custom(|iters| {
                let mut total = Duration::ZERO;
                for _ in 0..iters {
                    let (_, rep) = fit(black_box(&u), black_box(&y), &opts).unwrap();
                    total += Duration::from_secs_f64(rep.time_solve_s);
                }
                total
            })
        });
    }
    g.finish();
}

criterion_group!(benches, identify);
criterion_main!(benches);
