//! The relay grid: every cell's relay state held explicitly (the paper's eq. 1 and 4).
//! O(n_q) per sample. It is the test oracle for the staircase and the plain
//! definition the regression rows come from.

use crate::grid::{cell_index, Grid};

/// Explicit relay states of a discrete Preisach model.
#[derive(Debug, Clone)]
pub struct RelayGrid {
    grid: Grid,
    /// +1 / −1 per cell, packed like the masses.
    states: Vec<i8>,
}

impl RelayGrid {
    /// All relays at −1.
    pub fn new(grid: Grid) -> Self {
        let n_q = grid.n_q();
        RelayGrid { grid, states: vec![-1; n_q] }
    }

    /// Apply one input sample to every relay (eq. 1 with thresholds at cell centres).
    pub fn apply(&mut self, u: f64) {
        let n = self.grid.n_h();
        let thr = self.grid.thresholds();
        for i in 0..n {
            for j in i..n {
                let s = &mut self.states[cell_index(n, i, j)];
                if u >= thr[j] {
                    *s = 1;
                } else if u < thr[i] {
                    *s = -1;
                }
            }
        }
    }

    /// `sum w R + offset` (eq. 4).
    pub fn output(&self, masses: &[f64], offset: f64) -> f64 {
        self.states.iter().zip(masses).map(|(&s, &w)| s as f64 * w).sum::<f64>() + offset
    }

    /// Relay states, packed like the masses.
    pub fn states(&self) -> &[i8] {
        &self.states
    }
}
