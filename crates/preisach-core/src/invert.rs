//! Inversion of the discrete Preisach model (the paper §4.1): closest match, the paper's
//! linear interpolation between the discrete steps (Fig. 9), and a continuous inverse
//! of the interpolated model.
//!
//! - [`closest_level`]: the closest-match search of Tan et al. (2001). From a fixed
//!   memory the output after moving to level `k` is non-decreasing in `k` (masses are
//!   non-negative; `docs/method/fast-paths.md`, "Closest match is a search over a monotone function"), so the
//!   search is a galloping binary search from the previous level over
//!   [`PreisachModel::peek_level`]: O(log n_h) peeks worst case, one or two on a smooth
//!   reference, no state copies, no scan over the levels. Optimal at every sample.
//! - [`monotone_level`]: the direction-consistent ("monotone") closest match that the
//!   interpolation is built on: the best level among those on the reference's side of
//!   the current level (see below).
//! - [`interpolate`] / [`Interpolator`]: knots at the riser midpoints of the monotone
//!   closest-match signal, linear in between; offline, or streaming with a preview
//!   of `lookahead` samples (output delayed by exactly `lookahead` samples).
//! - [`continuous_position`]: inverts the interpolated model `y_c(u)` (continuous,
//!   piecewise linear, monotone on each branch) exactly, with no look-ahead.
//!
//! Why the interpolation does not use the per-sample closest match: the per-sample
//! optimum dithers. After a one-level rise switches a whole column of cells on, moving
//! a few levels down and back up gives outputs in between, so on a plain rising
//! reference the optimum keeps reversing (5 Hz sine at 100 kHz, n_h = 100: 5,374 steps,
//! 3,279 of them reversals), every reversal traces a minor loop, and knots at every
//! riser inherit the dither (only 1.4 dB less energy above 500 Hz than the closest
//! match itself). The paper's Fig. 9 shows a monotone staircase; the monotone closest
//! match never moves the input against the reference (700 steps, none reversing inside
//! a monotone stretch of the reference) and its interpolation is tens of dB quieter.
//!
//! Ties and plateaus (zero masses give levels with equal output) go to the input
//! nearest the previous one; references outside the reachable output range
//! `[offset − total, offset + total]` saturate and are counted, never an error.
//!
//! The interpolated model ([`crate::everett::Everett::bilinear`]) puts a diagonal cell's
//! mass along the diagonal, so `y_c` is continuous everywhere (also at reversals inside
//! diagonal cells) and piecewise linear with breakpoints at the levels and at the
//! stored extrema: every reachable reference has an exact preimage.

use std::collections::VecDeque;
use std::str::FromStr;
use std::sync::Arc;

use crate::error::{check_finite, PreisachError, Result};
use crate::model::{InterpMemory, PreisachModel, StepMemory};
use crate::sim::Compensator;

/// Relative tolerance of output comparisons: errors that differ by less than
/// `REL_TOL · (total mass + |offset|)` are ties (rounding in the Everett sums is far
/// below it), and the continuous inverse stops within it.
pub const REL_TOL: f64 = 1e-12;

/// Largest streaming look-ahead: the streaming interpolator preallocates a knot queue
/// of `lookahead + 1` entries.
pub const MAX_LOOKAHEAD: usize = 1 << 24;

/// The inversion methods.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Method {
    /// Closest match (Tan et al. 2001): the level whose output is nearest.
    Closest,
    /// The monotone closest match ([`monotone_level`]) smoothed by linear interpolation
    /// between its steps (the paper's Fig. 9).
    Interpolated,
    /// Exact inverse of the interpolated (continuous) model, no look-ahead.
    Continuous,
}

impl Method {
    pub const NAMES: [&'static str; 3] = ["closest", "interpolated", "continuous"];

    pub fn name(self) -> &'static str {
        match self {
            Method::Closest => "closest",
            Method::Interpolated => "interpolated",
            Method::Continuous => "continuous",
        }
    }
}

impl FromStr for Method {
    type Err = PreisachError;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "closest" => Ok(Method::Closest),
            "interpolated" => Ok(Method::Interpolated),
            "continuous" => Ok(Method::Continuous),
            _ => Err(PreisachError::invalid(
                "method",
                format!("expected one of 'closest', 'interpolated', 'continuous', got '{s}'"),
            )),
        }
    }
}

/// Absolute tolerance of output comparisons for `model` (see [`REL_TOL`]).
pub fn tolerance(model: &PreisachModel) -> f64 {
    REL_TOL * (model.everett().total() + model.offset().abs())
}

