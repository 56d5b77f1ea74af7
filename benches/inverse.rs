//! Inverse per-sample cost (the paper §4.1) through the batch API, per method and n_h.
//!
//! Model: a smooth density (Gaussian ridge near the diagonal plus a diagonal part) on
//! (0, 100). References, 1 s at 100 kHz: `sine` = 5 Hz reaching 10–90 % of the output
//! range (the paper's compensation test), `jumps` = uniform random levels every sample
//! (the worst case for the galloping search: O(log n_h) peeks per sample).
//! Criterion reports time per 100 000-sample run; ns/sample = that / 1e5.
//! `interpolated_L100` runs the monotone closest match (the interpolation's knot source,
//! which skips the search whenever the reference moves back towards the current level)
//! plus the interpolation with a 100-sample look-ahead.
//!
//! `cargo bench --bench inverse` (set `INVERSE_NH=10,100` to choose the n_h).

use std::hint::black_box;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use preisach_core::invert::{invert, Method};
use preisach_core::PreisachModel;

const FS: f64 = 100_000.0;
const T: usize = 100_000;

#[path = "common.rs"]
mod common;
use common::smooth_model;

fn references(model: &PreisachModel) -> [(&'static str, Vec<f64>); 2] {
    let total = model.everett().total();
    let (ymin, ymax) = (model.offset() - total, model.offset() + total);
    let sine = (0..T)
        .map(|k| ymin + (ymax - ymin) * (0.5 + 0.4 * (2.0 * std::f64::consts::PI * 5.0 * k as f64 / FS).sin()))
        .collect();
    let mut s = 0x2545F4914F6CDD1Du64;
    let jumps = (0..T)
        .map(|_| {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            ymin + (ymax - ymin) * ((s >> 11) as f64 / (1u64 << 53) as f64)
        })
        .collect();
    [("sine", sine), ("jumps", jumps)]
}

fn bench_inverse(c: &mut Criterion) {
    let sizes: Vec<usize> = std::env::var("INVERSE_NH")
        .ok()
        .map(|s| s.split(',').filter_map(|x| x.trim().parse().ok()).collect())
        .unwrap_or_else(|| vec![10, 100, 1000, 3000]);
    for &n_h in &sizes {
        let model = smooth_model(n_h);
        for (ref_name, r) in references(&model) {
            let mut g = c.benchmark_group(format!("inverse/{ref_name}"));
            g.throughput(Throughput::Elements(T as u64));
            g.sample_size(10).warm_up_time(Duration::from_millis(500)).measurement_time(Duration::from_secs(2));
            for (name, method, lookahead) in [
                ("closest", Method::Closest, None),
                ("interpolated_L100", Method::Interpolated, Some(100)),
                ("continuous", Method::Continuous, None),
            ] {
                g.bench_with_input(BenchmarkId::new(name, n_h), &r, |b, r| {
                    b.iter(|| invert(black_box(&model), black_box(r), method, lookahead).unwrap())
                });
            }
            g.finish();
        }
    }
}

criterion_group!(benches, bench_inverse);
criterion_main!(benches);
