//! Feed-forward through a whole chain (`docs/method/inversion.md`, "Inverting a
//! chain"): for a known reference `r`, the input `u` whose chain output follows `r`.
//!
//! A chain inverts when it is `pre → hysteresis → post`: `pre` the amplifier's gain and
//! linear blocks (low-pass, ...), `post` linear blocks (creep, vibration, low-pass,
//! delay, the sensor's gain, filter and delay) and a final drift; noise and quantizers
//! are left out (they cannot be inverted). With `G` the linear part after the
//! hysteresis and `D` its delay, the hysteresis output must be `h(t) = G⁻¹ r(t + D)`;
//! the inverse computes `G⁻¹ F r` with a low-pass `F` at a stated bandwidth
//! ([`crate::blocks::inverse`]) and takes `D` and the low-pass's group delay back by
//! preview. Then the hysteresis inverse ([`crate::invert::Inverter`], any method) gives
//! the hysteresis input, and the inverse of `pre` (the same construction) the chain's
//! input. The hysteresis is rate independent, so every time shift moves to the front:
//! the inverter's output lags its reference by a whole number of samples, its latency
//! `L >= ceil(preview)` (plus the interpolated method's own look-ahead), and the rest
//! `L − preview` is a fractional delay line on the hysteresis output.

use std::sync::Arc;

use crate::blocks::inverse::{fastest_lag_hz, invert_ltis};
use crate::blocks::lti::{DelayLine, Discretization, Filter, Lti, Section};
use crate::blocks::{BlockSpec, Chain, DriftParams, HysteresisParams};
use crate::error::{check_finite, PreisachError, Result};
use crate::invert::{Inverter, InverterState, Method};
use crate::model::PreisachModel;
use crate::sim::Compensator;

/// Look-ahead of the interpolated hysteresis inverse when none is given, samples.
pub const DEFAULT_INTERPOLATED_LOOKAHEAD: usize = 2000;
/// The default bandwidth: this many times the fastest lag of the chain's linear part...
pub const BANDWIDTH_PER_LAG: f64 = 2.0;
/// ...but at most this fraction of the sample rate.
pub const MAX_BANDWIDTH_PER_FS: f64 = 0.1;

/// What a chain's inverse is made of, for one sample rate.
#[derive(Debug, Clone)]
pub struct Plan {
    pub model: Arc<PreisachModel>,
    /// Linear blocks (and the amplifier's gain) before the hysteresis, after it.
    pub pre: Vec<(String, Lti)>,
    pub post: Vec<(String, Lti)>,
    pub drift: Option<DriftParams>,
    pub bandwidth_hz: f64,
    pub sample_rate_hz: f64,
}

fn refuse(k: usize, b: &BlockSpec, why: &str) -> PreisachError {
    PreisachError::invalid(format!("blocks[{k}] ({})", b.kind()), format!("cannot be inverted: {why}"))
}