/// `true` when `r` lies outside the reachable output range by more than `tol`. The
/// range does not depend on the memory: level 0 wipes every relay off, level n_h
/// switches every relay on.
#[inline]
fn outside(model: &PreisachModel, r: f64, tol: f64) -> bool {
    let total = model.everett().total();
    r < model.output_of(0.0) - tol || r > model.output_of(total) + tol
}

/// The reachable output range `[y(lo), y(hi)]`: the model's output at the ends of its
/// input range, from any memory.
pub fn reachable(model: &PreisachModel) -> (f64, f64) {
    (model.output_of(0.0), model.output_of(model.everett().total()))
}

/// The references outside the reachable output range (the ones every method clips and
/// counts as saturated): how many, and the index of the first.
pub fn saturation(model: &PreisachModel, r: &[f64]) -> (u64, Option<usize>) {
    let tol = tolerance(model);
    let count = r.iter().filter(|&&x| outside(model, x, tol)).count() as u64;
    (count, r.iter().position(|&x| outside(model, x, tol)))
}

// ---------------------------------------------------------------------------------
// Monotone searches over the levels 0..=n (pred false … false true … true).

/// Binary search between a known-false index `f` (−1 = virtual, before 0) and a
/// known-true index `t` (n + 1 = virtual, past the end). Returns the first true index
/// with the outputs at it and just before it (as far as evaluated).
#[inline(always)]
fn bisect<Y: Fn(u32) -> f64, P: Fn(f64) -> bool>(
    y: &Y,
    pred: &P,
    mut f: i64,
    mut yf: f64,
    mut t: i64,
    mut yt: f64,
) -> (i64, f64, f64) {
    while t - f > 1 {
        let m = (f + t) / 2;
        let ym = y(m as u32);
        if pred(ym) {
            t = m;
            yt = ym;
        } else {
            f = m;
            yf = ym;
        }
    }
    (t, yt, yf)
}

/// First index in 0..=n where `pred(y(k))` holds (n + 1 if none), galloping from
/// `start` whose output `ys` is known: O(log distance) peeks, so one or two when the
/// reference moves little between samples, O(log n_h) at worst.
#[inline(always)]
fn gallop<Y: Fn(u32) -> f64, P: Fn(f64) -> bool>(y: &Y, pred: &P, n: i64, start: i64, ys: f64) -> (i64, f64, f64) {
    let mut step = 1i64;
    if pred(ys) {
        let (mut t, mut yt) = (start, ys);
        loop {
            let c = t - step;
            if c < 0 {
                return bisect(y, pred, -1, f64::NEG_INFINITY, t, yt);
            }
            let yc = y(c as u32);
            if pred(yc) {
                t = c;
                yt = yc;
                step *= 2;
            } else {
                return bisect(y, pred, c, yc, t, yt);
            }
        }
    } else {
        let (mut f, mut yf) = (start, ys);
        loop {
            let c = f + step;
            if c > n {
                return bisect(y, pred, f, yf, n + 1, f64::INFINITY);
            }
            let yc = y(c as u32);
            if pred(yc) {
                return bisect(y, pred, f, yf, c, yc);
            }
            f = c;
            yf = yc;
            step *= 2;
        }
    }
}

// ---------------------------------------------------------------------------------
// Closest match (the paper §4.1, Tan et al. 2001).

