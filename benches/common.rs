//! Shared by the criterion benches (`#[path = "common.rs"] mod common;`).

use preisach_core::{Grid, PreisachModel};

/// A smooth density: Gaussian ridge near the diagonal plus a diagonal part.
pub fn smooth_model(n_h: usize) -> PreisachModel {
    let grid = Grid::new(0.0, 100.0, n_h).unwrap();
    let mut masses = Vec::with_capacity(grid.n_q());
    for i in 0..n_h {
        for j in i..n_h {
            let c = (j - i) as f64 / n_h as f64;
            let m = (i + j) as f64 / (2.0 * n_h as f64) - 0.5;
            let w = (-(c - 0.15).powi(2) / 0.02 - m * m / 0.1).exp() + if i == j { 2.0 } else { 0.0 };
            masses.push(w / n_h as f64);
        }
    }
    PreisachModel::new(grid, masses, 0.0).unwrap()
}
