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

use std::time::Instant;

use crate::blocks::Runtime;
use crate::error::{check_signal, PreisachError, Result};

/// `u = r`: no compensation (the baseline, and the loop test's compensator).
#[derive(Debug, Clone, Copy, Default)]
pub struct Identity;

impl Compensator for Identity {
    #[inline]
    fn step(&mut self, r: f64) -> f64 {
        r
    }
    fn reset(&mut self) {}
}

/// `u = gain · r + offset`: the inverse of a straight-line model of the stage.
#[derive(Debug, Clone, Copy)]
pub struct LinearGain {
    pub gain: f64,
    pub offset: f64,
}

impl Compensator for LinearGain {
    #[inline]
    fn step(&mut self, r: f64) -> f64 {
        self.gain * r + self.offset
    }
    fn reset(&mut self) {}
}

impl<C: Compensator + ?Sized> Compensator for Box<C> {
    #[inline]
    fn step(&mut self, r: f64) -> f64 {
        (**self).step(r)
    }
    fn reset(&mut self) {
        (**self).reset()
    }
}

/// Per-sample wall-clock timing of a loop run.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Timing {
    pub mean_ns: f64,
    pub p99_ns: f64,
    pub max_ns: f64,
    /// Samples that took longer than the budget.
    pub misses: u64,
    /// The budget: one sample period, ns (10 000 at 100 kHz).
    pub budget_ns: f64,
    pub samples: u64,
}

impl Timing {
    /// Statistics of per-sample durations (ns); reorders `ns`.
    pub fn from_samples(ns: &mut [u64], budget_ns: f64) -> Timing {
        let n = ns.len();
        if n == 0 {
            return Timing { mean_ns: 0.0, p99_ns: 0.0, max_ns: 0.0, misses: 0, budget_ns, samples: 0 };
        }
        let mean_ns = ns.iter().map(|&x| x as f64).sum::<f64>() / n as f64;
        let max_ns = *ns.iter().max().unwrap_or(&0) as f64;
        let misses = ns.iter().filter(|&&x| x as f64 > budget_ns).count() as u64;
        // Nearest-rank 99th percentile.
        let k = ((0.99 * n as f64).ceil() as usize).clamp(1, n) - 1;
        let (_, p99, _) = ns.select_nth_unstable(k);
        Timing { mean_ns, p99_ns: *p99 as f64, max_ns, misses, budget_ns, samples: n as u64 }
    }
}

/// What a loop run produced: the commanded input, the measured output and timing.
#[derive(Debug, Clone)]
pub struct LoopResult {
    /// Compensator output (DAC command, before the chain's DAC quantizer).
    pub u: Vec<f64>,
    /// Measured output (sensor volts for the `paper` stage).
    pub y: Vec<f64>,
    /// `reference − y`.
    pub error: Vec<f64>,
    pub timing: Timing,
}

/// The hardware-in-the-loop style sample loop: for each reference sample, one
/// compensator step and one plant-chain step, timed per sample with
/// `Instant` (one clock read per sample, so each duration also carries the loop's
/// own bookkeeping, about one clock read, ~20 ns). The plant is simulated here, so
/// the timing is an upper bound of what a real controller would spend (the
/// compensator and I/O only). Output buffers are allocated before the loop; the loop itself does
/// not allocate.
///
/// Both the compensator and the chain are reset first (replay from rest, time 0; the
/// chain starts in equilibrium with its initial input, by default the first compensator
/// output, so no start-up transient rings through the stage).
pub fn run_loop<C: Compensator + ?Sized>(comp: &mut C, plant: &mut Runtime, reference: &[f64]) -> Result<LoopResult> {
    run_loop_preview(comp, plant, reference, 0)
}

/// [`run_loop`] for a compensator whose output lags its input by `preview` samples
/// (the streaming interpolated inverse with look-ahead L): the reference is known
/// ahead (feed-forward from a planned trajectory, the paper §4.1), so the compensator is
/// primed with the first `preview` references (outputs discarded, not timed) and then
/// fed `r[k + preview]` (the last reference repeated at the end) while the plant gets
/// the compensator output that belongs to `r[k]`.
pub fn run_loop_preview<C: Compensator + ?Sized>(
    comp: &mut C,
    plant: &mut Runtime,
    reference: &[f64],
    preview: usize,
) -> Result<LoopResult> {
    check_signal("reference", reference)?;
    let n = reference.len();
    let budget_ns = 1e9 / plant.sample_rate_hz();
    comp.reset();
    plant.reset();
    let mut u = vec![0.0; n];
    let mut y = vec![0.0; n];
    let mut ns = vec![0u64; n];
    let ahead = |k: usize| reference[(k + preview).min(n - 1)];
    for k in 0..preview {
        comp.step(reference[k.min(n - 1)]);
    }
    let mut prev = Instant::now();
    for k in 0..n {
        let uk = comp.step(ahead(k));
        u[k] = uk;
        y[k] = plant.step(uk);
        let now = Instant::now();
        ns[k] = now.duration_since(prev).as_nanos() as u64;
        prev = now;
    }
    if let Some(k) = u.iter().position(|v| !v.is_finite()) {
        return Err(PreisachError::invalid(
            "compensator",
            format!("produced a non-finite input {} at sample {k}", u[k]),
        ));
    }
    let error = reference.iter().zip(&y).map(|(r, y)| r - y).collect();
    let timing = Timing::from_samples(&mut ns, budget_ns);
    Ok(LoopResult { u, y, error, timing })
}