/// The closest-match level for reference `r` from memory `mem` (nothing mutated), and
/// whether `r` is outside the reachable range.
///
/// Among all levels whose error `|y(k) − r|` is minimal (within `tol`) it returns the
/// one nearest the current level: the minimal-error levels form one contiguous run
/// (output monotone in k), so the answer is the current level clamped into that run.
#[inline]
pub fn closest_level(model: &PreisachModel, mem: &StepMemory, r: f64, tol: f64) -> (u32, bool) {
    let e = model.e_step();
    let y = |k: u32| model.peek_level(mem, k);
    let n = model.n_h() as i64;
    let p = mem.current() as i64;
    let yp = model.output_of(mem.s_plus(&e));
    let sat = outside(model, r, tol);

    // k1: first level reaching r; the nearest outputs are y(k1) and y(k1 − 1).
    let (k1, y_hi, y_lo) = gallop(&y, &|v| v >= r, n, p, yp);
    let e_hi = if k1 <= n { y_hi - r } else { f64::INFINITY };
    let e_lo = if k1 >= 1 { r - y_lo } else { f64::INFINITY };
    let best = e_hi.min(e_lo);
    // The thresholds hold the best output itself: `r ∓ best` alone can round past it
    // when r is far outside the reachable range (large r, small outputs).
    let y_best = if e_hi <= e_lo { y_hi } else { y_lo };
    let (lo_thr, hi_thr) = ((r - best).min(y_best) - tol, (r + best).max(y_best) + tol);

    let k = if yp < lo_thr {
        // Below the minimal-error run: take its first level, in (p, k1].
        let (t, yt) = if k1 >= 1 && y_lo >= lo_thr { (k1 - 1, y_lo) } else { (k1, y_hi) };
        bisect(&y, &|v| v >= lo_thr, p, yp, t, yt).0
    } else if yp > hi_thr {
        // Above it: take its last level, in [k1 − 1, p).
        let (f, yf) = if k1 <= n && y_hi <= hi_thr { (k1, y_hi) } else { (k1 - 1, y_lo) };
        bisect(&y, &|v| v > hi_thr, f, yf, p, yp).0 - 1
    } else {
        p // the previous level is itself optimal: ties stay put
    };
    (k.clamp(0, n) as u32, sat)
}

/// Closest match over a whole reference from memory `mem` (advanced in place). Writes
/// the input levels to `out` and returns the number of saturated samples. `r` must be
/// finite (checked by the caller).
pub fn closest_run(model: &PreisachModel, mem: &mut StepMemory, r: &[f64], out: &mut [f64]) -> u64 {
    let tol = tolerance(model);
    let e = model.e_step();
    let mut sat = 0u64;
    for (o, &x) in out.iter_mut().zip(r) {
        let (k, s) = closest_level(model, mem, x, tol);
        sat += s as u64;
        mem.apply(k, &e);
        *o = model.grid().level(k as usize);
    }
    sat
}

/// The reference before the first sample of a run: any first reference counts as
/// rising, which is the only way out of negative saturation (level 0) anyway.
pub const NO_PREVIOUS_REFERENCE: f64 = f64::NEG_INFINITY;

/// The monotone (direction-consistent) closest-match level for reference `r` after the
/// reference `r_prev`, from memory `mem` (nothing mutated), and whether `r` is outside
/// the reachable range.
///
/// The reference direction is the sign of `r − r_prev`. Rising: the best level among
/// `k >= p` (p = the current level); falling: among `k <= p`; constant: stay at `p`.
/// Ties go to the level nearest `p`, as in [`closest_level`]. So the input never moves
/// against the reference and never dithers on a constant one: no minor loops are
/// traced inside a monotone stretch of the reference.
///
/// Restricted to `k >= p` the output `y(k)` is non-decreasing from `y(p)`, so if
/// `y(p) >= r` staying is optimal there (and the search is skipped); otherwise the
/// unrestricted closest match is already `> p` or `p` itself (its minimal-error run
/// reaches above `y(p)`), so it is the restricted optimum. Falling is the mirror image.
#[inline]
pub fn monotone_level(model: &PreisachModel, mem: &StepMemory, r: f64, r_prev: f64, tol: f64) -> (u32, bool) {
    let p = mem.current();
    let sat = outside(model, r, tol);
    if r == r_prev {
        return (p, sat);
    }
    let yp = model.output_of(mem.s_plus(&model.e_step()));
    let rising = r > r_prev;
    if (rising && yp >= r) || (!rising && yp <= r) {
        return (p, sat);
    }
    let (k, _) = closest_level(model, mem, r, tol);
    // The clamp is the restriction itself; by the argument above it never binds.
    (if rising { k.max(p) } else { k.min(p) }, sat)
}

/// Monotone closest match over a whole reference from memory `mem` (advanced in place),
/// starting after the reference `r_prev` ([`NO_PREVIOUS_REFERENCE`] for a fresh run).
/// Writes the input levels to `out`, returns the number of saturated samples and the
/// last reference. `r` must be finite (checked by the caller).
pub fn monotone_run(
    model: &PreisachModel,
    mem: &mut StepMemory,
    mut r_prev: f64,
    r: &[f64],
    out: &mut [f64],
) -> (u64, f64) {
    let tol = tolerance(model);
    let e = model.e_step();
    let mut sat = 0u64;
    for (o, &x) in out.iter_mut().zip(r) {
        let (k, s) = monotone_level(model, mem, x, r_prev, tol);
        sat += s as u64;
        mem.apply(k, &e);
        *o = model.grid().level(k as usize);
        r_prev = x;
    }
    (sat, r_prev)
}

