//! Test helpers shared by the identification's unit tests: a seeded generator, a
//! random input and signed masses with their output (the model's own staircase).

use crate::grid::Grid;
use crate::model::PreisachModel;

/// xorshift64*, uniform in [0, 1).
pub(crate) struct Rng(pub(crate) u64);

impl Rng {
    pub(crate) fn uniform(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        (self.0.wrapping_mul(0x2545F4914F6CDD1D) >> 11) as f64 / (1u64 << 53) as f64
    }
    pub(crate) fn range(&mut self, a: f64, b: f64) -> f64 {
        a + (b - a) * self.uniform()
    }
}

/// A random walk with jumps and small wiggles, beyond the range (0, 1) on both sides.
pub(crate) fn input(rng: &mut Rng, n: usize) -> Vec<f64> {
    let mut u = 0.5;
    (0..n)
        .map(|_| {
            u += if rng.uniform() < 0.02 { rng.range(-0.8, 0.8) } else { rng.range(-0.03, 0.03) };
            u = u.clamp(-0.2, 1.2);
            u
        })
        .collect()
}

/// Signed masses (the difference of two models): their Everett values and offset,
/// and their output on `u` through the model's own staircase (the oracle).
pub(crate) fn signed(rng: &mut Rng, grid: &Grid, u: &[f64]) -> (Vec<f64>, Vec<f64>) {
    let model = |rng: &mut Rng, offset: f64| {
        let m: Vec<f64> = (0..grid.n_q()).map(|_| rng.uniform()).collect();
        PreisachModel::new(grid.clone(), m, offset).unwrap()
    };
    let offset = rng.range(-1.0, 1.0);
    let (pos, neg) = (model(rng, offset), model(rng, 0.0));
    let mut x: Vec<f64> = pos.everett_values().iter().zip(neg.everett_values()).map(|(a, b)| a - b).collect();
    x.push(pos.offset());
    let (mut hp, mut hn) = (vec![0.0; u.len()], vec![0.0; u.len()]);
    pos.run_interpolated(&mut pos.interp_memory(), u, &mut hp);
    neg.run_interpolated(&mut neg.interp_memory(), u, &mut hn);
    (x, hp.iter().zip(&hn).map(|(a, b)| a - b).collect())
}
