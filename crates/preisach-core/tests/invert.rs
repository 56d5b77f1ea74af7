//! Inversion (seed §4.1): closest match against a brute-force oracle, the tie rule, the
//! interpolation of Fig. 9 (offline vs streaming), the continuous inverse.
mod common;

use std::sync::Arc;

use common::{random_model, Rng};
use preisach_core::invert::{self, interpolate, Inverter, Method};
use preisach_core::model::StepMemory;
use preisach_core::{Grid, PreisachModel};

/// Outputs after moving to every level, by cloning the memory and stepping it (the
/// oracle: no peek, no search).
fn brute_outputs(model: &PreisachModel, mem: &StepMemory) -> Vec<f64> {
    let e = model.e_step();
    (0..=model.n_h() as u32)
        .map(|k| {
            let mut m = mem.clone();
            m.apply(k, &e);
            model.output_of(m.s_plus(&e))
        })
        .collect()
}

/// A model with many zero masses: long plateaus of equal output.
fn sparse_model(rng: &mut Rng, n_h: usize) -> PreisachModel {
    let grid = Grid::new(0.0, 1.0, n_h).unwrap();
    let masses = (0..grid.n_q()).map(|_| if rng.uniform() < 0.8 { 0.0 } else { rng.uniform() }).collect();
    PreisachModel::new(grid, masses, rng.range(-1.0, 1.0)).unwrap()
}

/// References as a random walk with jumps over [ymin − 30 %, ymax + 30 %] of the output
/// span, sometimes repeating a value exactly (ties against the previous output).
fn random_reference(rng: &mut Rng, model: &PreisachModel, n: usize) -> Vec<f64> {
    let total = model.everett().total();
    let (ymin, ymax) = (model.offset() - total, model.offset() + total);
    let span = (ymax - ymin).max(1.0);
    let mut r = 0.5 * (ymin + ymax);
    (0..n)
        .map(|_| {
            let c = rng.uniform();
            if c < 0.1 {
                r = rng.range(ymin - 0.3 * span, ymax + 0.3 * span);
            } else if c < 0.9 {
                r += rng.range(-0.05, 0.05) * span;
            }
            r
        })
        .collect()
}

#[test]
fn closest_match_is_optimal_at_every_sample_and_ties_go_to_the_nearest_level() {
    let mut rng = Rng::new(11);
    let mut saturated_seen = 0;
    let mut ties_seen = 0;
    for trial in 0..24 {
        let n_h = [1usize, 2, 3, 5, 8, 13, 30, 60][trial % 8];
        let model = Arc::new(if trial % 2 == 0 { random_model(&mut rng, n_h) } else { sparse_model(&mut rng, n_h) });
        let tol = invert::tolerance(&model);
        let r = random_reference(&mut rng, &model, 1500);
        let mut inv = Inverter::new(model.clone(), Method::Closest, None).unwrap();
        let mut mirror = model.memory();
        let mut n_sat = 0u64;
        for (t, &x) in r.iter().enumerate() {
            let ys = brute_outputs(&model, &mirror);
            let p = mirror.current() as i64;
            let u = inv.step(x);
            let k = model.grid().quantize(u) as i64;
            assert_eq!(model.grid().level(k as usize), u, "output must be a level");
            let err: Vec<f64> = ys.iter().map(|y| (y - x).abs()).collect();
            let e_min = err.iter().cloned().fold(f64::INFINITY, f64::min);
            assert!(
                err[k as usize] <= e_min + 2.0 * tol,
                "trial {trial} t={t}: level {k} err {} > best {e_min}",
                err[k as usize]
            );
            // Tie rule: no level strictly nearer the previous one is (near-)optimal.
            for (j, &ej) in err.iter().enumerate() {
                if (j as i64 - p).abs() < (k - p).abs() {
                    assert!(ej > e_min + 0.5 * tol, "trial {trial} t={t}: level {j} nearer {p} ties with chosen {k}");
                }
            }
            if err.iter().filter(|&&e| e <= e_min + 0.5 * tol).count() > 1 {
                ties_seen += 1;
            }
            let (ylo, yhi) = (ys.iter().cloned().fold(f64::INFINITY, f64::min), ys.iter().cloned().fold(f64::NEG_INFINITY, f64::max));
            if x < ylo - tol || x > yhi + tol {
                n_sat += 1;
            }
            mirror.apply(k as u32, &model.e_step());
        }
        assert_eq!(inv.saturated(), n_sat, "trial {trial}: saturation count");
        saturated_seen += n_sat;
    }
    assert!(saturated_seen > 100, "the test must exercise references outside the range");
    assert!(ties_seen > 100, "the test must exercise plateaus");
}

