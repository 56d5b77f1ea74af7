mod common;

use common::{random_input, random_model, Rng};
use preisach_core::identify::{fit, FitOptions, Solver};
use preisach_core::PreisachModel;

/// First-order reversal curves on the level grid: from the bottom up to each level a,
/// then down through every level to the bottom. Observes every Everett value.
fn forc_input(model: &PreisachModel) -> Vec<f64> {
    let g = model.grid();
    let n = g.n_h();
    let mut u = vec![g.lo() - 0.1];
    for a in 1..=n {
        for k in 0..=a {
            u.push(g.level(k));
        }
        for k in (0..a).rev() {
            u.push(g.level(k));
        }
    }
    u.push(g.hi() + 0.05);
    u
}

fn run(model: &PreisachModel, u: &[f64]) -> Vec<f64> {
    let mut y = vec![0.0; u.len()];
    model.run(&mut model.memory(), u, &mut y);
    y
}

fn opts(model: &PreisachModel, solver: Solver) -> FitOptions {
    let g = model.grid();
    FitOptions {
        n_h: g.n_h(),
        u_range: Some((g.lo(), g.hi())),
        reg: 0.0,
        solver,
        interpolated: false,
        diagonal_floor: 0.0,
    }
}

fn max_rel_err(a: &PreisachModel, b: &PreisachModel) -> f64 {
    let scale = a.masses().iter().cloned().fold(0.0, f64::max);
    let m = a.masses().iter().zip(b.masses()).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max);
    m.max((a.offset() - b.offset()).abs()) / scale
}

#[test]
fn identification_recovers_known_masses_and_offset_from_noise_free_data() {
    let mut rng = Rng::new(11);
    for solver in [Solver::Clarabel, Solver::Structured, Solver::Active] {
        let truth = random_model(&mut rng, 12);
        let u = forc_input(&truth);
        let y = run(&truth, &u);
        let (m, rep) = fit(&u, &y, &opts(&truth, solver)).unwrap();
        let err = max_rel_err(&truth, &m);
        assert!(err <= 1e-6, "{solver:?}: relative error {err}");
        assert_eq!(rep.cells_never_excited, 0);
        assert!(rep.rmse < 1e-6 * truth.everett().total());
    }
}

#[test]
fn dense_and_structured_solvers_agree_on_noisy_data() {
    let mut rng = Rng::new(12);
    let truth = random_model(&mut rng, 15);
    let u = random_input(&mut rng, 20_000);
    let mut y = run(&truth, &u);
    for v in y.iter_mut() {
        *v += 0.05 * (rng.uniform() - 0.5);
    }
    let (a, ra) = fit(&u, &y, &opts(&truth, Solver::Clarabel)).unwrap();
    let (b, rb) = fit(&u, &y, &opts(&truth, Solver::Structured)).unwrap();
    // Same objective (the solution may be non-unique in directions the data never saw).
    assert!((ra.rmse - rb.rmse).abs() <= 1e-6 * ra.rmse, "{} vs {}", ra.rmse, rb.rmse);
    let pa = run(&a, &u);
    let pb = run(&b, &u);
    let d = pa.iter().zip(&pb).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max);
    assert!(d < 1e-4 * truth.everett().total(), "predictions differ by {d}");
}

#[test]
fn active_set_solver_reaches_the_interior_point_optimum() {
    // Noisy data (many masses at zero), with and without smoothing, stepwise and
    // interpolated, and an input that never reaches the top (cells fixed to zero).
    let mut rng = Rng::new(15);
    for (k, (reg, interpolated, top)) in
        [(0.0, false, 2.5), (1e-3, false, 2.5), (0.0, true, 2.5), (0.0, false, 1.2)].into_iter().enumerate()
    {
        let truth = random_model(&mut rng, 14);
        let u: Vec<f64> = random_input(&mut rng, 15_000).into_iter().map(|v| v.min(top)).collect();
        let mut y = if interpolated {
            let mut y = vec![0.0; u.len()];
            truth.run_interpolated(&mut truth.interp_memory(), &u, &mut y);
            y
        } else {
            run(&truth, &u)
        };
        for v in y.iter_mut() {
            *v += 0.2 * (rng.uniform() - 0.5);
        }
        let mut o = opts(&truth, Solver::Active);
        o.reg = reg;
        o.interpolated = interpolated;
        let (_, ra) = fit(&u, &y, &o).unwrap();
        assert_eq!(ra.solver, "active", "case {k} fell back to the interior point");
        o.solver = Solver::Clarabel;
        let (_, rc) = fit(&u, &y, &o).unwrap();
        // The active-set point is an exact KKT point: never worse than the interior point.
        assert!(ra.rmse <= rc.rmse * (1.0 + 1e-9), "case {k}: {} vs {}", ra.rmse, rc.rmse);
        assert!(ra.rmse >= rc.rmse * (1.0 - 1e-7), "case {k}: {} vs {}", ra.rmse, rc.rmse);
    }
}