// ---------------------------------------------------------------------------------
// Continuous inverse of the interpolated model.

/// Input position (level coordinate, 0..=n_h) where the interpolated model reaches `r`
/// from memory `imem` (nothing mutated), and whether `r` is outside the reachable range.
///
/// `y_c` is continuous and non-decreasing in the position (`docs/method/fast-paths.md`, "The interpolated
/// output"), so the solution set is an interval; the point of it nearest the current
/// input is bracketed by a galloping search over the levels, then found by
/// regula falsi (Illinois): `y_c` is linear between levels and stored extrema, so once
/// the iterate sits on the root's segment the next step lands on the root.
/// Unreachable references are clamped to the reachable range first, so the answer is
/// the nearest input giving the extreme output (lo/hi unless the model is flat there).
#[inline]
pub fn continuous_position(model: &PreisachModel, imem: &InterpMemory, r: f64, tol: f64) -> (f64, bool) {
    let e = model.e_interp();
    let n = model.n_h() as i64;
    let pc = imem.current();
    let yc = model.output_of(imem.s_plus(&e));
    let sat = outside(model, r, tol);
    let total = model.everett().total();
    let target = r.clamp(model.output_of(0.0), model.output_of(total));
    if (yc - target).abs() <= tol {
        return (pc, sat);
    }
    let yk = |k: u32| model.peek_position(imem, k as f64);
    let yx = |x: f64| model.peek_position(imem, x);
    if sat {
        // Beyond the range: the end level (or, on a flat end, the level nearest the
        // current input with the extreme output), on the level exactly.
        let k = if yc < target {
            gallop(&yk, &|v| v >= target - tol, n, pc.floor() as i64, f64::NEG_INFINITY).0.min(n)
        } else {
            gallop(&yk, &|v| v > target + tol, n, pc.ceil() as i64, f64::INFINITY).0 - 1
        };
        return (k.max(0) as f64, sat);
    }
    // Aim half a tolerance short of the target on the side we come from: on a plateau at
    // exactly the target this finds its near end, not an arbitrary point of it.
    let half = 0.5 * tol;
    if yc < target {
        let thr = target - half;
        // First level above pc reaching thr; the bracket is [max(pc, k − 1), k].
        let k0 = pc.floor() as i64 + 1; // first level strictly above pc (pc < n here)
        let (k, yk_hi, yk_lo) = gallop(&yk, &|v| v >= thr, n, k0 - 1, f64::NEG_INFINITY);
        let k = k.min(n); // target <= y(n) so k <= n; guard against rounding
        let (a, ya) = if (k - 1) as f64 > pc { ((k - 1) as f64, yk_lo) } else { (pc, yc) };
        (regula_falsi(&yx, thr, a, ya, k as f64, yk_hi.min(model.output_of(total)), half), sat)
    } else {
        let thr = target + half;
        // Last level below pc with output <= thr; the bracket is [k, min(pc, k + 1)].
        let k0 = pc.ceil() as i64 - 1; // first level strictly below pc (pc > 0 here)
        let (t, yt, yf) = gallop(&yk, &|v| v > thr, n, k0 + 1, f64::INFINITY);
        let k = (t - 1).max(0);
        let (b, yb) = if (t as f64) < pc { (t as f64, yt) } else { (pc, yc) };
        (regula_falsi(&yx, thr, k as f64, yf.max(model.output_of(0.0)), b, yb, half), sat)
    }
}