#[test]
fn closest_match_tie_rule_on_a_model_with_plateaus() {
    // n_h = 6, only cells (0,0) and (5,5) carry mass 1: from negative saturation
    // y(0) = -2, y(1..=5) = 0, y(6) = 2.
    let n_h = 6;
    let mut dense = vec![0.0; n_h * n_h];
    dense[0] = 1.0;
    dense[5 * n_h + 5] = 1.0;
    let model = Arc::new(PreisachModel::from_dense(0.0, 6.0, n_h, &dense, 0.0).unwrap());
    let mut inv = Inverter::new(model, Method::Closest, None).unwrap();
    // (reference, expected level): plateaus pick the end nearest the previous level.
    let script = [
        (0.0, 1.0),  // plateau 1..=5 from level 0 -> 1
        (0.0, 1.0),  // stays
        (2.0, 6.0),  // top
        (0.1, 5.0),  // plateau 1..=5 from level 6 -> 5
        (1.0, 5.0),  // tie between y=0 (levels 1..=5) and y=2 (level 6): stay at 5
        (-1.0, 5.0), // tie between y=-2 (level 0) and y=0 (1..=5): nearest 5
        (-5.0, 0.0), // below the range: saturates at level 0
        (-1.0, 0.0), // tie between level 0 and levels 1..=5: stay at 0
        (9.0, 6.0),  // above the range
    ];
    for (i, &(r, want)) in script.iter().enumerate() {
        assert_eq!(inv.step(r), want, "step {i}: r = {r}");
    }
    assert_eq!(inv.saturated(), 2);
}

#[test]
fn forward_model_on_closest_match_stays_within_half_the_local_step() {
    let mut rng = Rng::new(12);
    for n_h in [2usize, 7, 25, 80] {
        let model = random_model(&mut rng, n_h);
        let tol = invert::tolerance(&model);
        let total = model.everett().total();
        let (ymin, ymax) = (model.offset() - total, model.offset() + total);
        let r: Vec<f64> = random_reference(&mut rng, &model, 2000).into_iter().map(|x| x.clamp(ymin, ymax)).collect();
        let (u, sat) = invert::invert(&model, &r, Method::Closest, None).unwrap();
        assert_eq!(sat, 0);
        let mut fwd = model.memory();
        let mut mirror = model.memory();
        for (t, (&x, &ut)) in r.iter().zip(&u).enumerate() {
            let ys = brute_outputs(&model, &mirror);
            let k1 = ys.iter().position(|&y| y >= x).unwrap_or(n_h);
            let step = if k1 == 0 { 0.0 } else { ys[k1] - ys[k1 - 1] };
            let y = model.step(&mut fwd, ut);
            assert!((y - x).abs() <= 0.5 * step + tol, "n_h={n_h} t={t}: |{y} - {x}| > half step {step}");
            mirror.apply(model.grid().quantize(ut), &model.e_step());
        }
    }
}

/// A random model without diagonal masses: its interpolated output is continuous (the
/// bilinear Everett table puts part of a diagonal cell's mass below the diagonal, which
/// makes `y_c` jump at a reversal inside that cell; see `invert.rs`).
fn off_diagonal_model(rng: &mut Rng, n_h: usize, sparse: bool) -> PreisachModel {
    let base = if sparse { sparse_model(rng, n_h) } else { random_model(rng, n_h) };
    let mut d = base.dense_weights();
    for i in 0..n_h {
        d[i * n_h + i] = 0.0;
    }
    PreisachModel::from_dense(0.0, 1.0, n_h, &d, base.offset()).unwrap()
}

#[test]
fn continuous_inverse_reproduces_reachable_references_through_the_interpolated_model() {
    let mut rng = Rng::new(13);
    for trial in 0..12 {
        let n_h = [2usize, 3, 10, 40][trial % 4];
        let model = off_diagonal_model(&mut rng, n_h, trial % 3 == 2);
        let total = model.everett().total();
        let (ymin, ymax) = (model.offset() - total, model.offset() + total);
        let r: Vec<f64> = random_reference(&mut rng, &model, 3000).into_iter().map(|x| x.clamp(ymin, ymax)).collect();
        let (u, sat) = invert::invert(&model, &r, Method::Continuous, None).unwrap();
        assert_eq!(sat, 0);
        let mut mem = model.interp_memory();
        let mut y = vec![0.0; u.len()];
        model.run_interpolated(&mut mem, &u, &mut y);
        for t in 0..r.len() {
            assert!((y[t] - r[t]).abs() <= 1e-9, "trial {trial} t={t}: {} vs {}", y[t], r[t]);
            assert!(u[t] >= model.grid().lo() && u[t] <= model.grid().hi());
        }
    }
}