#[test]
fn admm_warm_start_saves_active_set_steps_and_changes_nothing() {
    use preisach_core::grid::Grid;
    use preisach_core::identify::{active::solve_active, qp::Problem, rows::build_rows};
    let mut rng = Rng::new(17);
    // The same problem from the ADMM guess (start = None) and from "all masses free":
    // the same optimum, in fewer factorizations. The case the guess is for: the paper's
    // identification input (a sine of growing amplitude) on a density concentrated near
    // the diagonal, noisy output, so the wide loops' masses end at zero. (On problems
    // the active-set method settles in a few steps anyway it saves nothing.)
    let n_h = 30;
    let g = Grid::new(0.0, 100.0, n_h).unwrap();
    let mut masses = Vec::with_capacity(g.n_q());
    for i in 0..n_h {
        for j in i..n_h {
            let c = (j - i) as f64 / n_h as f64 - 0.15;
            let m = (i + j) as f64 / (2 * n_h) as f64 - 0.5;
            masses.push((-(c * c) / 0.02 - m * m / 0.1).exp() / n_h as f64);
        }
    }
    let truth = PreisachModel::new(g, masses, 0.0).unwrap();
    let n = 200_000;
    let u: Vec<f64> = (0..n)
        .map(|k| {
            let t = k as f64 / (n - 1) as f64;
            50.0 + 53.0 * (0.02 + 0.98 * t) * (std::f64::consts::PI * 100.0 * t).sin() + 0.02 * (rng.uniform() - 0.5)
        })
        .collect();
    let mut y = run(&truth, &u);
    for v in y.iter_mut() {
        *v += 0.02 * (rng.uniform() - 0.5);
    }
    let grid = Grid::new(-2.0, 102.0, n_h).unwrap();
    let rows = build_rows(&grid, &u, &y, false);
    let zero = vec![false; grid.n_q()];
    let mu = y.iter().sum::<f64>() / y.len() as f64;
    let pb = Problem { rows: &rows, mu, scale: 1.0, zero: &zero, reg: 0.0 };
    let warm = solve_active(&pb, None, 100).unwrap().expect("warm start converges");
    let cold = solve_active(&pb, Some(zero.clone()), 100).unwrap().expect("cold start converges");
    assert!(2 * warm.iterations <= cold.iterations, "{} vs {} steps", warm.iterations, cold.iterations);
    let scale = cold.masses.iter().fold(0.0f64, |a, b| a.max(*b));
    for (a, b) in warm.masses.iter().zip(&cold.masses) {
        assert!((a - b).abs() <= 1e-9 * scale, "{a} vs {b}");
    }
    assert!((warm.offset - cold.offset).abs() <= 1e-9 * scale.max(1.0));
}

#[test]
fn auto_solver_is_exact_on_degenerate_interpolated_problems() {
    // Input well inside the model range: border cells never excited, many Everett values
    // unobserved. The active-set method may give up here; `auto` must still return the
    // optimum (never a non-finite model).
    let mut rng = Rng::new(16);
    for n_h in [20, 40] {
        let truth = random_model(&mut rng, n_h);
        let u: Vec<f64> = random_input(&mut rng, 30_000).into_iter().map(|v| v.clamp(-0.8, 1.8)).collect();
        let mut y = vec![0.0; u.len()];
        truth.run_interpolated(&mut truth.interp_memory(), &u, &mut y);
        for v in y.iter_mut() {
            *v += 0.1 * (rng.uniform() - 0.5);
        }
        let mut o = opts(&truth, Solver::Auto);
        o.interpolated = true;
        let (m, ra) = fit(&u, &y, &o).unwrap();
        assert!(m.offset().is_finite() && m.masses().iter().all(|w| w.is_finite() && *w >= 0.0));
        o.solver = Solver::Clarabel;
        let (_, rc) = fit(&u, &y, &o).unwrap();
        assert!(ra.rmse <= rc.rmse * (1.0 + 1e-9), "n_h {n_h}: {} ({}) vs {}", ra.rmse, ra.solver, rc.rmse);
    }
}