impl Plan {
    /// Split `chain` into what the inverse needs; refuses (naming the block) what it
    /// cannot invert. `bandwidth_hz`: the low-pass of the linear inverse (below Nyquist);
    /// `None`: [`BANDWIDTH_PER_LAG`] times the fastest lag of the linear blocks, at most
    /// [`MAX_BANDWIDTH_PER_FS`] of the rate.
    pub fn new(chain: &Chain, sample_rate_hz: f64, bandwidth_hz: Option<f64>) -> Result<Plan> {
        crate::blocks::positive("sample_rate_hz", sample_rate_hz)?;
        let (mut pre, mut post) = (Vec::new(), Vec::new());
        let mut model: Option<Arc<PreisachModel>> = None;
        let mut drift: Option<DriftParams> = None;
        for (k, b) in chain.blocks().iter().enumerate() {
            let name = format!("blocks[{k}] ({})", b.kind());
            if drift.is_some() && !matches!(b, BlockSpec::Noise(_) | BlockSpec::Quantizer(_)) {
                return Err(refuse(k, b, "only noise or a quantizer may follow a drift block"));
            }
            let side = if model.is_some() { &mut post } else { &mut pre };
            match b {
                BlockSpec::Noise(_) | BlockSpec::Quantizer(_) => {}
                BlockSpec::Hysteresis(p) => {
                    if model.is_some() {
                        return Err(refuse(k, b, "a second hysteresis block"));
                    }
                    if let HysteresisParams::Parametric(_) = p {
                        return Err(refuse(
                            k,
                            b,
                            "a parametric hysteresis has a reversible part the Preisach inverse does not model; \
                             identify a model from its records and invert that",
                        ));
                    }
                    let core = chain.hysteresis(k).ok_or_else(|| refuse(k, b, "its model is not built"))?;
                    model = Some(core.model().clone());
                }
                BlockSpec::Amplifier(p) => {
                    if p.gain == 0.0 {
                        return Err(refuse(k, b, "its gain is zero"));
                    }
                    side.push((name, Lti::series(vec![Section::gain(p.gain)?])));
                }
                BlockSpec::Rate(_) => {
                    return Err(refuse(k, b, "the rate branch acts on the hysteresis input in parallel"));
                }
                BlockSpec::Drift(p) if model.is_some() => drift = Some(p.clone()),
                BlockSpec::Drift(_) => return Err(refuse(k, b, "a drift before the hysteresis")),
                other => {
                    let lti = other.lti().ok_or_else(|| refuse(k, b, "not a linear block"))??;
                    side.push((name, lti));
                }
            }
        }
        let model = model.ok_or_else(|| {
            PreisachError::invalid("chain", "has no hysteresis block: nothing for the hysteresis inverse to invert")
        })?;
        let nyquist = 0.5 * sample_rate_hz;
        let bandwidth_hz = match bandwidth_hz {
            Some(b) => {
                crate::blocks::positive("bandwidth_hz", b)?;
                if b >= nyquist {
                    return Err(PreisachError::invalid(
                        "bandwidth_hz",
                        format!("must be below Nyquist ({nyquist} Hz) of the rate {sample_rate_hz} Hz, got {b}"),
                    ));
                }
                b
            }
            None => {
                let cap = MAX_BANDWIDTH_PER_FS * sample_rate_hz;
                let lag = fastest_lag_hz(&post)?.into_iter().chain(fastest_lag_hz(&pre)?).fold(0.0, f64::max);
                if lag > 0.0 {
                    (BANDWIDTH_PER_LAG * lag).min(cap)
                } else {
                    cap
                }
            }
        };
        Ok(Plan { model, pre, post, drift, bandwidth_hz, sample_rate_hz })
    }
}

/// The streaming chain inverse: one reference sample in, the input `latency` samples
/// earlier out; no allocation per sample. See the module doc.
#[derive(Debug, Clone)]
pub struct ChainInverter {
    drift: Option<DriftParams>,
    post: Filter,
    shift: DelayLine,
    hysteresis: Inverter,
    pre: Filter,
    latency: usize,
    preview_s: f64,
    bandwidth_hz: f64,
    dt: f64,
    /// Reference samples so far.
    n: u64,
}

/// A snapshot of a [`ChainInverter`]: enough to resume exactly.
#[derive(Debug, Clone, PartialEq)]
pub struct ChainInverterState {
    pub n: u64,
    pub post: Vec<f64>,
    pub shift: Vec<f64>,
    pub hysteresis: InverterState,
    pub pre: Vec<f64>,
}