/// Root of `y(x) = thr` in `[a, b]` with `y(a) <= thr <= y(b)`, `y` non-decreasing and
/// piecewise linear: Illinois regula falsi, stopping within `half`. If `y` jumps over
/// `thr` (see the module notes on diagonal cells) the bracket collapses onto the jump
/// and the end whose output is nearer `thr` is returned.
#[inline]
fn regula_falsi<Y: Fn(f64) -> f64>(
    y: &Y,
    thr: f64,
    mut a: f64,
    mut ya: f64,
    mut b: f64,
    mut yb: f64,
    half: f64,
) -> f64 {
    if (yb - thr).abs() <= half {
        return b;
    }
    if (ya - thr).abs() <= half {
        return a;
    }
    // Illinois weights: the stale end's residual is halved so the iteration cannot stall.
    let (mut fa, mut fb) = (ya - thr, yb - thr);
    let width = 4.0 * f64::EPSILON * b.abs().max(1.0);
    let mut side = 0i8;
    for _ in 0..200 {
        if b - a <= width {
            break;
        }
        let mut x = if fb > fa { a - fa * (b - a) / (fb - fa) } else { 0.5 * (a + b) };
        if !(x > a && x < b) {
            x = 0.5 * (a + b);
        }
        let yx = y(x);
        let fx = yx - thr;
        if fx.abs() <= half {
            return x;
        }
        if fx < 0.0 {
            (a, ya, fa) = (x, yx, fx);
            if side == -1 {
                fb *= 0.5;
            }
            side = -1;
        } else {
            (b, yb, fb) = (x, yx, fx);
            if side == 1 {
                fa *= 0.5;
            }
            side = 1;
        }
    }
    if (yb - thr).abs() < (thr - ya).abs() {
        b
    } else {
        a
    }
}

/// Continuous inverse over a whole reference from `imem` (advanced in place). Returns
/// the number of saturated samples. `r` must be finite.
pub fn continuous_run(model: &PreisachModel, imem: &mut InterpMemory, r: &[f64], out: &mut [f64]) -> u64 {
    let tol = tolerance(model);
    let mut sat = 0u64;
    for (o, &x) in out.iter_mut().zip(r) {
        sat += continuous_advance(model, imem, x, tol, &mut *o) as u64;
    }
    sat
}

/// One sample of the continuous inverse: solve, write the input, advance the memory.
#[inline]
fn continuous_advance(model: &PreisachModel, imem: &mut InterpMemory, r: f64, tol: f64, out: &mut f64) -> bool {
    let (pos, sat) = continuous_position(model, imem, r, tol);
    let u = model.grid().value_at(pos);
    // Advance with the position the forward model would compute from `u` itself, so
    // that this memory is exactly the one of `step_interpolated` driven by the output.
    imem.apply(model.grid().position(u), &model.e_interp());
    *out = u;
    sat
}

// ---------------------------------------------------------------------------------
// Linear interpolation between the steps of the closest match (the paper §4.1, Fig. 9).

/// Knot value at a riser: the midpoint of the step from `a` to `b`.
#[inline(always)]
fn midpoint(a: f64, b: f64) -> f64 {
    0.5 * (a + b)
}

/// One sample of the interpolation rule: move from the previous output towards the
/// target knot `(t_tgt, v)`, reaching it exactly at `t_tgt` (linear in between).
#[inline(always)]
fn lerp_step(u_prev: f64, v: f64, t: u64, t_tgt: u64) -> f64 {
    if t_tgt == t {
        v // exactly on the knot, whatever the rounding of the expression below
    } else {
        u_prev + (v - u_prev) / ((t_tgt - t + 1) as f64)
    }
}

/// Offline interpolation of a closest-match signal `u_cm` (the paper's Fig. 9; [`invert`] feeds
/// it the monotone closest match, [`monotone_run`]).
///
/// Knots: `(0, u_cm[0])` and, at every step `t_s` from level `a` to level `b`,
/// `(t_s, (a + b) / 2)` (the riser midpoint). Sample `t` moves from `u[t−1]` towards
/// the first knot in `[t, t + L]`, or, if none, the pseudo-knot `(t + L, u_cm[t + L])`,
/// with the window end clamped to the last sample: `u[t] = u[t−1] + (v − u[t−1]) /
/// (t_tgt − t + 1)`. `lookahead = None` is L infinite: piecewise linear through the
/// knots, ending at `u_cm[T−1]` (unless the last sample is itself a step, whose knot is
/// its midpoint). With a finite L this equals the streaming [`Interpolator`] exactly,
/// shifted by L samples.
pub fn interpolate(u_cm: &[f64], lookahead: Option<usize>, out: &mut [f64]) {
    let n = u_cm.len();
    if n == 0 {
        return;
    }
    let last = (n - 1) as u64;
    let l = lookahead.map_or(u64::MAX, |l| l as u64);
    let mut knots: Vec<(u64, f64)> = Vec::new();
    knots.push((0, u_cm[0]));
    for t in 1..n {
        if u_cm[t] != u_cm[t - 1] {
            knots.push((t as u64, midpoint(u_cm[t - 1], u_cm[t])));
        }
    }
    let mut q = 0usize; // first knot at or after t
    let mut u_prev = u_cm[0];
    for (t, o) in out.iter_mut().enumerate().take(n) {
        let t = t as u64;
        while knots[q..].first().is_some_and(|&(tk, _)| tk < t) {
            q += 1;
        }
        let end = t.saturating_add(l).min(last);
        let (tt, v) = match knots.get(q) {
            Some(&(tk, vk)) if tk <= end => (tk, vk),
            _ => (end, u_cm[end as usize]),
        };
        u_prev = lerp_step(u_prev, v, t, tt);
        *o = u_prev;
    }
}

