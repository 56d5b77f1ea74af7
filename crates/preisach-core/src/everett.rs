//! The Everett table: `E(a, b)` = total mass of the cells with α-index < a and
//! β-index >= b (`docs/method/fast-paths.md`). One O(n_h²) pass; every staircase output is then a few
//! lookups.

use crate::grid::cell_index;

/// 2-D prefix sums of the masses over the upper triangle, `(n_h + 1)²` entries.
#[derive(Debug, Clone, PartialEq)]
pub struct Everett {
    n1: usize,
    table: Vec<f64>,
    /// Diagonal masses w[k][k], for the interpolated evaluation.
    diag: Vec<f64>,
}

impl Everett {
    /// Build from packed masses (see [`cell_index`]).
    pub fn new(n_h: usize, masses: &[f64]) -> Self {
        let n1 = n_h + 1;
        let mut table = vec![0.0; n1 * n1];
        // col[j] = C(b, j) = sum_{i=b..=j} w[i][j]; walk b downwards.
        let mut col = vec![0.0; n_h];
        for b in (0..n1).rev() {
            if b < n_h {
                for (j, c) in col.iter_mut().enumerate().skip(b) {
                    *c += masses[cell_index(n_h, b, j)];
                }
            }
            let mut acc = 0.0;
            for a in 1..n1 {
                acc += col[a - 1];
                table[a * n1 + b] = acc;
            }
        }
        let diag = (0..n_h).map(|k| masses[cell_index(n_h, k, k)]).collect();
        Everett { n1, table, diag }
    }

    /// `E(a, b)` at integer level indices (0 when a <= b).
    #[inline(always)]
    pub fn at(&self, a: u32, b: u32) -> f64 {
        // Indices come from the staircase, which only holds levels 0..=n_h.
        self.table[a as usize * self.n1 + b as usize]
    }

    /// `E` at continuous level coordinates for a >= b (`docs/method/fast-paths.md`, "The interpolated
    /// output"): each off-diagonal mass spread uniformly over its square cell, each
    /// diagonal mass uniformly along the diagonal α = β of its cell (the reversible
    /// relays). The square spread is exactly the bilinear interpolation of the table;
    /// the diagonal spread differs from it only when a and b lie in the same cell k, by
    /// `w_kk · f_b · (f_a − 1)` (line fraction f_a − f_b against square f_a (1 − f_b)).
    /// Spreading the diagonal mass over the square would put relays with α < β in the
    /// model and make the output jump at a reversal inside a diagonal cell.
    /// Both parts are affine in each coordinate, so the output stays piecewise linear.
    #[inline]
    pub fn bilinear(&self, a: f64, b: f64) -> f64 {
        let n_h = self.n1 - 1;
        let (ia, fa) = split(a, n_h);
        let (ib, fb) = split(b, n_h);
        let t = &self.table;
        let r0 = ia * self.n1;
        let r1 = r0 + self.n1;
        let e00 = t[r0 + ib];
        let e01 = t[r0 + ib + 1];
        let e10 = t[r1 + ib];
        let e11 = t[r1 + ib + 1];
        let lo = e00 + fb * (e01 - e00);
        let hi = e10 + fb * (e11 - e10);
        let e = lo + fa * (hi - lo);
        if ia == ib {
            e + self.diag[ia] * fb * (fa - 1.0)
        } else {
            e
        }
    }

    /// Total mass `E(n_h, 0)`.
    #[inline]
    pub fn total(&self) -> f64 {
        self.table[(self.n1 - 1) * self.n1]
    }

    pub fn n_h(&self) -> usize {
        self.n1 - 1
    }
}

#[inline(always)]
fn split(x: f64, n_h: usize) -> (usize, f64) {
    let i = (x as usize).min(n_h - 1);
    (i, x - i as f64)
}