impl ChainInverter {
    /// The inverse of `plan` with the hysteresis inverse `method`. `lookahead` is the
    /// latency in samples: at least `ceil(preview)` (plus the interpolated method's
    /// look-ahead, which gets whatever exceeds it); `None`: the least (for
    /// `interpolated`, plus [`DEFAULT_INTERPOLATED_LOOKAHEAD`]).
    pub fn new(plan: &Plan, method: Method, lookahead: Option<usize>) -> Result<Self> {
        let post = invert_ltis(&plan.post, plan.bandwidth_hz)?;
        let pre = invert_ltis(&plan.pre, plan.bandwidth_hz)?;
        let preview_s = post.preview_s + pre.preview_s;
        let fs = plan.sample_rate_hz;
        let preview = preview_s * fs;
        let need = (preview - 1e-9).ceil().max(0.0) as usize;
        let interp = method == Method::Interpolated;
        let latency = match lookahead {
            Some(l) if l < need + usize::from(interp) => {
                return Err(PreisachError::invalid(
                    "lookahead",
                    format!(
                    "must be at least {} samples (the chain's delay and the low-pass's group delay: {:.3} samples{})",
                    need + usize::from(interp),
                    preview,
                    if interp { ", plus one for the interpolated inverse" } else { "" }
                ),
                ))
            }
            Some(l) => l,
            None if interp => need + DEFAULT_INTERPOLATED_LOOKAHEAD,
            None => need,
        };
        let (h_look, shift) =
            if interp { (Some(latency - need), need as f64 - preview) } else { (None, latency as f64 - preview) };
        let dt = 1.0 / fs;
        Ok(ChainInverter {
            drift: plan.drift.clone(),
            post: Filter::of(&post.sections, dt, Discretization::Foh),
            shift: DelayLine::new(shift.max(0.0) * dt, fs)?,
            hysteresis: Inverter::new(plan.model.clone(), method, h_look)?,
            pre: Filter::of(&pre.sections, dt, Discretization::Foh),
            latency,
            preview_s,
            bandwidth_hz: plan.bandwidth_hz,
            dt,
            n: 0,
        })
    }

    /// The output's lag behind the reference, samples.
    pub fn latency(&self) -> usize {
        self.latency
    }
    /// The preview the chain needs: its delay plus the low-passes' group delay, seconds.
    pub fn preview_s(&self) -> f64 {
        self.preview_s
    }
    pub fn bandwidth_hz(&self) -> f64 {
        self.bandwidth_hz
    }
    pub fn method(&self) -> Method {
        self.hysteresis.method()
    }
    /// References so far outside the hysteresis model's reachable range.
    pub fn saturated(&self) -> u64 {
        self.hysteresis.saturated()
    }

    /// Reference sample `r[n]` in, input `u[n − latency]` out. `r` must be finite (see
    /// [`ChainInverter::process`]).
    #[inline]
    pub fn step(&mut self, r: f64) -> f64 {
        let t = self.n as f64 * self.dt;
        self.n += 1;
        let x = match &self.drift {
            Some(d) => (r - d.offset - d.offset_per_s * t) / (1.0 + d.gain_per_s * t),
            None => r,
        };
        let h = self.shift.step(self.post.step(x));
        self.pre.step(self.hysteresis.step(h))
    }

    /// A block of references; errors (naming the first bad index) before touching the
    /// state if any is not finite.
    pub fn process(&mut self, r: &[f64], out: &mut [f64]) -> Result<()> {
        check_finite("r", r)?;
        for (o, &x) in out.iter_mut().zip(r) {
            *o = self.step(x);
        }
        Ok(())
    }

    /// Back to the start: filters at rest with the next reference, the hysteresis
    /// inverse at negative saturation, time 0.
    pub fn reset(&mut self) {
        self.n = 0;
        self.post.reset();
        self.shift.reset();
        self.hysteresis.reset();
        self.pre.reset();
    }

    pub fn state(&self) -> ChainInverterState {
        ChainInverterState {
            n: self.n,
            post: self.post.state(),
            shift: self.shift.state(),
            hysteresis: self.hysteresis.state(),
            pre: self.pre.state(),
        }
    }

    /// Restore a snapshot of an inverter of the same chain, rate, bandwidth, method and
    /// look-ahead. Validated; on error the inverter is unchanged.
    pub fn set_state(&mut self, s: &ChainInverterState) -> Result<()> {
        let mut next = self.clone();
        next.post.set_state(&s.post)?;
        next.shift.set_state(&s.shift)?;
        next.hysteresis.set_state(&s.hysteresis)?;
        next.pre.set_state(&s.pre)?;
        next.n = s.n;
        *self = next;
        Ok(())
    }
}

