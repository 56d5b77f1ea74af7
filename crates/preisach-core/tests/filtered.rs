//! Masses fitted behind linear dynamics (`identify::filtered`): the block recursion and
//! its adjoint, and recovery of known masses through a lightly damped mode.
mod common;

use common::{random_input, random_model, Rng};
use preisach_core::blocks::lti::C;
use preisach_core::blocks::{CreepParams, Discretization, Filter, Lti, Mode, Section, VibrationParams};
use preisach_core::identify::filtered::{fit_behind, BehindOptions};
use preisach_core::identify::{fit, FitOptions, Solver};

/// `w²/(s² + 2ζw s + w²)`: the vibration block of one mode.
fn mode(f: f64, zeta: f64) -> Lti {
    VibrationParams { modes: vec![Mode { frequency_hz: f, damping: zeta }] }.lti().unwrap()
}

/// `1/(1 + s τ)`: a normalized creep element of amplitude 1.
fn first_order(tau: f64) -> Lti {
    CreepParams { taus_s: vec![tau], amplitudes: vec![1.0], normalized: true }.lti().unwrap()
}

/// `1 + 0.05 (1/(1 + s/20) − 1)`: creep with a direct term and a slow pole.
fn creep() -> Lti {
    CreepParams { taus_s: vec![0.05], amplitudes: vec![0.05], normalized: true }.lti().unwrap()
}

fn cascade(blocks: &[Lti], dt: f64) -> Filter {
    Filter::cascade(blocks, dt, Discretization::Foh)
}

