//! `preisach-core`: the discrete Preisach hysteresis model for piezoelectric stages
//! and other smart-material actuators (Stakvik et al. 2015; the reference is in `docs/index.md`).
//!
//! - [`grid`]: levels and cells of the discretized Preisach plane (the paper §2.2);
//! - [`everett`]: the Everett table (2-D prefix sums of the masses);
//! - [`memory`]: the memory staircase with wiping-out, the O(1) fast path;
//! - [`relay_grid`]: explicit relay states, the test oracle;
//! - [`model`]: a model (grid, masses, offset) and its per-sample paths;
//! - [`identify`]: exact non-negative least squares identification (the paper §3.2–3.3).
//!
//! No Python here: the bindings live in `crates/preisach-py`.
#![forbid(unsafe_code)]

pub mod error;
pub mod everett;
pub mod grid;
pub mod identify;
pub mod memory;
pub mod model;
pub mod relay_grid;

pub use error::{PreisachError, Result};
pub use grid::Grid;
pub use memory::Memory;
pub use model::PreisachModel;
pub use relay_grid::RelayGrid;
pub mod blocks;
pub mod chain_invert;
pub mod invert;
pub mod sim;
