//! Quick identification timing (medians and minima over repeated fits):
//!
//!     cargo run --release -p preisach-core --example prof_identify -- N_H SOLVER SAMPLES REPS [sweep|random|file:U:Y] [SEED] [interp]
//!
//! `sweep` (default): a sine of growing amplitude through a smooth density, as
//! `benches/compare.py`; `random`: a random walk through random targets (deeper
//! staircases, more rows); `file:U:Y`: input and output read from two raw
//! little-endian f64 files (the first SAMPLES of each; model range = the default
//! range of the input). `interp` fits the interpolated model. Prints the solver used,
//! its steps, the training RMSE and the median fit / solve / rows times. (`cargo bench --bench identify` is the criterion
//! version of the sweep at n_h = 20, 40, 60.)

use preisach_core::grid::Grid;
use preisach_core::identify::{fit, FitOptions, Solver, DEFAULT_DIAGONAL_FLOOR};
use preisach_core::model::PreisachModel;
use std::time::Instant;
struct Lcg(u64);
impl Lcg {
    fn next(&mut self) -> f64 {
        self.0 = self.0.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
    fn normal(&mut self) -> f64 {
        let (a, b) = (self.next().max(1e-300), self.next());
        (-2.0 * a.ln()).sqrt() * (std::f64::consts::TAU * b).cos()
    }
}
fn smooth(n: usize) -> Vec<f64> {
    let mut w = Vec::new();
    for i in 0..n {
        for j in i..n {
            let c = (j - i) as f64 / n as f64;
            let m = (i + j) as f64 / (2.0 * n as f64) - 0.5;
            let d = if i == j { 2.0 } else { 0.0 };
            w.push(((-(c - 0.15) * (c - 0.15) / 0.02 - m * m / 0.1).exp() + d) / n as f64);
        }
    }
    w
}
fn main() {
    let args: Vec<String> = std::env::args().collect();
    let n_h: usize = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(40);
    let solver = Solver::parse(args.get(2).map_or("auto", |s| s.as_str())).unwrap();
    let n: usize = args.get(3).and_then(|s| s.parse().ok()).unwrap_or(200_000);
    let reps: usize = args.get(4).and_then(|s| s.parse().ok()).unwrap_or(20);
    let seed: u64 = args.get(6).and_then(|s| s.parse().ok()).unwrap_or(7);
    let mut rng = Lcg(seed);
    let kind = args.get(5).map_or("sweep", |s| s.as_str());
    let interpolated = args.get(7).is_some_and(|s| s == "interp");
    let read = |p: &str| -> Vec<f64> {
        let b = std::fs::read(p).unwrap_or_else(|e| panic!("{p}: {e}"));
        b.chunks_exact(8).take(n).map(|c| f64::from_le_bytes(c.try_into().unwrap())).collect()
    };
    let file = kind.strip_prefix("file:").map(|s| s.split_once(':').expect("file:PATH_U:PATH_Y"));
    let u: Vec<f64> = if let Some((pu, _)) = file {
        read(pu)
    } else if kind == "random" {
        // Band-limited random input: a random walk through smoothed random targets.
        let mut v = Vec::with_capacity(n);
        let (mut x, mut target) = (50.0, 50.0);
        for k in 0..n {
            if k % 400 == 0 {
                target = 3.0 + 94.0 * rng.next();
            }
            x += 0.02 * (target - x);
            v.push(x + 0.02 * rng.normal());
        }
        v
    } else {
        (0..n)
            .map(|k| {
                let t = k as f64 / (n - 1) as f64;
                50.0 + 53.0 * (0.02 + 0.98 * t) * (std::f64::consts::PI * 100.0 * t).sin() + 0.02 * rng.normal()
            })
            .collect()
    };
    let y = if let Some((_, py)) = file {
        read(py)
    } else {
        let truth = PreisachModel::new(Grid::new(0.0, 100.0, n_h).unwrap(), smooth(n_h), 0.0).unwrap();
        let mut y = vec![0.0; n];
        truth.run(&mut truth.memory(), &u, &mut y);
        for v in &mut y {
            *v += 0.01 * rng.normal();
        }
        y
    };
    let (mn, mx) = u.iter().fold((f64::MAX, f64::MIN), |(a, b), &x| (a.min(x), b.max(x)));
    let rg = (mn + 0.005 * (mx - mn), mx - 0.005 * (mx - mn));
    let opts =
        FitOptions { n_h, u_range: Some(rg), reg: 0.0, solver, interpolated, diagonal_floor: DEFAULT_DIAGONAL_FLOOR };
    let mut ts = vec![];
    let mut ss = vec![];
    let mut rs = vec![];
    let mut rep = None;
    for _ in 0..reps {
        let t0 = Instant::now();
        let (_m, r) = fit(&u, &y, &opts).unwrap();
        ts.push(t0.elapsed().as_secs_f64());
        ss.push(r.time_solve_s);
        rs.push(r.time_rows_s);
        rep = Some(r);
    }
    let med = |v: &mut Vec<f64>| {
        v.sort_by(|a, b| a.partial_cmp(b).unwrap());
        v[v.len() / 2] * 1e3
    };
    let r = rep.unwrap();
    let (mt, ms) = (med(&mut ts), med(&mut ss));
    println!("n_h={n_h} solver={} rows={} it={} rmse={:.12e} fit {:.2} ms solve {:.2} ms rows {:.2} ms (min fit {:.2} solve {:.2})", r.solver, r.n_rows, r.iterations, r.rmse, mt, ms, med(&mut rs), ts[0] * 1e3, ss[0] * 1e3);
}
