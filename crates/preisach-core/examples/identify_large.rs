//! Identification at large n_h from 10^6 samples (the benchmark workload of
//! benches/compare.py: a sine of growing amplitude with noise, a smooth density):
//! wall time and peak resident memory (VmHWM) per solver.
//!
//!   cargo run --release -p preisach-core --example identify_large -- 300 structured
use std::time::Instant;

use preisach_core::grid::Grid;
use preisach_core::identify::{fit, FitOptions, Solver, DEFAULT_DIAGONAL_FLOOR};
use preisach_core::model::PreisachModel;

fn peak_rss_mb() -> f64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| s.lines().find(|l| l.starts_with("VmHWM:")).map(|l| l.to_string()))
        .and_then(|l| l.split_whitespace().nth(1).and_then(|v| v.parse::<f64>().ok()))
        .map_or(f64::NAN, |kb| kb / 1024.0)
}

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
    let mut w = Vec::with_capacity(n * (n + 1) / 2);
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
    let n_h: usize = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(300);
    let solver = Solver::parse(args.get(2).map_or("structured", |s| s.as_str())).expect("solver");
    let n = 1_000_000;
    let mut rng = Lcg(1);
    let u: Vec<f64> = (0..n)
        .map(|k| {
            let t = k as f64 / (n - 1) as f64;
            let amp = 0.02 + 0.98 * t;
            50.0 + 53.0 * amp * (std::f64::consts::PI * 100.0 * t).sin() + 0.02 * rng.normal()
        })
        .collect();
    let truth = PreisachModel::new(Grid::new(0.0, 100.0, 100).unwrap(), smooth(100), 0.0).unwrap();
    let mut y = vec![0.0; n];
    truth.run(&mut truth.memory(), &u, &mut y);
    for v in &mut y {
        *v += 1e-3 * rng.normal();
    }
    let base = peak_rss_mb();
    let t0 = Instant::now();
    let opts = FitOptions {
        n_h,
        u_range: None,
        reg: 0.0,
        solver,
        interpolated: false,
        diagonal_floor: DEFAULT_DIAGONAL_FLOOR,
    };
    let (_m, rep) = fit(&u, &y, &opts).expect("fit");
    let dt = t0.elapsed().as_secs_f64();
    println!(
        "n_h={n_h} solver={} rows={} time={dt:.2}s peak_rss={:.0}MB (data {base:.0}MB) rmse={:.6e} iterations={}",
        rep.solver,
        rep.n_rows,
        peak_rss_mb(),
        rep.rmse,
        rep.iterations
    );
}