#[test]
fn continuous_inverse_is_optimal_against_a_fine_grid_even_where_the_output_jumps() {
    // With diagonal masses y_c can jump at a reversal, so some references have no exact
    // preimage; the inverse must still be at least as good as any input on a fine grid.
    let mut rng = Rng::new(18);
    for trial in 0..6 {
        let n_h = [1usize, 4, 12][trial % 3];
        let model = random_model(&mut rng, n_h);
        let tol = invert::tolerance(&model);
        let r = random_reference(&mut rng, &model, 600);
        let mut mem = model.interp_memory();
        let grid: Vec<f64> = (0..=4000).map(|i| n_h as f64 * i as f64 / 4000.0).collect();
        for (t, &x) in r.iter().enumerate() {
            let best = grid.iter().map(|&p| (model.peek_position(&mem, p) - x).abs()).fold(f64::INFINITY, f64::min);
            let (p, _) = invert::continuous_position(&model, &mem, x, tol);
            let err = (model.peek_position(&mem, p) - x).abs();
            assert!(err <= best + 1e-9, "trial {trial} t={t}: err {err} > grid best {best}");
            mem.apply(p, &model.e_interp());
        }
    }
}

#[test]
fn continuous_inverse_saturates_out_of_range_and_stays_put_on_plateaus() {
    // Same plateau model as above, interpolated: y_c = -2 at 0, rises to 0 at position
    // 1, flat to 5, rises to 2 at 6 (from negative saturation).
    let n_h = 6;
    let mut dense = vec![0.0; n_h * n_h];
    dense[0] = 1.0;
    dense[5 * n_h + 5] = 1.0;
    let model = Arc::new(PreisachModel::from_dense(0.0, 6.0, n_h, &dense, 0.0).unwrap());
    let mut inv = Inverter::new(model, Method::Continuous, None).unwrap();
    assert!((inv.step(-1.0) - 0.5).abs() < 1e-12); // halfway up the first ramp
    assert!((inv.step(0.0) - 1.0).abs() < 1e-9); // near end of the plateau
    assert_eq!(inv.step(0.0), inv.step(0.0)); // stays put
    assert!((inv.step(1.0) - 5.5).abs() < 1e-12);
    assert_eq!(inv.step(7.0), 6.0); // above: hi
    assert!((inv.step(0.0) - 5.0).abs() < 1e-9); // plateau from above: its upper end
    assert_eq!(inv.step(-3.0), 0.0); // below: lo
    assert_eq!(inv.saturated(), 2);
}

#[test]
fn interpolation_passes_through_the_riser_midpoints() {
    // Hand-computed (seed Fig. 9): steps at t = 3 (0 -> 1) and t = 7 (1 -> 3).
    let cm = [0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 1.0, 3.0, 3.0, 3.0];
    let mut u = [0.0; 10];
    interpolate(&cm, None, &mut u);
    // Knots (0, 0), (3, 0.5), (7, 2), end (9, 3).
    let want = [0.0, 1.0 / 6.0, 2.0 / 6.0, 0.5, 0.875, 1.25, 1.625, 2.0, 2.5, 3.0];
    for t in 0..10 {
        assert!((u[t] - want[t]).abs() < 1e-15, "t={t}: {} vs {}", u[t], want[t]);
    }
    // Look-ahead 1: window [t, t+1]; pseudo-knot (t+1, cm[t+1]) when no step in it.
    let cm = [0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0];
    interpolate(&cm, Some(1), &mut u);
    let want = [0.0, 0.0, 0.25, 0.5, 0.75, 0.875, 0.9375, 0.96875, 0.984375, 1.0];
    assert_eq!(u, want);
    // Look-ahead 0 is the closest match except at the step samples (the midpoint).
    interpolate(&cm, Some(0), &mut u);
    assert_eq!(u, [0.0, 0.0, 0.0, 0.5, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0]);
}