/// An identification record's input: a sine of `cycles` periods whose amplitude grows
/// from mid-range (0.5) to 1.5, over `n` samples.
fn increasing_sine(n: usize, cycles: f64) -> Vec<f64> {
    (0..n)
        .map(|k| {
            let t = k as f64 / n as f64;
            0.5 + 1.5 * t * (std::f64::consts::TAU * cycles * t).sin()
        })
        .collect()
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// The plain interpolated fit on the tests' input range (no chain behind it).
fn plain_options(n_h: usize) -> FitOptions {
    FitOptions {
        n_h,
        u_range: Some((-1.0, 2.0)),
        reg: 0.0,
        solver: Solver::Auto,
        interpolated: true,
        diagonal_floor: 0.0,
    }
}

#[test]
fn adjoint_of_the_cascade_is_exact() {
    let mut rng = Rng::new(3);
    // Creep-like block (direct term plus a slow pole), a mode and a fast low-pass.
    let blocks = [creep(), mode(700.0, 0.01), first_order(1.0 / (2.0 * std::f64::consts::PI * 3000.0))];
    let mut l = cascade(&blocks, 2e-5);
    let n = 5000;
    let x: Vec<f64> = (0..n).map(|_| rng.range(-1.0, 1.0)).collect();
    let w: Vec<f64> = (0..n).map(|_| rng.range(-1.0, 1.0)).collect();
    let (mut lx, mut ltw) = (vec![0.0; n], vec![0.0; n]);
    l.apply(&x, &mut lx);
    l.adjoint(&w, &mut ltw);
    let (a, b) = (dot(&w, &lx), dot(&ltw, &x));
    assert!((a - b).abs() <= 1e-11 * a.abs().max(1.0), "<w, Lx> = {a}, <L'w, x> = {b}");
}

#[test]
fn first_order_block_is_exact_for_a_ramp_from_rest() {
    // 1/(1 + s tau) driven by x(t) = t from rest: y(t) = t − tau (1 − e^{−t/tau}); the
    // hold is first order, so a ramp is reproduced exactly.
    let (tau, dt) = (3e-3, 1e-4);
    let mut l = cascade(&[first_order(tau)], dt);
    let n = 400;
    let x: Vec<f64> = (0..n).map(|k| k as f64 * dt).collect();
    let mut y = vec![0.0; n];
    l.apply(&x, &mut y);
    for (k, &v) in y.iter().enumerate() {
        let t = k as f64 * dt;
        let exact = t - tau * (1.0 - (-t / tau).exp());
        assert!((v - exact).abs() < 1e-15 + 1e-11 * exact.abs(), "k={k}: {v} vs {exact}");
    }
}

#[test]
fn mode_block_starts_at_rest_and_has_unit_dc_gain() {
    let mut l = cascade(&[mode(500.0, 0.05)], 1e-5);
    let x = vec![2.5; 20_000];
    let mut y = vec![0.0; x.len()];
    l.apply(&x, &mut y);
    assert!(y.iter().all(|v| (v - 2.5).abs() < 1e-12), "a constant input from rest stays constant");
}

#[test]
fn fit_behind_recovers_masses_through_a_lightly_damped_mode() {
    let mut rng = Rng::new(11);
    let n_h = 8;
    let truth = random_model(&mut rng, n_h);
    let u = random_input(&mut rng, 6000);
    let mut h = vec![0.0; u.len()];
    truth.run_interpolated(&mut truth.interp_memory(), &u, &mut h);
    let dt = 1e-4;
    let blocks = [mode(300.0, 0.02)];
    let mut z = vec![0.0; u.len()];
    cascade(&blocks, dt).apply(&h, &mut z);
    let opts = BehindOptions { n_h, u_range: (-1.0, 2.0), dt, tol: 1e-12, max_iter: 500 };
    let (m, rep) = fit_behind(&u, &z, None, &blocks, &opts).unwrap();
    let span = z.iter().fold(0.0f64, |a, v| a.max(v.abs()));
    assert!(rep.rmse < 1e-8 * span, "chain rmse {} (iterations {})", rep.rmse, rep.iterations);
    let wmax = truth.masses().iter().fold(0.0f64, |a, v| a.max(*v));
    for (a, b) in m.masses().iter().zip(truth.masses()) {
        assert!((a - b).abs() < 1e-6 * wmax, "mass {a} vs {b}");
    }
    assert!((m.offset() - truth.offset()).abs() < 1e-6 * wmax);

    // Ignoring the mode (the plain fit of z) is far off: the test can fail.
    let (plain, _) = fit(&u, &z, &plain_options(n_h)).unwrap();
    let err = plain.masses().iter().zip(truth.masses()).fold(0.0f64, |a, (x, y)| a.max((x - y).abs()));
    assert!(err > 1e-3 * wmax, "plain fit error {err}");
}

#[test]
fn fit_behind_without_blocks_is_the_plain_fit() {
    let mut rng = Rng::new(5);
    let truth = random_model(&mut rng, 6);
    let u = random_input(&mut rng, 3000);
    let mut y = vec![0.0; u.len()];
    truth.run_interpolated(&mut truth.interp_memory(), &u, &mut y);
    for v in y.iter_mut() {
        *v += 0.05 * rng.range(-1.0, 1.0);
    }
    let opts = BehindOptions { n_h: 6, u_range: (-1.0, 2.0), dt: 1e-3, tol: 1e-12, max_iter: 200 };
    let (m, rep) = fit_behind(&u, &y, None, &[], &opts).unwrap();
    let (_, plain) = fit(&u, &y, &plain_options(6)).unwrap();
    assert!((rep.rmse - plain.rmse).abs() <= 1e-9 * plain.rmse, "{} vs {}", rep.rmse, plain.rmse);
    assert!(m.masses().iter().all(|&w| w >= 0.0));
}

#[test]
fn fit_behind_rejects_bad_input_by_name() {
    let u = vec![0.0, 1.0, 0.5, 0.8];
    let opts = BehindOptions { n_h: 2, u_range: (0.0, 1.0), dt: 1e-3, tol: 1e-8, max_iter: 10 };
    let unstable = preisach_core::blocks::Section::new(0.0, [(C::new(10.0, 0.0), C::new(1.0, 0.0))]);
    assert!(unstable.unwrap_err().to_string().contains("is not stable"));
    let e = fit_behind(&u, &u[..3], None, &[], &opts).unwrap_err().to_string();
    assert!(e.starts_with("z:") && e.contains("length"), "{e}");
    let e = fit_behind(&u, &u, Some(&[1.0, -1.0, 1.0, 1.0]), &[], &opts).unwrap_err().to_string();
    assert!(e.starts_with("weights:") && e.contains("negative"), "{e}");
    let bad = BehindOptions { dt: 0.0, ..opts };
    let e = fit_behind(&u, &u, None, &[], &bad).unwrap_err().to_string();
    assert!(e.starts_with("dt:"), "{e}");
}

#[test]
fn cascade_equals_the_blocks_one_after_the_other() {
    let mut rng = Rng::new(9);
    let blocks = [creep(), mode(700.0, 0.01), mode(2300.0, 0.05), first_order(1e-4)];
    let mut l = cascade(&blocks, 2e-5);
    let x: Vec<f64> = (0..3000).map(|_| rng.range(-1.0, 1.0)).collect();
    let (mut a, mut b) = (vec![0.0; x.len()], x.clone());
    l.apply(&x, &mut a);
    // The blocks one after the other, each on its own.
    for blk in &blocks {
        let input = b.clone();
        cascade(std::slice::from_ref(blk), 2e-5).apply(&input, &mut b);
    }
    for (p, q) in a.iter().zip(&b) {
        assert!((p - q).abs() <= 1e-12 * (1.0 + q.abs()), "{p} vs {q}");
    }
}

/// Signed masses (some negative, as an unconstrained optimum has them): the Everett
/// values and offset of `pos − neg`, and their output on `u`.
fn signed_solution(rng: &mut Rng, n_h: usize, u: &[f64]) -> (Vec<f64>, Vec<f64>) {
    let (pos, neg) = (random_model(rng, n_h), random_model(rng, n_h));
    let neg =
        preisach_core::PreisachModel::new(neg.grid().clone(), neg.masses().iter().map(|m| 0.3 * m).collect(), 0.0)
            .unwrap();
    let mut x: Vec<f64> = pos.everett_values().iter().zip(neg.everett_values()).map(|(a, b)| a - b).collect();
    x.push(pos.offset());
    let (mut hp, mut hn) = (vec![0.0; u.len()], vec![0.0; u.len()]);
    pos.run_interpolated(&mut pos.interp_memory(), u, &mut hp);
    neg.run_interpolated(&mut neg.interp_memory(), u, &mut hn);
    (x, hp.iter().zip(&hn).map(|(a, b)| a - b).collect())
}

#[test]
fn projection_is_the_plain_fit_of_the_optimum_output() {
    // The oracle: `fit` of the unconstrained optimum's output on the input samples (its
    // own rows and objective), on two inputs, each with a stride of 1 and 4 (the
    // projection is on the input samples whatever the windows); twice per problem (the
    // second projection reuses the kept Hessian).
    let mut rng = Rng::new(23);
    let n = 4000;
    let walk = random_input(&mut rng, n);
    let sine: Vec<f64> = (0..n)
        .map(|k| {
            let t = k as f64 / n as f64;
            0.5 + 1.4 * (0.2 + 0.8 * t) * (std::f64::consts::TAU * 9.0 * t).sin() + 0.05 * rng.range(-1.0, 1.0)
        })
        .collect();
    let n_h = 7;
    for (u, stride) in [(&walk, 1), (&walk, 4), (&sine, 1), (&sine, 4)] {
        let mut b = preisach_core::identify::filtered::Behind::new(u, n_h, (-1.0, 2.0), stride).unwrap();
        let m = b.n_samples();
        let mut id = cascade(&[], 1e-3);
        for _ in 0..2 {
            let (x, h_star) = signed_solution(&mut rng, n_h, u);
            let z: Vec<f64> = (0..m).map(|_| rng.range(-1.0, 1.0)).collect();
            let sol = preisach_core::identify::filtered::BehindSolution {
                x,
                extra: vec![],
                iterations: 0,
                residual: 0.0,
                rmse: 0.0,
                gave_up: false,
            };
            let terms = preisach_core::identify::filtered::Terms::default();
            let (model, _, _, rep) = b.project(&sol, &z, &mut id, &terms).unwrap();
            let (plain, prep) = fit(u, &h_star, &plain_options(n_h)).unwrap();
            assert!(model.masses().iter().all(|&w| w >= 0.0));
            let span = h_star.iter().fold(0.0f64, |a, v| a.max(v.abs()));
            // The optimum's output is unique (the masses need not be).
            let (mut a, mut p) = (vec![0.0; u.len()], vec![0.0; u.len()]);
            model.run_interpolated(&mut model.interp_memory(), u, &mut a);
            plain.run_interpolated(&mut plain.interp_memory(), u, &mut p);
            let d = a.iter().zip(&p).fold(0.0f64, |e, (x, y)| e.max((x - y).abs()));
            assert!(d < 1e-5 * span, "outputs differ by {d} (span {span}, stride {stride})");
            assert!(prep.rmse > 1e-3 * span, "the masses' bound is not active: rmse {}", prep.rmse);
            assert!((rep.rmse - prep.rmse).abs() <= 1e-5 * prep.rmse, "rmse {} vs {}", rep.rmse, prep.rmse);
            assert_eq!(
                (rep.n_rows, rep.reversals, rep.cells_never_excited),
                (prep.n_rows, prep.reversals, prep.cells_never_excited)
            );
        }
    }
}

/// A random stable pole and its residue: real or complex, fast or slow against the
/// sample period.
fn random_pole(rng: &mut Rng) -> (C, C) {
    let re = -(10f64).powf(rng.range(0.5, 4.5));
    if rng.uniform() < 0.5 {
        (C::new(re, 0.0), C::new(rng.range(-2.0, 2.0) * -re, 0.0))
    } else {
        let im = -re * rng.range(0.5, 50.0);
        (C::new(re, im), C::new(rng.range(-1.0, 1.0) * im, rng.range(-1.0, 1.0) * im))
    }
}

/// Random stable sections in series: real and complex poles (several in a section, as
/// a creep of several elements or a higher-order low-pass gives), direct terms, fast and
/// slow against the sample period.
fn random_sections(rng: &mut Rng) -> Vec<Section> {
    let n_sec = 1 + (rng.next_u64() % 3) as usize;
    (0..n_sec)
        .map(|_| {
            let n_p = (rng.next_u64() % 4) as usize;
            let terms: Vec<(C, C)> = (0..n_p).map(|_| random_pole(rng)).collect();
            Section::new(rng.range(-0.5, 1.5), terms).unwrap()
        })
        .collect()
}

const DISCRETIZATIONS: [Discretization; 3] =
    [Discretization::Foh, Discretization::Zoh, Discretization::Bilinear { prewarp_hz: 1000.0 }];

#[test]
fn record_pass_is_the_per_sample_recursion_bit_for_bit() {
    let mut rng = Rng::new(17);
    for case in 0..60 {
        let sections = random_sections(&mut rng);
        let d = DISCRETIZATIONS[case % 3];
        let n = [0, 1, 2, 3, 257, 4000][case % 6];
        let x: Vec<f64> = (0..n).map(|_| rng.range(-3.0, 3.0)).collect();
        let mut pass = Filter::of(&sections, 1e-4, d);
        let mut y = vec![f64::NAN; n];
        pass.apply(&x, &mut y);
        let mut each = Filter::of(&sections, 1e-4, d);
        let steps: Vec<f64> = x.iter().map(|&v| each.step(v)).collect();
        assert_eq!(y, steps, "case {case}: {} sections, {d:?}, {n} samples", sections.len());
        if n > 0 {
            assert_eq!(pass.state(), each.state(), "case {case}: the state at the record's end");
            // And the record pass leaves the filter where the recursion goes on.
            assert_eq!(pass.step(0.5), each.step(0.5), "case {case}: the sample after the record");
        }
    }
}

#[test]
fn adjoint_is_the_transpose_of_the_record_pass() {
    let mut rng = Rng::new(29);
    for case in 0..30 {
        let sections = random_sections(&mut rng);
        let d = DISCRETIZATIONS[case % 3];
        let n = [1, 2, 3, 70][case % 4];
        let mut l = Filter::of(&sections, 1e-4, d);
        // The matrix of the record pass, column by column.
        let cols: Vec<Vec<f64>> = (0..n)
            .map(|j| {
                let mut e = vec![0.0; n];
                e[j] = 1.0;
                let mut c = vec![0.0; n];
                l.apply(&e, &mut c);
                c
            })
            .collect();
        let w: Vec<f64> = (0..n).map(|_| rng.range(-1.0, 1.0)).collect();
        let mut ltw = vec![f64::NAN; n];
        l.adjoint(&w, &mut ltw);
        let scale = cols.iter().flatten().fold(1.0f64, |m, v| m.max(v.abs()));
        for (j, c) in cols.iter().enumerate() {
            let want = dot(c, &w);
            assert!((ltw[j] - want).abs() <= 1e-12 * scale * n as f64, "case {case}, j={j}: {} vs {want}", ltw[j]);
        }
    }
}

/// Two or three sections of one pole each (a mode, a creep element, a low-pass): the
/// shape the record passes run side by side.
fn one_pole_sections(rng: &mut Rng) -> Vec<Section> {
    let n_sec = 2 + (rng.next_u64() % 2) as usize;
    (0..n_sec).map(|_| Section::new(rng.range(-0.5, 1.5), vec![random_pole(rng)]).unwrap()).collect()
}

#[test]
fn passes_of_one_pole_sections_are_the_sections_in_series_bit_for_bit() {
    let mut rng = Rng::new(31);
    for case in 0..60 {
        let sections = one_pole_sections(&mut rng);
        let d = DISCRETIZATIONS[case % 3];
        let n = [1, 2, 3, 257, 4000][case % 5];
        let x: Vec<f64> = (0..n).map(|_| rng.range(-3.0, 3.0)).collect();
        let each = |k: usize| Filter::of(std::slice::from_ref(&sections[k]), 1e-4, d);
        let mut l = Filter::of(&sections, 1e-4, d);
        let mut y = vec![f64::NAN; n];
        l.apply(&x, &mut y);
        let mut want = x.clone();
        for k in 0..sections.len() {
            let input = want.clone();
            each(k).apply(&input, &mut want);
        }
        assert_eq!(y, want, "case {case}: {} sections, {d:?}, {n} samples", sections.len());
        // The record pass leaves the state the per-sample recursion reaches.
        let mut stepped = Filter::of(&sections, 1e-4, d);
        x.iter().for_each(|&v| {
            stepped.step(v);
        });
        assert_eq!(l.state(), stepped.state(), "case {case}: the state at the record's end");
        // The adjoint: the sections' adjoints in reverse order.
        let mut g = vec![f64::NAN; n];
        l.adjoint(&x, &mut g);
        let mut want = x.clone();
        for k in (0..sections.len()).rev() {
            let input = want.clone();
            each(k).adjoint(&input, &mut want);
        }
        assert_eq!(g, want, "case {case}: the adjoint, {} sections, {d:?}, {n} samples", sections.len());
    }
}

#[test]
fn a_forked_session_solves_as_a_new_one_bit_for_bit() {
    // The oracle: a session built anew on the same input. The fork is taken from a
    // session that has solved (its warm start and delay set): the fork starts cold, as a
    // new session does, and the session it came from keeps its own state.
    use preisach_core::identify::filtered::{Behind, Stop, Terms};
    let mut rng = Rng::new(31);
    let (n_h, dt) = (6, 1e-4);
    let u = random_input(&mut rng, 3000);
    for stride in [1, 3] {
        let mut first = Behind::new(&u, n_h, (-1.0, 2.0), stride).unwrap();
        let m = first.n_samples();
        let z1: Vec<f64> = (0..m).map(|_| rng.range(-1.0, 1.0)).collect();
        let z2: Vec<f64> = (0..m).map(|_| rng.range(-1.0, 1.0)).collect();
        let blocks = [mode(700.0, 0.05)];
        let delayed = Terms { delay: 2.5, ..Terms::default() };
        let before = first.solve(&z1, &mut cascade(&blocks, dt), &delayed, &Stop::new(1e-9, 40), true).unwrap();
        let mut fork = first.fork().unwrap();
        let mut new = Behind::new(&u, n_h, (-1.0, 2.0), stride).unwrap();
        let terms = Terms::default();
        let a = fork.solve(&z2, &mut cascade(&blocks, dt), &terms, &Stop::new(1e-9, 40), true).unwrap();
        let b = new.solve(&z2, &mut cascade(&blocks, dt), &terms, &Stop::new(1e-9, 40), true).unwrap();
        assert_eq!((a.x, a.iterations, a.rmse.to_bits()), (b.x, b.iterations, b.rmse.to_bits()));
        // The first session warm-starts from its own last solve, not the fork's.
        let again = first.solve(&z1, &mut cascade(&blocks, dt), &delayed, &Stop::new(1e-9, 40), true).unwrap();
        assert!(again.iterations < before.iterations, "{} vs {}", again.iterations, before.iterations);
        assert!((again.rmse - before.rmse).abs() <= 1e-6 * before.rmse, "{} vs {}", again.rmse, before.rmse);
    }
}

#[test]
fn a_session_after_a_history_fits_the_chain_started_there() {
    // The oracle: the model's own memory run through the history's extrema, then the
    // record (an increasing sine from mid-range, as an identification record starts),
    // behind a mode. A session started after the same extrema recovers that output; one
    // started from negative saturation cannot; a stride and several histories.
    use preisach_core::identify::filtered::{Behind, Stop, Terms};
    let mut rng = Rng::new(41);
    let (n_h, dt, n) = (6, 1e-4, 4000);
    let u = increasing_sine(n, 12.0);
    let blocks = [mode(300.0, 0.05)];
    for (case, stride) in [1, 2, 1].into_iter().enumerate() {
        let truth = random_model(&mut rng, n_h);
        let extrema = [rng.range(1.0, 1.9), rng.range(-0.9, 0.0), rng.range(0.6, 0.9)];
        let mut mem = truth.interp_memory();
        let mut h = vec![0.0; n];
        truth.run_interpolated(&mut mem, &extrema, &mut vec![0.0; extrema.len()]);
        truth.run_interpolated(&mut mem, &u, &mut h);
        // (The fit's forward map: the windows' means, then the blocks at their rate.)
        let hw: Vec<f64> = h.chunks(stride).map(|c| c.iter().sum::<f64>() / c.len() as f64).collect();
        let dts = dt * stride as f64;
        let mut z = vec![0.0; hw.len()];
        cascade(&blocks, dts).apply(&hw, &mut z);
        let span = z.iter().fold(0.0f64, |a, v| a.max(v.abs()));
        let terms = Terms::default();
        let fit_rmse = |b: &mut Behind| {
            let sol = b.solve(&z, &mut cascade(&blocks, dts), &terms, &Stop::new(1e-12, 300), false).unwrap();
            b.project(&sol, &z, &mut cascade(&blocks, dts), &terms).unwrap().2
        };
        let after = fit_rmse(&mut Behind::after(&extrema, &u, n_h, (-1.0, 2.0), stride).unwrap());
        let plain = fit_rmse(&mut Behind::new(&u, n_h, (-1.0, 2.0), stride).unwrap());
        assert!(after < 1e-6 * span, "case {case}: rmse {after} (span {span})");
        assert!(plain > 1e-3 * span, "case {case}: the history left no trace: rmse {plain}");
    }
    let bad = Behind::after(&[f64::NAN], &u, n_h, (-1.0, 2.0), 1).err().unwrap().to_string();
    assert!(bad.contains("initial_extrema"), "{bad}");
}

#[test]
fn a_projection_after_a_history_is_the_nnls_of_the_record_started_there() {
    // The oracle: non-negative least squares on the dense columns of every cell's unit
    // mass (and a free offset), each column the model's own output from the memory after
    // the history's extrema. With no dynamics and no windows the projection is that fit
    // (noise makes the masses' bound active).
    use preisach_core::identify::filtered::{Behind, Stop, Terms};
    use preisach_core::identify::nnls::nnls;
    use preisach_core::{Grid, PreisachModel};
    let mut rng = Rng::new(43);
    let (n_h, n) = (5, 3000);
    let grid = Grid::new(-1.0, 2.0, n_h).unwrap();
    let u = increasing_sine(n, 9.0);
    let extrema = [1.6, -0.5, 0.8];
    let output = |m: &PreisachModel| {
        let mut mem = m.interp_memory();
        m.run_interpolated(&mut mem, &extrema, &mut [0.0; 3]);
        let mut h = vec![0.0; n];
        m.run_interpolated(&mut mem, &u, &mut h);
        h
    };
    let truth = random_model(&mut rng, n_h);
    let z: Vec<f64> = output(&truth).iter().map(|v| v + 0.3 * rng.range(-1.0, 1.0)).collect();
    let n_q = grid.n_q();
    let mut cols: Vec<Vec<f64>> = (0..n_q)
        .map(|q| output(&PreisachModel::new(grid.clone(), (0..n_q).map(|k| f64::from(k == q)).collect(), 0.0).unwrap()))
        .collect();
    cols.push(vec![1.0; n]);
    cols.push(vec![-1.0; n]);
    let a: Vec<f64> = (0..n).flat_map(|r| cols.iter().map(move |c| c[r])).collect();
    let x = nnls(&a, cols.len(), &z).unwrap();
    let want: Vec<f64> = (0..n).map(|r| cols.iter().zip(&x).map(|(c, w)| c[r] * w).sum()).collect();

    let mut b = Behind::after(&extrema, &u, n_h, (-1.0, 2.0), 1).unwrap();
    let terms = Terms::default();
    let sol = b.solve(&z, &mut cascade(&[], 1e-3), &terms, &Stop::new(1e-12, 300), false).unwrap();
    let (model, _, rmse, _) = b.project(&sol, &z, &mut cascade(&[], 1e-3), &terms).unwrap();
    let got = output(&model);
    let err = |h: &[f64]| (h.iter().zip(&z).map(|(a, b)| (a - b) * (a - b)).sum::<f64>() / n as f64).sqrt();
    assert!(err(&want) > sol.rmse * (1.0 + 1e-4), "the bound is not active: {} vs {}", err(&want), sol.rmse);
    assert!((rmse - err(&got)).abs() <= 1e-9 * rmse, "reported {rmse}, run from the history {}", err(&got));
    assert!((err(&got) - err(&want)).abs() <= 1e-6 * err(&want), "{} vs the oracle's {}", err(&got), err(&want));
    let d = got.iter().zip(&want).fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
    assert!(d < 1e-4, "outputs differ by {d}");
}

#[test]
fn a_fit_that_cannot_get_below_the_ceiling_gives_up_and_one_that_can_is_left_alone() {
    // A record behind a mode, fitted behind that mode (its optimum is the oracle: the
    // solve with no ceiling) and behind a far too slow low-pass, which no masses make
    // fit. With a ceiling the first beats, its solve is the same to the bit; the second
    // gives up early, above the ceiling and above its own optimum.
    use preisach_core::identify::filtered::{Behind, Stop, Terms};
    let mut rng = Rng::new(47);
    let (n_h, dt, n) = (8, 1e-4, 6000);
    let u = increasing_sine(n, 15.0);
    let truth = random_model(&mut rng, n_h);
    let mut h = vec![0.0; n];
    truth.run_interpolated(&mut truth.interp_memory(), &u, &mut h);
    let right = [mode(400.0, 0.04)];
    let mut z = vec![0.0; n];
    cascade(&right, dt).apply(&h, &mut z);
    z.iter_mut().for_each(|v| *v += 0.01 * rng.range(-1.0, 1.0));
    let wrong = [first_order(1.0 / (std::f64::consts::TAU * 2.0))];
    let terms = Terms::default();
    let solve = |blocks: &[Lti], above: Option<f64>| {
        let mut b = Behind::new(&u, n_h, (-1.0, 2.0), 1).unwrap();
        b.solve(&z, &mut cascade(blocks, dt), &terms, &Stop { tol: 1e-12, max_iter: 300, above }, false).unwrap()
    };
    let best = solve(&right, None);
    let kept = solve(&right, Some(1.05 * best.rmse));
    assert!(!kept.gave_up);
    assert_eq!((kept.x, kept.iterations), (best.x, best.iterations));

    let full = solve(&wrong, None);
    let ceiling = 2.0 * best.rmse;
    assert!(full.rmse > 1.5 * ceiling, "the wrong chain fits: {} vs {ceiling}", full.rmse);
    let quit = solve(&wrong, Some(ceiling));
    assert!(quit.gave_up && !full.gave_up);
    assert!(quit.iterations * 2 < full.iterations, "{} of {} iterations", quit.iterations, full.iterations);
    assert!(quit.rmse >= full.rmse && quit.rmse > ceiling, "{} vs {} and {ceiling}", quit.rmse, full.rmse);
    // A ceiling the wrong chain's optimum just beats: reached, not given up on the way.
    let near = solve(&wrong, Some(1.01 * full.rmse));
    assert!(!near.gave_up && near.rmse < 1.01 * full.rmse, "{} vs {}", near.rmse, full.rmse);

    let mut b = Behind::new(&u, n_h, (-1.0, 2.0), 1).unwrap();
    let bad =
        b.solve(&z, &mut cascade(&right, dt), &terms, &Stop { tol: 1e-6, max_iter: 10, above: Some(f64::NAN) }, false);
    assert!(bad.unwrap_err().to_string().contains("above"));
}