/// Streaming form of [`interpolate`] with a finite look-ahead `L`: push the
/// closest-match sample `u_cm[t]`, get `u[t − L]` back (the first `L` pushes return
/// the initial input `lo`). The output equals `[lo]·L + interpolate(u_cm, Some(L))[..T−L]`
/// exactly. No allocation per sample: the knot queue holds at most `L + 1` entries.
#[derive(Debug, Clone)]
pub struct Interpolator {
    lookahead: usize,
    lo: f64,
    /// Samples pushed so far.
    t: u64,
    /// Last output `u[t − L − 1]` (`lo` before the first).
    u_prev: f64,
    /// Last closest-match sample pushed.
    last_cm: f64,
    /// Knots with time in `[t − L, t]` (older ones are dropped).
    knots: VecDeque<(u64, f64)>,
}

impl Interpolator {
    /// A fresh interpolator; `lo` is the initial input (level 0).
    pub fn new(lookahead: usize, lo: f64) -> Result<Self> {
        if lookahead > MAX_LOOKAHEAD {
            return Err(PreisachError::invalid(
                "lookahead",
                format!("{lookahead} is too large for streaming (limit {MAX_LOOKAHEAD} samples)"),
            ));
        }
        Ok(Interpolator { lookahead, lo, t: 0, u_prev: lo, last_cm: lo, knots: VecDeque::with_capacity(lookahead + 2) })
    }

    pub fn lookahead(&self) -> usize {
        self.lookahead
    }

    /// Push `u_cm[t]`, return `u[t − L]` (`lo` while `t < L`).
    #[inline]
    pub fn push(&mut self, cm: f64) -> f64 {
        let t = self.t;
        if t == 0 {
            self.knots.push_back((0, cm));
        } else if cm != self.last_cm {
            self.knots.push_back((t, midpoint(self.last_cm, cm)));
        }
        self.last_cm = cm;
        self.t = t + 1;
        let l = self.lookahead as u64;
        if t < l {
            return self.lo;
        }
        let s = t - l; // the sample being emitted; its window is [s, t]
        while self.knots.front().is_some_and(|&(tk, _)| tk < s) {
            self.knots.pop_front();
        }
        let (tt, v) = self.knots.front().copied().unwrap_or((t, cm));
        self.u_prev = lerp_step(self.u_prev, v, s, tt);
        self.u_prev
    }

    /// Back to the initial state (allocation kept).
    pub fn reset(&mut self) {
        self.t = 0;
        self.u_prev = self.lo;
        self.last_cm = self.lo;
        self.knots.clear();
    }
}

// ---------------------------------------------------------------------------------
// Offline entry point and the streaming inverter.

/// Invert the model over a whole reference `r` from negative saturation. Returns the
/// input and the number of references outside the reachable output range (saturated,
/// not an error). `lookahead` is only meaningful for [`Method::Interpolated`]
/// (`None` = the whole record); it must be `None` for the other methods.
pub fn invert(model: &PreisachModel, r: &[f64], method: Method, lookahead: Option<usize>) -> Result<(Vec<f64>, u64)> {
    check_finite("r", r)?;
    check_lookahead(method, lookahead, false)?;
    let mut u = vec![0.0; r.len()];
    let sat = match method {
        Method::Closest => closest_run(model, &mut model.memory(), r, &mut u),
        Method::Interpolated => {
            let mut cm = vec![0.0; r.len()];
            let (sat, _) = monotone_run(model, &mut model.memory(), NO_PREVIOUS_REFERENCE, r, &mut cm);
            interpolate(&cm, lookahead, &mut u);
            sat
        }
        Method::Continuous => continuous_run(model, &mut model.interp_memory(), r, &mut u),
    };
    Ok((u, sat))
}

