//! Test helpers: a tiny deterministic generator (no extra dependency) and random models.
#![allow(dead_code)]

use preisach_core::{Grid, PreisachModel};

pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Self {
        Rng(seed.wrapping_mul(0x9E3779B97F4A7C15) | 1)
    }
    pub fn next_u64(&mut self) -> u64 {
        // xorshift64*
        let mut x = self.0;
        x ^= x >> 12;
        x ^= x << 25;
        x ^= x >> 27;
        self.0 = x;
        x.wrapping_mul(0x2545F4914F6CDD1D)
    }
    /// Uniform in [0, 1).
    pub fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
    pub fn range(&mut self, a: f64, b: f64) -> f64 {
        a + (b - a) * self.uniform()
    }
}

/// A random model on (-1, 2) with some zero masses.
pub fn random_model(rng: &mut Rng, n_h: usize) -> PreisachModel {
    let grid = Grid::new(-1.0, 2.0, n_h).unwrap();
    let masses = (0..grid.n_q()).map(|_| if rng.uniform() < 0.2 { 0.0 } else { rng.uniform() }).collect();
    PreisachModel::new(grid, masses, rng.range(-1.0, 1.0)).unwrap()
}

/// A random walk with jumps, reaching beyond the range on both sides.
pub fn random_input(rng: &mut Rng, n: usize) -> Vec<f64> {
    let mut u = 0.5;
    (0..n)
        .map(|_| {
            if rng.uniform() < 0.1 {
                u = rng.range(-1.5, 2.5);
            } else {
                u += rng.range(-0.3, 0.3);
            }
            u
        })
        .collect()
}
