//! A discrete Preisach model: grid, non-negative masses, offset, and its Everett table.
//! The per-sample paths (stepwise and interpolated) live here.

use crate::error::{check_finite, check_scalar, PreisachError, Result};
use crate::everett::Everett;
use crate::grid::{cell_index, Grid};
use crate::memory::Memory;

/// Memory of the stepwise model (integer level indices).
pub type StepMemory = Memory<u32>;
/// Memory of the interpolated model (continuous level positions).
pub type InterpMemory = Memory<f64>;

/// The discrete Preisach operator `y = sum w R + offset` (the paper's eq. 4).
#[derive(Debug, Clone, PartialEq)]
pub struct PreisachModel {
    grid: Grid,
    masses: Vec<f64>,
    offset: f64,
    everett: Everett,
}

impl PreisachModel {
    /// Build from packed masses (`cell_index` order). Masses must be finite and >= 0.
    pub fn new(grid: Grid, masses: Vec<f64>, offset: f64) -> Result<Self> {
        if masses.len() != grid.n_q() {
            return Err(PreisachError::invalid(
                "weights",
                format!("expected {} packed masses for n_h = {}, got {}", grid.n_q(), grid.n_h(), masses.len()),
            ));
        }
        check_finite("weights", &masses)?;
        if let Some(k) = masses.iter().position(|&w| w < 0.0) {
            return Err(PreisachError::invalid(
                "weights",
                format!("masses must be >= 0, got {} at packed index {k}", masses[k]),
            ));
        }
        check_scalar("offset", offset)?;
        let everett = Everett::new(grid.n_h(), &masses);
        // Outputs are sums of ± Everett values plus the offset: keep them in range.
        if !(4.0 * everett.total() + offset.abs()).is_finite() {
            return Err(PreisachError::invalid(
                "weights",
                format!("the masses sum to {:e}, too large: the outputs would overflow float64", everett.total()),
            ));
        }
        Ok(PreisachModel { grid, masses, offset, everett })
    }

    /// Build from a dense row-major (n_h × n_h) array: β-cell = row, α-cell = column,
    /// upper triangle incl. diagonal; entries below the diagonal are ignored.
    pub fn from_dense(lo: f64, hi: f64, n_h: usize, dense: &[f64], offset: f64) -> Result<Self> {
        let grid = Grid::new(lo, hi, n_h)?;
        if dense.len() != n_h * n_h {
            return Err(PreisachError::invalid(
                "weights",
                format!("expected an ({n_h}, {n_h}) array, got {} values", dense.len()),
            ));
        }
        let mut masses = Vec::with_capacity(grid.n_q());
        for i in 0..n_h {
            for j in i..n_h {
                let w = dense[i * n_h + j];
                if !w.is_finite() {
                    return Err(PreisachError::invalid("weights", format!("non-finite value {w} at [{i}, {j}]")));
                }
                if w < 0.0 {
                    return Err(PreisachError::invalid("weights", format!("negative mass {w} at [{i}, {j}]")));
                }
                masses.push(w);
            }
        }
        Self::new(grid, masses, offset)
    }

    /// Dense row-major (n_h × n_h) weights, zero below the diagonal.
    pub fn dense_weights(&self) -> Vec<f64> {
        let n = self.grid.n_h();
        let mut d = vec![0.0; n * n];
        for i in 0..n {
            for j in i..n {
                d[i * n + j] = self.masses[cell_index(n, i, j)];
            }
        }
        d
    }

    pub fn grid(&self) -> &Grid {
        &self.grid
    }
    pub fn masses(&self) -> &[f64] {
        &self.masses
    }
    pub fn offset(&self) -> f64 {
        self.offset
    }
    pub fn everett(&self) -> &Everett {
        &self.everett
    }
    /// The Everett values `E(a, b)`, 0 <= b < a <= n_h, in the order of
    /// [`crate::identify::rows::everett_var`] (the coordinates of the regression rows).
    pub fn everett_values(&self) -> Vec<f64> {
        let n_h = self.n_h();
        let mut e = Vec::with_capacity(self.grid.n_q());
        for a in 1..=n_h {
            for b in 0..a {
                e.push(self.everett.at(a as u32, b as u32));
            }
        }
        e
    }
    pub fn n_h(&self) -> usize {
        self.grid.n_h()
    }

