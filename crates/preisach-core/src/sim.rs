//! The 100 kHz sample loop: reference → compensator → DAC → plant chain → sensor.

/// Anything that turns a reference sample into an input sample, one at a time:
/// the streaming inverters implement it (crate::invert), and so can a user's own
/// compensator. `step` must not allocate.
pub trait Compensator {
    /// One reference sample in, one input sample out.
    fn step(&mut self, r: f64) -> f64;
    /// Back to the initial state.
    fn reset(&mut self);
}
