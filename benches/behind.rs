//! The masses' fit behind a chain (`identify::filtered::Behind`), on the diagnosis's
//! workload: `cargo bench --bench behind`.
//! 2 s of 100 kHz input (a sine of growing amplitude with a slower one on top, small
//! noise) through a smooth density (n_h = 40), then a lightly damped mode (700 Hz,
//! ζ = 0.02) and creep, noisy output; the fit on windows of 8 samples (25 000 of them).
//! Timed: building the problem (`new`), the chain's record pass and its adjoint on the
//! windows (`passes`, a conjugate-gradient iteration's), a cold solve, a profile of five neighbouring
//! chains warm-started one from the other (the mode's frequency stepped by 0.5 %, as a
//! line search moves it), the masses' projection (`project`, the plain one polished;
//! `project_tie`, the diagnosis's, with its smoothness term) of one solution, and the
//! projections of the profile's five solutions in turn (`project_profile_5`).

use std::hint::black_box;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, Criterion};
use preisach_core::blocks::{CreepParams, Discretization, Filter, Lti, Mode, VibrationParams};
use preisach_core::identify::filtered::{Behind, Stop, Terms};
use preisach_core::identify::projection::TIE;

#[path = "common.rs"]
mod common;
use common::smooth_model;

const DT: f64 = 1e-5;
const STRIDE: usize = 8;
const N_H: usize = 40;

fn chain(f_hz: f64) -> Vec<Lti> {
    let mode = VibrationParams { modes: vec![Mode { frequency_hz: f_hz, damping: 0.02 }] }.lti().unwrap();
    let creep = CreepParams { taus_s: vec![0.05], amplitudes: vec![0.05], normalized: true }.lti().unwrap();
    vec![mode, creep]
}

/// (u, target on the windows, model range).
fn workload() -> (Vec<f64>, Vec<f64>, (f64, f64)) {
    let n = 200_000;
    let mut s = 7u64;
    let mut noise = move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        ((s >> 11) as f64 / (1u64 << 53) as f64) - 0.5
    };
    let pi = std::f64::consts::PI;
    let u: Vec<f64> = (0..n)
        .map(|k| {
            let t = k as f64 / n as f64;
            50.0 + 45.0 * (0.1 + 0.9 * t) * (2.0 * pi * 40.0 * t).sin()
                + 4.0 * (2.0 * pi * 330.0 * t).sin()
                + 0.05 * noise()
        })
        .collect();
    let truth = smooth_model(N_H);
    let mut h = vec![0.0; n];
    truth.run_interpolated(&mut truth.interp_memory(), &u, &mut h);
    let mut y = vec![0.0; n];
    Filter::cascade(&chain(700.0), DT, Discretization::Foh).apply(&h, &mut y);
    let z: Vec<f64> = y.chunks_exact(STRIDE).map(|w| w.iter().sum::<f64>() / STRIDE as f64 + 0.01 * noise()).collect();
    (u, z, (2.0, 98.0))
}

fn behind(c: &mut Criterion) {
    let (u, z, range) = workload();
    let dt = DT * STRIDE as f64;
    let terms = Terms::default();
    let tol = 1e-4;
    let mut g = c.benchmark_group("behind");
    g.measurement_time(Duration::from_secs(8)).warm_up_time(Duration::from_secs(1)).sample_size(10);
    g.bench_function("new", |b| b.iter(|| black_box(Behind::new(&u, N_H, range, STRIDE).unwrap().n_samples())));
    let mut fit = Behind::new(&u, N_H, range, STRIDE).unwrap();
    let mut lti = Filter::cascade(&chain(700.0), dt, Discretization::Foh);
    // The chain's record pass and its adjoint on the windows (every iteration's).
    let (mut y, mut back) = (vec![0.0; z.len()], vec![0.0; z.len()]);
    g.bench_function("passes", |b| {
        b.iter(|| {
            lti.apply(&z, &mut y);
            lti.adjoint(&y, &mut back);
            black_box(back[0])
        })
    });
    g.bench_function("solve_cold", |b| {
        b.iter(|| black_box(fit.solve(&z, &mut lti, &terms, &Stop::new(tol, 300), false).unwrap().rmse))
    });
    let mut along: Vec<Filter> =
        (0..5).map(|k| Filter::cascade(&chain(700.0 * (1.0 + 0.005 * k as f64)), dt, Discretization::Foh)).collect();
    g.bench_function("profile_5_warm", |b| {
        b.iter(|| {
            fit.solve(&z, &mut along[0], &terms, &Stop::new(tol, 300), false).unwrap();
            let mut e = 0.0;
            for l in along.iter_mut().skip(1) {
                e += fit.solve(&z, l, &terms, &Stop::new(tol, 300), true).unwrap().rmse;
            }
            black_box(e)
        })
    });
    let sol = fit.solve(&z, &mut lti, &terms, &Stop::new(tol, 300), false).unwrap();
    g.bench_function("project", |b| b.iter(|| black_box(fit.project(&sol, &z, &mut lti, &terms).unwrap().2)));
    // The diagnosis's projection: with the smoothness term that makes it unique, the
    // interior point not polished.
    let mut tied = Behind::new(&u, N_H, range, STRIDE).unwrap();
    tied.set_tie(TIE).unwrap();
    g.bench_function("project_tie", |b| b.iter(|| black_box(tied.project(&sol, &z, &mut lti, &terms).unwrap().2)));
    // The projections of the profile's five solutions in turn (each one's neighbour the
    // last one projected, as a search asks for them).
    let sols: Vec<_> =
        along.iter_mut().map(|l| fit.solve(&z, l, &terms, &Stop::new(tol, 300), false).unwrap()).collect();
    g.bench_function("project_profile_5", |b| {
        b.iter(|| {
            let mut e = 0.0;
            for (s, l) in sols.iter().zip(along.iter_mut()) {
                e += fit.project(s, &z, l, &terms).unwrap().2;
            }
            black_box(e)
        })
    });
    g.finish();
}

criterion_group!(benches, behind);
criterion_main!(benches);