    /// Output for a switched-on mass S⁺: relays are ±1, so `y = 2 S⁺ − total + offset`.
    #[inline(always)]
    pub fn output_of(&self, s_plus: f64) -> f64 {
        2.0 * s_plus - self.everett.total() + self.offset
    }

    /// Fresh stepwise memory (all relays −1), preallocated to the maximum depth.
    pub fn memory(&self) -> StepMemory {
        Memory::new(0, self.grid.n_h() + 3)
    }

    /// Fresh interpolated memory (all relays −1).
    pub fn interp_memory(&self) -> InterpMemory {
        Memory::new(0.0, 4 * (self.grid.n_h() + 3))
    }

    /// Everett lookup at level indices, for `Memory::apply` / `peek_s_plus`.
    #[inline(always)]
    pub fn e_step(&self) -> impl Fn(u32, u32) -> f64 + '_ {
        move |a, b| self.everett.at(a, b)
    }

    /// Everett lookup at continuous positions (bilinear).
    #[inline(always)]
    pub fn e_interp(&self) -> impl Fn(f64, f64) -> f64 + '_ {
        move |a, b| self.everett.bilinear(a, b)
    }

    /// One sample of the stepwise model (the staircase fast path).
    #[inline]
    pub fn step(&self, mem: &mut StepMemory, u: f64) -> f64 {
        let e = self.e_step();
        mem.apply(self.grid.quantize(u), &e);
        self.output_of(mem.s_plus(&e))
    }

    /// Stepwise model over a block. `u` must be finite (checked by the caller's API).
    pub fn run(&self, mem: &mut StepMemory, u: &[f64], out: &mut [f64]) {
        let e = self.e_step();
        for (o, &x) in out.iter_mut().zip(u) {
            mem.apply(self.grid.quantize(x), &e);
            *o = self.output_of(mem.s_plus(&e));
        }
    }

    /// One sample of the interpolated model: masses spread uniformly over their cells,
    /// so the output is continuous in the input, piecewise linear between levels and
    /// equal to the stepwise model whenever the input and its extrema sit on levels
    /// (`docs/method/fast-paths.md`).
    #[inline]
    pub fn step_interpolated(&self, mem: &mut InterpMemory, u: f64) -> f64 {
        let e = self.e_interp();
        mem.apply(self.grid.position(u), &e);
        self.output_of(mem.s_plus(&e))
    }

    /// Interpolated model over a block.
    pub fn run_interpolated(&self, mem: &mut InterpMemory, u: &[f64], out: &mut [f64]) {
        for (o, &x) in out.iter_mut().zip(u) {
            *o = self.step_interpolated(mem, x);
        }
    }

    /// Stepwise output if the input moved to level `k` now (nothing mutated).
    #[inline]
    pub fn peek_level(&self, mem: &StepMemory, k: u32) -> f64 {
        self.output_of(mem.peek_s_plus(k, &self.e_step()))
    }

    /// Interpolated output if the input moved to position `p` now (nothing mutated).
    #[inline]
    pub fn peek_position(&self, mem: &InterpMemory, p: f64) -> f64 {
        self.output_of(mem.peek_s_plus(p, &self.e_interp()))
    }

    /// Rebuild a stepwise memory from input values (e.g. a snapshot in input units).
    pub fn step_memory_from(&self, values: &[f64]) -> Result<StepMemory> {
        check_finite("state", values)?;
        let mut mem = self.memory();
        let e = self.e_step();
        for &v in values {
            mem.apply(self.grid.quantize(v), &e);
        }
        Ok(mem)
    }

    /// Snapshot of a stepwise memory in input units (levels).
    pub fn step_memory_values(&self, mem: &StepMemory) -> Vec<f64> {
        mem.snapshot().into_iter().map(|k| self.grid.level(k as usize)).collect()
    }

    /// Rebuild an interpolated memory from input values.
    pub fn interp_memory_from(&self, values: &[f64]) -> Result<InterpMemory> {
        check_finite("state", values)?;
        let mut mem = self.interp_memory();
        let e = self.e_interp();
        for &v in values {
            mem.apply(self.grid.position(v), &e);
        }
        Ok(mem)
    }

    /// Snapshot of an interpolated memory in input units.
    pub fn interp_memory_values(&self, mem: &InterpMemory) -> Vec<f64> {
        mem.snapshot().into_iter().map(|p| self.grid.value_at(p)).collect()
    }
}