#[test]
fn regularization_smooths_the_weights() {
    let mut rng = Rng::new(13);
    let truth = random_model(&mut rng, 10);
    let u = random_input(&mut rng, 5000);
    let y = run(&truth, &u);
    let rough = |m: &PreisachModel| {
        let d = m.dense_weights();
        let n = m.n_h();
        let mut s = 0.0;
        for i in 0..n {
            for j in i..n - 1 {
                s += (d[i * n + j] - d[i * n + j + 1]).powi(2);
            }
        }
        s
    };
    let mut o = opts(&truth, Solver::Structured);
    let (plain, _) = fit(&u, &y, &o).unwrap();
    o.reg = 1.0;
    let (smooth, _) = fit(&u, &y, &o).unwrap();
    assert!(rough(&smooth) < 0.5 * rough(&plain));
}

#[test]
fn interpolated_model_is_recovered_from_its_own_output() {
    let mut rng = Rng::new(14);
    let truth = random_model(&mut rng, 8);
    let u = forc_input(&truth);
    // Add off-level samples so the interpolation is exercised.
    let mut uu = Vec::new();
    for w in u.windows(2) {
        uu.push(w[0]);
        uu.push(0.5 * (w[0] + w[1]));
    }
    let mut y = vec![0.0; uu.len()];
    truth.run_interpolated(&mut truth.interp_memory(), &uu, &mut y);
    let mut o = opts(&truth, Solver::Structured);
    o.interpolated = true;
    let (m, _) = fit(&uu, &y, &o).unwrap();
    assert!(max_rel_err(&truth, &m) <= 1e-6, "{}", max_rel_err(&truth, &m));
}

#[test]
fn pitfalls_are_reported() {
    let mut rng = Rng::new(15);
    let truth = random_model(&mut rng, 20);
    // Few reversals, input short of the model range.
    let u: Vec<f64> = (0..2000).map(|t| 0.5 + 0.8 * (t as f64 * 0.01).sin()).collect();
    let y = run(&truth, &u);
    let (_, rep) = fit(&u, &y, &opts(&truth, Solver::Auto)).unwrap();
    assert!(rep.warnings.iter().any(|w| w.contains("reversals")));
    assert!(rep.warnings.iter().any(|w| w.contains("does not exceed")));
    assert!(rep.cells_never_excited > 0);
    let wide: Vec<f64> = u.iter().map(|x| (x - 0.5) * 4.0 + 0.5).collect();
    let (_, rep) = fit(&wide, &run(&truth, &wide), &opts(&truth, Solver::Auto)).unwrap();
    assert!(rep.warnings.iter().any(|w| w.contains("far beyond")));
}

#[test]
fn bad_input_is_rejected_with_the_argument_named() {
    let o =
        FitOptions { n_h: 5, u_range: None, reg: 0.0, solver: Solver::Auto, interpolated: false, diagonal_floor: 0.0 };
    let e = fit(&[0.0, f64::NAN], &[0.0, 1.0], &o).unwrap_err().to_string();
    assert!(e.starts_with("u:") && e.contains("NaN at index 1"), "{e}");
    let e = fit(&[0.0, 1.0], &[0.0], &o).unwrap_err().to_string();
    assert!(e.contains("y:") && e.contains("length"), "{e}");
    let e = fit(&[], &[], &o).unwrap_err().to_string();
    assert!(e.contains("empty"), "{e}");
    let mut o2 = o.clone();
    o2.n_h = 0;
    assert!(fit(&[0.0, 1.0], &[0.0, 1.0], &o2).unwrap_err().to_string().starts_with("n_h:"));
    o2.n_h = 100_000;
    assert!(fit(&[0.0, 1.0], &[0.0, 1.0], &o2).unwrap_err().to_string().contains("too large"));
    let mut o3 = o.clone();
    o3.u_range = Some((1.0, 1.0));
    assert!(fit(&[0.0, 1.0], &[0.0, 1.0], &o3).unwrap_err().to_string().starts_with("u_range:"));
}