fn check_lookahead(method: Method, lookahead: Option<usize>, streaming: bool) -> Result<()> {
    match (method, lookahead) {
        (Method::Interpolated, None) if streaming => Err(PreisachError::invalid(
            "lookahead",
            "required for streaming method 'interpolated' (the output is delayed by lookahead samples)",
        )),
        (Method::Closest | Method::Continuous, Some(_)) => Err(PreisachError::invalid(
            "lookahead",
            format!("only used by method 'interpolated'; must be None for '{}'", method.name()),
        )),
        _ => Ok(()),
    }
}

#[derive(Debug, Clone)]
enum Engine {
    Closest(StepMemory),
    /// The monotone closest match's memory, the previous reference, the interpolator.
    Interpolated(StepMemory, f64, Interpolator),
    Continuous(InterpMemory),
}

/// A streaming inverter (any method): one reference sample in, one input sample out,
/// no allocation per sample. Drives the 100 kHz loop through [`Compensator`].
#[derive(Debug, Clone)]
pub struct Inverter {
    model: Arc<PreisachModel>,
    method: Method,
    tol: f64,
    saturated: u64,
    engine: Engine,
}

/// A snapshot of an [`Inverter`]: enough to resume exactly.
#[derive(Debug, Clone, PartialEq)]
pub struct InverterState {
    /// The memory staircase in level coordinates (0 = lo, n_h = hi): the dominant
    /// extrema in order, then the current input (the inverter's own memory: the
    /// closest-match levels for 'closest'/'interpolated', positions for 'continuous').
    pub memory: Vec<f64>,
    /// Saturated samples so far.
    pub saturated: u64,
    /// Interpolation only: samples pushed, last output, last closest-match value
    /// (input units) and the knots `(time, value)` inside the look-ahead window.
    pub t: u64,
    pub u_prev: f64,
    pub last_cm: f64,
    pub knots: Vec<(u64, f64)>,
    /// Interpolation only: the previous reference, which sets the direction of the
    /// monotone closest match ([`NO_PREVIOUS_REFERENCE`] before the first sample).
    pub r_prev: f64,
}

impl Inverter {
    /// A streaming inverter from negative saturation. `lookahead` is required for
    /// [`Method::Interpolated`] (the output lags the reference by that many samples)
    /// and must be `None` otherwise.
    pub fn new(model: Arc<PreisachModel>, method: Method, lookahead: Option<usize>) -> Result<Self> {
        check_lookahead(method, lookahead, true)?;
        let engine = match method {
            Method::Closest => Engine::Closest(model.memory()),
            Method::Interpolated => {
                let interp = Interpolator::new(lookahead.unwrap_or(0), model.grid().lo())?;
                Engine::Interpolated(model.memory(), NO_PREVIOUS_REFERENCE, interp)
            }
            Method::Continuous => Engine::Continuous(model.interp_memory()),
        };
        Ok(Inverter { tol: tolerance(&model), model, method, saturated: 0, engine })
    }

    pub fn method(&self) -> Method {
        self.method
    }
    /// Look-ahead (delay) in samples: the interpolated method's `L`, else 0.
    pub fn lookahead(&self) -> usize {
        match &self.engine {
            Engine::Interpolated(_, _, i) => i.lookahead(),
            _ => 0,
        }
    }
    /// References so far outside the reachable output range (saturated inputs).
    pub fn saturated(&self) -> u64 {
        self.saturated
    }
    pub fn model(&self) -> &Arc<PreisachModel> {
        &self.model
    }