#[test]
fn streaming_interpolation_equals_offline_delayed_by_the_lookahead() {
    let mut rng = Rng::new(14);
    for &l in &[0usize, 1, 2, 5, 17, 200, 3000] {
        let model = Arc::new(random_model(&mut rng, 20));
        let r = random_reference(&mut rng, &model, 2500);
        let (off, _) = invert::invert(&model, &r, Method::Interpolated, Some(l)).unwrap();
        let mut inv = Inverter::new(model.clone(), Method::Interpolated, Some(l)).unwrap();
        let lo = model.grid().lo();
        for (t, &x) in r.iter().enumerate() {
            let u = inv.step(x);
            let want = if t < l { lo } else { off[t - l] };
            assert_eq!(u.to_bits(), want.to_bits(), "L={l} t={t}");
        }
        // The offline interpolation starts from the closest match's own values.
        let (cm, _) = invert::invert(&model, &r, Method::Closest, None).unwrap();
        assert_eq!(off[0], cm[0]);
        assert_eq!(off[r.len() - 1], if cm[r.len() - 1] != cm[r.len() - 2] { 0.5 * (cm[r.len() - 2] + cm[r.len() - 1]) } else { cm[r.len() - 1] });
    }
}

#[test]
fn snapshot_restore_resumes_exactly() {
    let mut rng = Rng::new(15);
    let model = Arc::new(random_model(&mut rng, 30));
    let r = random_reference(&mut rng, &model, 4000);
    for (method, l) in [(Method::Closest, None), (Method::Interpolated, Some(37)), (Method::Continuous, None)] {
        let mut a = Inverter::new(model.clone(), method, l).unwrap();
        let mut first = vec![0.0; 1733];
        a.process(&r[..1733], &mut first).unwrap();
        let snap = a.state();
        let mut rest_a = vec![0.0; r.len() - 1733];
        a.process(&r[1733..], &mut rest_a).unwrap();
        let mut b = Inverter::new(model.clone(), method, l).unwrap();
        b.step(r[5]); // some unrelated history, overwritten by the snapshot
        b.set_state(&snap).unwrap();
        assert_eq!(b.state(), snap);
        let mut rest_b = vec![0.0; r.len() - 1733];
        b.process(&r[1733..], &mut rest_b).unwrap();
        assert_eq!(rest_a, rest_b, "{method:?}");
        assert_eq!(a.saturated(), b.saturated());
        assert!(a.saturated() > 0);
        // reset = a fresh inverter
        a.reset();
        let mut fresh = Inverter::new(model.clone(), method, l).unwrap();
        assert_eq!(a.step(r[0]), fresh.step(r[0]));
    }
}

#[test]
fn nan_names_the_first_bad_index_and_empty_is_empty() {
    let mut rng = Rng::new(16);
    let model = random_model(&mut rng, 5);
    let mut r = vec![0.1; 30];
    r[17] = f64::NAN;
    r[20] = f64::NAN;
    for m in [Method::Closest, Method::Interpolated, Method::Continuous] {
        let e = invert::invert(&model, &r, m, None).unwrap_err();
        assert_eq!(e.to_string(), "r: NaN at index 17");
        assert!(invert::invert(&model, &[], m, None).unwrap().0.is_empty());
    }
    let mut inv = Inverter::new(Arc::new(model.clone()), Method::Closest, None).unwrap();
    let mut out = vec![0.0; 30];
    assert_eq!(inv.process(&r, &mut out).unwrap_err().to_string(), "r: NaN at index 17");
    assert_eq!(inv.state().memory, vec![0.0], "a rejected block leaves the state untouched");
}

#[test]
fn method_and_lookahead_are_validated() {
    let e = "nearest".parse::<Method>().unwrap_err().to_string();
    assert!(e.starts_with("method: expected one of"), "{e}");
    let mut rng = Rng::new(17);
    let model = Arc::new(random_model(&mut rng, 5));
    assert!(Inverter::new(model.clone(), Method::Interpolated, None).unwrap_err().to_string().starts_with("lookahead:"));
    assert!(Inverter::new(model.clone(), Method::Closest, Some(3)).unwrap_err().to_string().starts_with("lookahead:"));
    assert!(invert::invert(&model, &[0.0], Method::Continuous, Some(0)).is_err());
    let mut inv = Inverter::new(model, Method::Interpolated, Some(4)).unwrap();
    let mut s = inv.state();
    s.memory = vec![2.5];
    assert!(inv.set_state(&s).unwrap_err().to_string().starts_with("state:"));
}