impl Compensator for ChainInverter {
    #[inline]
    fn step(&mut self, r: f64) -> f64 {
        ChainInverter::step(self, r)
    }
    fn reset(&mut self) {
        ChainInverter::reset(self)
    }
}

/// The chain inverse over a whole reference: `u[n]` makes the chain output follow
/// `r[n]` (the streaming inverter run over `r`, then `latency` copies of its last
/// sample, its first `latency` outputs dropped: streaming and offline agree exactly).
/// Returns the input and the number of saturated samples.
pub fn invert_chain(inv: &mut ChainInverter, r: &[f64]) -> Result<(Vec<f64>, u64)> {
    crate::error::check_signal("r", r)?;
    inv.reset();
    let last = r[r.len() - 1];
    let l = inv.latency();
    let mut u = Vec::with_capacity(r.len());
    for (k, &x) in r.iter().chain(std::iter::repeat_n(&last, l)).enumerate() {
        let v = inv.step(x);
        if k >= l {
            u.push(v);
        }
    }
    Ok((u, inv.saturated()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::blocks::{
        BlockSpec, CreepParams, DelayParams, HysteresisParams, IdentifiedHysteresis, LowpassParams, Mode, Output,
        VibrationParams,
    };
    use crate::{Grid, PreisachModel};

    fn chain() -> Chain {
        let n = 30;
        let grid = Grid::new(0.0, 10.0, n).unwrap();
        let masses: Vec<f64> = (0..n)
            .flat_map(|i| (i..n).map(move |j| if i == j { 0.02 } else { 0.01 / (1.0 + (j - i) as f64) }))
            .collect();
        let model = PreisachModel::new(grid, masses, 0.0).unwrap();
        Chain::new(vec![
            BlockSpec::Hysteresis(HysteresisParams::Identified(IdentifiedHysteresis::of_model(
                &model,
                Output::Interpolated,
            ))),
            BlockSpec::Creep(CreepParams { taus_s: vec![0.02], amplitudes: vec![0.05], normalized: false }),
            BlockSpec::Vibration(VibrationParams { modes: vec![Mode { frequency_hz: 700.0, damping: 0.03 }] }),
            BlockSpec::Lowpass(LowpassParams { cutoff_hz: 1500.0, order: 2 }),
            BlockSpec::Delay(DelayParams { delay_s: 3.3e-4 }),
        ])
        .unwrap()
    }

    #[test]
    fn the_chain_follows_its_inverse_and_streaming_equals_offline() {
        let fs = 20e3;
        let c = chain();
        let plan = Plan::new(&c, fs, None).unwrap();
        assert_eq!(plan.bandwidth_hz, 2000.0); // 2 x 1500 Hz, capped at fs / 10
        let mut inv = ChainInverter::new(&plan, Method::Continuous, None).unwrap();
        // At rest for 200 samples, then a 20 Hz sine.
        let r: Vec<f64> = (0..3000)
            .map(|k: usize| {
                let t = k.saturating_sub(200) as f64 / fs;
                1.05 * (0.6 - 0.3 * (std::f64::consts::TAU * 20.0 * t).cos())
            })
            .collect();
        let (u, sat) = invert_chain(&mut inv, &r).unwrap();
        assert_eq!(sat, 0);
        let t: Vec<f64> = (0..r.len()).map(|k| k as f64 / fs).collect();
        let y = c.predict(&t, &u, None).unwrap();
        let err = r[1200..2900].iter().zip(&y[1200..2900]).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
        assert!(err < 1e-3 * 0.3, "peak error {err}");
        let l = inv.latency();
        inv.reset();
        let streamed: Vec<f64> =
            r.iter().chain(std::iter::repeat_n(&r[r.len() - 1], l)).map(|&x| inv.step(x)).collect();
        assert_eq!(&streamed[l..], &u[..]);
    }
}