    /// One reference sample in, one input out. `r` must be finite (not checked here:
    /// the per-sample path stays branch-light; [`Inverter::process`] checks blocks).
    #[inline]
    pub fn step(&mut self, r: f64) -> f64 {
        let m = &*self.model;
        match &mut self.engine {
            Engine::Closest(mem) => {
                let (k, s) = closest_level(m, mem, r, self.tol);
                self.saturated += s as u64;
                mem.apply(k, &m.e_step());
                m.grid().level(k as usize)
            }
            Engine::Interpolated(mem, r_prev, interp) => {
                let (k, s) = monotone_level(m, mem, r, *r_prev, self.tol);
                *r_prev = r;
                self.saturated += s as u64;
                mem.apply(k, &m.e_step());
                interp.push(m.grid().level(k as usize))
            }
            Engine::Continuous(imem) => {
                let mut u = 0.0;
                self.saturated += continuous_advance(m, imem, r, self.tol, &mut u) as u64;
                u
            }
        }
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

    /// Back to negative saturation, counters cleared.
    pub fn reset(&mut self) {
        self.saturated = 0;
        match &mut self.engine {
            Engine::Closest(mem) => mem.reset(),
            Engine::Interpolated(mem, r_prev, i) => {
                mem.reset();
                *r_prev = NO_PREVIOUS_REFERENCE;
                i.reset();
            }
            Engine::Continuous(imem) => imem.reset(),
        }
    }

    /// Snapshot of the whole state.
    pub fn state(&self) -> InverterState {
        let mut s = InverterState {
            memory: Vec::new(),
            saturated: self.saturated,
            t: 0,
            u_prev: self.model.grid().lo(),
            last_cm: self.model.grid().lo(),
            knots: Vec::new(),
            r_prev: NO_PREVIOUS_REFERENCE,
        };
        match &self.engine {
            Engine::Closest(mem) => s.memory = mem.snapshot().into_iter().map(f64::from).collect(),
            Engine::Interpolated(mem, r_prev, i) => {
                s.memory = mem.snapshot().into_iter().map(f64::from).collect();
                s.r_prev = *r_prev;
                s.t = i.t;
                s.u_prev = i.u_prev;
                s.last_cm = i.last_cm;
                s.knots = i.knots.iter().copied().collect();
            }
            Engine::Continuous(imem) => s.memory = imem.snapshot(),
        }
        s
    }

    /// Restore a snapshot taken from an inverter of the same model, method and
    /// look-ahead. Validated; on error the inverter is unchanged.
    pub fn set_state(&mut self, s: &InverterState) -> Result<()> {
        let n = self.model.n_h() as f64;
        check_finite("state", &s.memory)?;
        if let Some(i) = s.memory.iter().position(|&x| !(0.0..=n).contains(&x)) {
            return Err(PreisachError::invalid(
                "state",
                format!("memory[{i}] = {} is outside the level range [0, {n}]", s.memory[i]),
            ));
        }
        let m = &*self.model;
        let engine = match &self.engine {
            Engine::Closest(_) | Engine::Interpolated(..) => {
                if let Some(i) = s.memory.iter().position(|&x| x.fract() != 0.0) {
                    return Err(PreisachError::invalid(
                        "state",
                        format!("memory[{i}] = {} is not a level index", s.memory[i]),
                    ));
                }
                let mut mem = m.memory();
                for &k in &s.memory {
                    mem.apply(k as u32, &m.e_step());
                }
                if let Engine::Interpolated(_, _, old) = &self.engine {
                    // -inf is the "no previous reference" marker; NaN and +inf are invalid.
                    if s.r_prev.is_nan() || s.r_prev == f64::INFINITY {
                        return Err(PreisachError::invalid(
                            "state",
                            format!("r_prev must be finite or -inf (no previous reference), got {}", s.r_prev),
                        ));
                    }
                    Engine::Interpolated(mem, s.r_prev, restore_interpolator(old, s)?)
                } else {
                    Engine::Closest(mem)
                }
            }
            Engine::Continuous(_) => {
                let mut imem = m.interp_memory();
                for &p in &s.memory {
                    imem.apply(p, &m.e_interp());
                }
                Engine::Continuous(imem)
            }
        };
        self.engine = engine;
        self.saturated = s.saturated;
        Ok(())
    }
}

fn restore_interpolator(old: &Interpolator, s: &InverterState) -> Result<Interpolator> {
    for (name, x) in [("u_prev", s.u_prev), ("last_cm", s.last_cm)] {
        if !x.is_finite() {
            return Err(PreisachError::invalid("state", format!("{name} must be finite, got {x}")));
        }
    }
    let l = old.lookahead as u64;
    let window_start = s.t.saturating_sub(1).saturating_sub(l);
    let mut prev: Option<u64> = None;
    for &(tk, v) in &s.knots {
        if !v.is_finite() || tk >= s.t || tk < window_start || prev.is_some_and(|p| tk <= p) {
            return Err(PreisachError::invalid(
                "state",
                format!("knot ({tk}, {v}) is not an increasing knot inside the look-ahead window of sample {}", s.t),
            ));
        }
        prev = Some(tk);
    }
    let mut i = old.clone();
    i.t = s.t;
    i.u_prev = s.u_prev;
    i.last_cm = s.last_cm;
    i.knots.clear();
    i.knots.extend(s.knots.iter().copied());
    Ok(i)
}

impl Compensator for Inverter {
    #[inline]
    fn step(&mut self, r: f64) -> f64 {
        Inverter::step(self, r)
    }
    fn reset(&mut self) {
        Inverter::reset(self)
    }
}
