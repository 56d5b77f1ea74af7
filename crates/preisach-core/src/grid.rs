//! The discretized Preisach plane (`docs/method/model.md`; the paper §2.2).
//!
//! Range `(lo, hi)` = (β_m, α_m), `n_h` cells per axis, `n_h + 1` input levels
//! `v_k = lo + k·Δ`. Cell `(i, j)`, `i <= j`, carries its mass at the cell centre, so
//! its relay switches up at `α_c = v_j + Δ/2` and down below `β_c = v_i + Δ/2`.

use crate::error::{check_scalar, PreisachError, Result};
use serde::{Deserialize, Serialize};

/// Largest `n_h` accepted: the Everett table has `(n_h + 1)^2` doubles, so this keeps it
/// under 2 GB and is checked before anything is allocated.
pub const MAX_N_H: usize = 16_000;

/// The level grid of a discrete Preisach model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Grid {
    lo: f64,
    hi: f64,
    n_h: usize,
    #[serde(skip)]
    delta: f64,
    /// Switching thresholds `v_j + Δ/2`, j = 0..n_h (cell centres on either axis).
    #[serde(skip)]
    thresholds: Vec<f64>,
}

impl Grid {
    /// A grid on `[lo, hi]` with `n_h` cells per axis.
    pub fn new(lo: f64, hi: f64, n_h: usize) -> Result<Self> {
        check_scalar("u_range", lo)?;
        check_scalar("u_range", hi)?;
        if lo >= hi {
            return Err(PreisachError::invalid("u_range", format!("lo must be below hi, got ({lo}, {hi})")));
        }
        if n_h < 1 {
            return Err(PreisachError::invalid("n_h", format!("must be >= 1, got {n_h}")));
        }
        if n_h > MAX_N_H {
            return Err(PreisachError::invalid(
                "n_h",
                format!(
                    "{n_h} is too large: the Everett table would need {:.1} GB (limit n_h <= {MAX_N_H})",
                    (n_h as f64 + 1.0).powi(2) * 8.0 / 1e9
                ),
            ));
        }
        let delta = (hi - lo) / n_h as f64;
        if delta.is_nan() || delta <= 0.0 || !delta.is_finite() {
            return Err(PreisachError::invalid("u_range", "span too small or too large for n_h"));
        }
        let thresholds = (0..n_h).map(|j| lo + (j as f64 + 0.5) * delta).collect();
        Ok(Grid { lo, hi, n_h, delta, thresholds })
    }

    /// Rebuild the derived fields after deserialization.
    pub fn validated(self) -> Result<Self> {
        Grid::new(self.lo, self.hi, self.n_h)
    }

    pub fn lo(&self) -> f64 {
        self.lo
    }
    pub fn hi(&self) -> f64 {
        self.hi
    }
    pub fn n_h(&self) -> usize {
        self.n_h
    }
    /// Level pitch Δ.
    pub fn delta(&self) -> f64 {
        self.delta
    }
    /// Number of cells n_q = n_h (n_h + 1) / 2 (the paper's eq. 5).
    pub fn n_q(&self) -> usize {
        self.n_h * (self.n_h + 1) / 2
    }
    /// Input level `v_k`, k = 0..=n_h.
    #[inline]
    pub fn level(&self, k: usize) -> f64 {
        if k >= self.n_h {
            self.hi
        } else {
            self.lo + k as f64 * self.delta
        }
    }
    /// All n_h + 1 levels.
    pub fn levels(&self) -> Vec<f64> {
        (0..=self.n_h).map(|k| self.level(k)).collect()
    }
    /// Switching thresholds (cell centres), n_h values.
    pub fn thresholds(&self) -> &[f64] {
        &self.thresholds
    }

    /// The level index the relays see for input `u`: the number of thresholds `<= u`
    /// (relay up at `u >= α_c`, down at `u < β_c`, eq. 1). Exact at the thresholds:
    /// the arithmetic guess is corrected against the stored thresholds, so the staircase
    /// and the relay grid agree even on ties.
    #[inline]
    pub fn quantize(&self, u: f64) -> u32 {
        let x = (u - self.lo) / self.delta + 0.5;
        let n = self.n_h;
        let mut k = if x >= n as f64 {
            n
        } else if x > 0.0 {
            x as usize
        } else {
            0
        };
        // At most one step either way; loops keep it exact for any rounding.
        while k < n && u >= self.thresholds[k] {
            k += 1;
        }
        while k > 0 && u < self.thresholds[k - 1] {
            k -= 1;
        }
        k as u32
    }

    /// Continuous level coordinate `(u - lo) / Δ`, clamped to `[0, n_h]`.
    #[inline]
    pub fn position(&self, u: f64) -> f64 {
        ((u - self.lo) / self.delta).clamp(0.0, self.n_h as f64)
    }

    /// Input value of a continuous level coordinate.
    #[inline]
    pub fn value_at(&self, pos: f64) -> f64 {
        self.lo + pos * self.delta
    }
}

/// Masses of the upper triangle, packed row by row: cell (i, j), i <= j < n_h.
/// Row i starts after the `i·n_h − i(i−1)/2` cells of rows 0..i.
#[inline]
pub fn cell_index(n_h: usize, i: usize, j: usize) -> usize {
    debug_assert!(i <= j && j < n_h);
    i * n_h - i * i.saturating_sub(1) / 2 + (j - i)
}
