//! Inversion (the paper §4.1): closest match against a brute-force oracle, the tie rule, the
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
            let (ylo, yhi) = (
                ys.iter().cloned().fold(f64::INFINITY, f64::min),
                ys.iter().cloned().fold(f64::NEG_INFINITY, f64::max),
            );
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

#[test]
fn continuous_inverse_reproduces_reachable_references_through_the_interpolated_model() {
    // Random models WITH diagonal masses (dense and sparse): the interpolated output is
    // continuous everywhere (diagonal mass along the diagonal), so every reachable
    // reference has an exact preimage and must be reproduced to rounding.
    let mut rng = Rng::new(13);
    let mut reversals_in_diagonal_cells = 0usize;
    for trial in 0..16 {
        let n_h = [1usize, 2, 3, 10, 40, 7, 25, 60][trial % 8];
        let model = if trial % 3 == 2 { sparse_model(&mut rng, n_h) } else { random_model(&mut rng, n_h) };
        assert!((0..n_h).any(|i| model.dense_weights()[i * n_h + i] > 0.0) || trial % 3 == 2);
        let total = model.everett().total();
        let (ymin, ymax) = (model.offset() - total, model.offset() + total);
        let r: Vec<f64> = random_reference(&mut rng, &model, 3000).into_iter().map(|x| x.clamp(ymin, ymax)).collect();
        let (u, sat) = invert::invert(&model, &r, Method::Continuous, None).unwrap();
        assert_eq!(sat, 0);
        let mut mem = model.interp_memory();
        let mut y = vec![0.0; u.len()];
        model.run_interpolated(&mut mem, &u, &mut y);
        let scale = (ymax - ymin).max(f64::MIN_POSITIVE);
        for t in 0..r.len() {
            assert!((y[t] - r[t]).abs() <= 1e-9 * scale, "trial {trial} n_h={n_h} t={t}: {} vs {}", y[t], r[t]);
            assert!(u[t] >= model.grid().lo() && u[t] <= model.grid().hi());
        }
        // The test must exercise reversals at fractional positions (inside cells).
        reversals_in_diagonal_cells += u
            .windows(3)
            .filter(|w| (w[1] - w[0]) * (w[2] - w[1]) < 0.0 && model.grid().position(w[1]).fract() != 0.0)
            .count();
    }
    assert!(reversals_in_diagonal_cells > 1000, "{reversals_in_diagonal_cells}");
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
fn saturation_counts_what_every_method_clips_and_finds_the_first() {
    let mut rng = Rng::new(71);
    for n_h in [1, 4, 30] {
        let model = Arc::new(sparse_model(&mut rng, n_h));
        let r = random_reference(&mut rng, &model, 500);
        // Oracle: the outputs at the ends of the input range, run through the model.
        let y_lo = model.step(&mut model.memory(), model.grid().lo());
        let y_hi = model.step(&mut model.memory(), model.grid().hi());
        let (a, b) = invert::reachable(&model);
        assert!((a - y_lo).abs() <= 1e-12 && (b - y_hi).abs() <= 1e-12, "{a} {b} vs {y_lo} {y_hi}");
        let out = |x: &f64| *x < y_lo || *x > y_hi;
        let (count, first) = invert::saturation(&model, &r);
        assert_eq!(count, r.iter().filter(|x| out(x)).count() as u64);
        assert_eq!(first, r.iter().position(out));
        assert!(count > 0);
        for method in [Method::Closest, Method::Interpolated, Method::Continuous] {
            assert_eq!(invert::invert(&model, &r, method, None).unwrap().1, count, "{method:?}");
            let lookahead = (method == Method::Interpolated).then_some(7);
            let mut inv = Inverter::new(model.clone(), method, lookahead).unwrap();
            let mut u = vec![0.0; r.len()];
            inv.process(&r, &mut u).unwrap();
            assert_eq!(inv.saturated(), count, "{method:?}");
        }
    }
}

/// The monotone closest match over a whole reference (what the interpolation is built on).
fn monotone_cm(model: &PreisachModel, r: &[f64]) -> Vec<f64> {
    let mut cm = vec![0.0; r.len()];
    invert::monotone_run(model, &mut model.memory(), invert::NO_PREVIOUS_REFERENCE, r, &mut cm);
    cm
}

#[test]
fn monotone_closest_match_is_optimal_among_the_levels_on_the_references_side() {
    // Oracle: every level tried on a copy of the memory; the allowed levels are those
    // at or above the current one when the reference rises, at or below when it falls,
    // only the current one when it is constant.
    let mut rng = Rng::new(21);
    let (mut ties_seen, mut sat_seen, mut restricted_seen) = (0, 0u64, 0);
    for trial in 0..24 {
        let n_h = [1usize, 2, 3, 5, 8, 13, 30, 60][trial % 8];
        let model = if trial % 2 == 0 { random_model(&mut rng, n_h) } else { sparse_model(&mut rng, n_h) };
        let tol = invert::tolerance(&model);
        let r = random_reference(&mut rng, &model, 1500);
        let mut mem = model.memory();
        let mut r_prev = invert::NO_PREVIOUS_REFERENCE;
        let mut cm = vec![0.0; r.len()];
        let (n_sat, _) = invert::monotone_run(&model, &mut model.memory(), r_prev, &r, &mut cm);
        let mut n_sat_oracle = 0u64;
        for (t, &x) in r.iter().enumerate() {
            let ys = brute_outputs(&model, &mem);
            let p = mem.current() as usize;
            let allowed: Vec<usize> = if x > r_prev {
                (p..=n_h).collect()
            } else if x < r_prev {
                (0..=p).collect()
            } else {
                vec![p]
            };
            let (k, s) = invert::monotone_level(&model, &mem, x, r_prev, tol);
            let k = k as usize;
            assert_eq!(model.grid().level(k), cm[t], "trial {trial} t={t}: run and single step differ");
            assert!(allowed.contains(&k), "trial {trial} t={t}: level {k} against the reference (from {p})");
            let err = |j: usize| (ys[j] - x).abs();
            let e_min = allowed.iter().map(|&j| err(j)).fold(f64::INFINITY, f64::min);
            assert!(
                err(k) <= e_min + 2.0 * tol,
                "trial {trial} t={t}: level {k} err {} > best allowed {e_min}",
                err(k)
            );
            for &j in &allowed {
                if j.abs_diff(p) < k.abs_diff(p) {
                    assert!(err(j) > e_min + 0.5 * tol, "trial {trial} t={t}: level {j} nearer {p} ties with {k}");
                }
            }
            if allowed.iter().filter(|&&j| err(j) <= e_min + 0.5 * tol).count() > 1 {
                ties_seen += 1;
            }
            // Where the unrestricted optimum lies on the other side, the restriction binds.
            let e_all = (0..=n_h).map(err).fold(f64::INFINITY, f64::min);
            if e_all + tol < e_min {
                restricted_seen += 1;
            }
            let (ylo, yhi) = (
                ys.iter().cloned().fold(f64::INFINITY, f64::min),
                ys.iter().cloned().fold(f64::NEG_INFINITY, f64::max),
            );
            if x < ylo - tol || x > yhi + tol {
                n_sat_oracle += 1;
                assert!(s);
            }
            mem.apply(k as u32, &model.e_step());
            r_prev = x;
        }
        assert_eq!(n_sat, n_sat_oracle, "trial {trial}: saturation count");
        sat_seen += n_sat;
    }
    assert!(sat_seen > 100 && ties_seen > 100 && restricted_seen > 100, "{sat_seen} {ties_seen} {restricted_seen}");
}

/// References made of monotone segments (alternating direction, 20..400 samples each,
/// small steps, some repeats, some jumps), beyond the range at times.
fn segmented_reference(rng: &mut Rng, model: &PreisachModel, n_seg: usize) -> (Vec<f64>, Vec<(usize, usize, f64)>) {
    let total = model.everett().total();
    let (ymin, ymax) = (model.offset() - total, model.offset() + total);
    let span = (ymax - ymin).max(1.0);
    let (lo, hi) = (ymin - 0.1 * span, ymax + 0.1 * span);
    let mut r = vec![ymin - 0.2 * span];
    let mut segs = Vec::new();
    let mut dir = 1.0;
    for _ in 0..n_seg {
        let len = 20 + (rng.uniform() * 380.0) as usize;
        let slope = rng.range(0.0, 0.01) * span;
        let a = r.len();
        let mut x = *r.last().unwrap();
        // A segment must move: its first step goes strictly in `dir` (away from a bound).
        x = if dir > 0.0 { x.min(hi - 0.05 * span) } else { x.max(lo + 0.05 * span) };
        for i in 0..len {
            let c = rng.uniform();
            let d = if i == 0 {
                0.01 * span + slope
            } else if c < 0.1 {
                0.0
            } else if c < 0.13 {
                0.2 * span
            } else {
                slope * rng.uniform()
            };
            x = (x + dir * d).clamp(lo, hi);
            r.push(x);
        }
        // Keep only the part that actually moves monotonically (clamping may flatten it).
        segs.push((a, r.len() - 1, dir));
        dir = -dir;
    }
    (r, segs)
}

/// `u` on `[a, end]` never moves against `dir` after it has first moved with it (at most
/// one turn, carried over from the previous segment's knots, then monotone).
fn assert_unimodal(u: &[f64], a: usize, end: usize, dir: f64, what: &str) {
    let mut turned = false;
    for t in a + 1..=end {
        let d = (u[t] - u[t - 1]) * dir;
        if d > 0.0 {
            turned = true;
        } else if d < 0.0 {
            assert!(
                !turned,
                "{what}: u moves against the reference at t={t} in [{a}, {end}] ({} -> {})",
                u[t - 1],
                u[t]
            );
        }
    }
}

#[test]
fn interpolated_inverse_is_monotone_on_monotone_reference_segments() {
    let mut rng = Rng::new(22);
    let mut checked = 0usize;
    for trial in 0..12 {
        let n_h = [3usize, 10, 30, 80][trial % 4];
        let model = if trial % 3 == 2 { sparse_model(&mut rng, n_h) } else { random_model(&mut rng, n_h) };
        let (r, segs) = segmented_reference(&mut rng, &model, 40);
        let cm = monotone_cm(&model, &r);
        let (u_off, _) = invert::invert(&model, &r, Method::Interpolated, None).unwrap();
        for &(a, b, dir) in &segs {
            // The monotone closest match itself never moves against the reference.
            for t in a..=b {
                assert!((cm[t] - cm[t - 1]) * dir >= 0.0, "trial {trial} t={t}: closest match reverses");
            }
            // Offline: piecewise linear through knots that are all monotone inside the
            // segment: monotone from the first knot in it to the last.
            let knots: Vec<usize> = (a..=b).filter(|&t| cm[t] != cm[t - 1]).collect();
            if let (Some(&k0), Some(&k1)) = (knots.first(), knots.last()) {
                for t in k0 + 1..=k1 {
                    assert!((u_off[t] - u_off[t - 1]) * dir >= 0.0, "trial {trial} offline t={t} in [{k0}, {k1}]");
                }
                assert_unimodal(&u_off, a - 1, k1, dir, &format!("trial {trial} offline"));
                checked += 1;
            }
            // Finite look-ahead: the targets inside [a, b − L] are monotone, so the output
            // turns at most once (finishing the previous segment's ramp) then follows.
            for l in [0usize, 1, 7, 50] {
                if b >= a + l {
                    let (u, _) = invert::invert(&model, &r, Method::Interpolated, Some(l)).unwrap();
                    assert_unimodal(&u, a - 1, b - l, dir, &format!("trial {trial} L={l}"));
                }
            }
        }
    }
    assert!(checked > 300, "{checked}");
}

#[test]
fn interpolation_passes_through_the_riser_midpoints() {
    // Hand-computed (the paper's Fig. 9): steps at t = 3 (0 -> 1) and t = 7 (1 -> 3).
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
        // The offline interpolation starts from the monotone closest match's own values.
        let cm = monotone_cm(&model, &r);
        assert_eq!(off[0], cm[0]);
        assert_eq!(
            off[r.len() - 1],
            if cm[r.len() - 1] != cm[r.len() - 2] {
                0.5 * (cm[r.len() - 2] + cm[r.len() - 1])
            } else {
                cm[r.len() - 1]
            }
        );
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
    assert!(Inverter::new(model.clone(), Method::Interpolated, None)
        .unwrap_err()
        .to_string()
        .starts_with("lookahead:"));
    assert!(Inverter::new(model.clone(), Method::Closest, Some(3)).unwrap_err().to_string().starts_with("lookahead:"));
    assert!(invert::invert(&model, &[0.0], Method::Continuous, Some(0)).is_err());
    let mut inv = Inverter::new(model, Method::Interpolated, Some(4)).unwrap();
    let mut s = inv.state();
    s.memory = vec![2.5];
    assert!(inv.set_state(&s).unwrap_err().to_string().starts_with("state:"));
}
