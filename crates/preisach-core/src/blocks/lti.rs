//! Linear blocks: one continuous description, sampled three ways.
//!
//! A linear block (creep, vibration modes, a low-pass filter, the rate branch) is a
//! series of [`Section`]s, each given by partial fractions
//!
//! ```text
//!   H(s) = direct + Σ_k r_k / (s − p_k),
//! ```
//!
//! with distinct stable poles (a pole with a non-zero imaginary part stands for itself
//! and its conjugate), plus a pure delay ([`Lti`]). The series form keeps a block's
//! factors apart (one section per vibration mode), so a block is easy to turn into a
//! product or a quotient of factors.
//!
//! [`Discretization`] samples a section; every pole then becomes the complex one-pole
//! recursion `z[n] = a z[n−1] + b0 x[n−1] + b1 x[n]` whose output is `Re(g z[n])`:
//!
//! - `Zoh`: the input held over the interval that *ends* at each sample (the output is
//!   taken after the update, so a step shows at the sample it is applied);
//! - `Foh`: exact at the samples for an input linear between samples, at any rate;
//! - `Bilinear`: Tustin's transform prewarped at a frequency (the per-sample low-pass:
//!   a Butterworth section sampled so equals `scipy.signal.butter(order, fc, fs=fs)`).
//!
//! [`Filter`] runs the sampled sections (per sample or over a record, starting at rest
//! with an input: every state at its steady value) and applies the exact adjoint of
//! the record pass, which the least-squares fit behind the blocks needs.

use nalgebra::Complex;

use crate::error::{PreisachError, Result};

/// A complex number.
pub type C = Complex<f64>;

/// One factor of a linear block: `direct + Σ r_k / (s − p_k)`; see the module doc.
#[derive(Debug, Clone, PartialEq)]
pub struct Section {
    direct: f64,
    poles: Vec<C>,
    residues: Vec<C>,
}

impl Section {
    /// Checks the description once: everything finite, every pole stable (`Re p < 0`),
    /// a real pole with a real residue. A pole with `Im p < 0` is taken as its conjugate
    /// (with the conjugate residue); equal poles merge (their residues add), so the
    /// poles are distinct.
    pub fn new(direct: f64, terms: impl IntoIterator<Item = (C, C)>) -> Result<Self> {
        let bad = |problem: String| PreisachError::invalid("section", problem);
        if !direct.is_finite() {
            return Err(bad(format!("direct term must be finite, got {direct}")));
        }
        let mut poles: Vec<C> = Vec::new();
        let mut residues: Vec<C> = Vec::new();
        for (p, r) in terms {
            if !(p.re.is_finite() && p.im.is_finite() && r.re.is_finite() && r.im.is_finite()) {
                return Err(bad(format!("pole {p} and residue {r} must be finite")));
            }
            if p.re >= 0.0 {
                return Err(bad(format!("pole {p} is not stable (its real part must be < 0)")));
            }
            if p.im == 0.0 && r.im != 0.0 {
                return Err(bad(format!("the real pole {p} needs a real residue, got {r}")));
            }
            let (p, r) = if p.im < 0.0 { (p.conj(), r.conj()) } else { (p, r) };
            match poles.iter().position(|&q| q == p) {
                Some(k) => residues[k] += r,
                None => {
                    poles.push(p);
                    residues.push(r);
                }
            }
        }
        Ok(Section { direct, poles, residues })
    }

    /// A gain (no poles).
    pub fn gain(k: f64) -> Result<Self> {
        Section::new(k, [])
    }

    pub fn direct(&self) -> f64 {
        self.direct
    }
    /// One pole of each conjugate pair.
    pub fn poles(&self) -> &[C] {
        &self.poles
    }
    pub fn residues(&self) -> &[C] {
        &self.residues
    }

    /// `H(s)`.
    pub fn at(&self, s: C) -> C {
        let mut h = C::new(self.direct, 0.0);
        for (&p, &r) in self.poles.iter().zip(&self.residues) {
            h += r / (s - p);
            if p.im != 0.0 {
                h += r.conj() / (s - p.conj());
            }
        }
        h
    }

    /// The static gain `H(0)`.
    pub fn dc_gain(&self) -> f64 {
        self.at(C::new(0.0, 0.0)).re
    }
}

/// A linear block: sections in series, then a pure delay (seconds, >= 0).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Lti {
    pub sections: Vec<Section>,
    pub delay_s: f64,
}

impl Lti {
    /// Sections in series, no delay.
    pub fn series(sections: Vec<Section>) -> Self {
        Lti { sections, delay_s: 0.0 }
    }

    /// A pure delay.
    pub fn delay(delay_s: f64) -> Self {
        Lti { sections: Vec::new(), delay_s }
    }

    /// `self` then `other`.
    pub fn then(mut self, other: Lti) -> Self {
        self.sections.extend(other.sections);
        self.delay_s += other.delay_s;
        self
    }

    /// Frequency response at `f_hz` (the analog block, delay included).
    pub fn response(&self, f_hz: f64) -> C {
        let w = std::f64::consts::TAU * f_hz;
        let s = C::new(0.0, w);
        let h = self.sections.iter().fold(C::new(1.0, 0.0), |h, sec| h * sec.at(s));
        h * C::from_polar(1.0, -w * self.delay_s)
    }

    /// The static gain.
    pub fn dc_gain(&self) -> f64 {
        self.sections.iter().map(Section::dc_gain).product()
    }
}

/// How a section is sampled; see the module doc.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Discretization {
    Zoh,
    Foh,
    /// Tustin's transform with the frequency `prewarp_hz` mapped exactly (it must lie
    /// below Nyquist).
    Bilinear {
        prewarp_hz: f64,
    },
}

/// How a chain is sampled: per sample (`Zoh`: the simulator and the sample loop; its
/// low-pass filters use Tustin's transform) or over records (`Foh`: predictions and
/// fits, exact for inputs linear between samples at any rate).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Sampling {
    Zoh,
    Foh,
}

impl Sampling {
    /// The discretization of a block sampled the plain way (all but a per-sample
    /// low-pass).
    pub fn plain(self) -> Discretization {
        match self {
            Sampling::Zoh => Discretization::Zoh,
            Sampling::Foh => Discretization::Foh,
        }
    }
}

/// One sampled pole: `z[n] = a z[n−1] + b0 x[n−1] + b1 x[n]`, output `Re(g z[n])`;
/// `init` is the state at rest per unit input (`−1/p`). `real`: every coefficient is
/// real (a real pole), so the state stays real.
#[derive(Debug, Clone, Copy)]
struct Pole {
    a: C,
    b0: C,
    b1: C,
    g: C,
    init: C,
    real: bool,
}

/// `(e^x − 1)/x` and `(e^x − 1 − x)/x²`, by their series where the closed forms cancel.
fn phi12(x: C) -> (C, C) {
    if x.norm() < 1e-4 {
        (1.0 + x / 2.0 + x * x / 6.0, 0.5 + x / 6.0 + x * x / 24.0)
    } else {
        let em1 = x.exp() - 1.0;
        (em1 / x, (em1 - x) / (x * x))
    }
}

impl Pole {
    fn new(p: C, r: C, dt: f64, d: Discretization) -> Self {
        let g = if p.im != 0.0 { 2.0 * r } else { r };
        let init = -1.0 / p;
        let pt = p * dt;
        let (a, b0, b1) = match d {
            Discretization::Zoh => {
                let (phi1, _) = phi12(pt);
                (pt.exp(), C::new(0.0, 0.0), dt * phi1)
            }
            Discretization::Foh => {
                // Exact integrals of e^{p(T−τ)} against the hold's two ramps.
                let (phi1, phi2) = phi12(pt);
                let (i0, i1) = (dt * phi1, dt * phi2);
                (pt.exp(), i0 - i1, i1)
            }
            Discretization::Bilinear { prewarp_hz } => {
                let w = std::f64::consts::TAU * prewarp_hz;
                let k = w / (0.5 * w * dt).tan();
                let b = 1.0 / (k - p);
                ((k + p) * b, b, b)
            }
        };
        let real = [a, b0, b1, g, init].iter().all(|c| c.im == 0.0);
        Pole { a, b0, b1, g, init, real }
    }

    /// Adds this pole's output over a record to `out`, from rest with `x[0]`; returns the
    /// final state. The operations of [`Filter::advance`], in its order (bit for bit the
    /// per-sample recursion); a real pole in real arithmetic (the imaginary parts it
    /// skips are zeros, so the sums are the same).
    fn run(&self, x: &[f64], out: &mut [f64]) -> C {
        if self.real {
            let (a, b0, b1, g) = (self.a.re, self.b0.re, self.b1.re, self.g.re);
            let mut z = self.init.re * x[0];
            out[0] += g * z;
            for (o, w) in out[1..].iter_mut().zip(x.windows(2)) {
                z = a * z + b0 * w[0] + b1 * w[1];
                *o += g * z;
            }
            return C::new(z, 0.0);
        }
        let mut z = self.init * x[0];
        out[0] += (self.g * z).re;
        for (o, w) in out[1..].iter_mut().zip(x.windows(2)) {
            z = self.a * z + self.b0 * w[0] + self.b1 * w[1];
            *o += (self.g * z).re;
        }
        z
    }

    /// Adds this pole's part of the adjoint over a record to `out` (backwards in time,
    /// the operations of the per-sample adjoint in its order; see [`Filter::adjoint`]).
    fn run_adjoint(&self, w: &[f64], out: &mut [f64]) {
        let n = w.len();
        if self.real {
            let (a, b0, b1, g) = (self.a.re, self.b0.re, self.b1.re, self.g.re);
            let mut gn = 0.0;
            for m in (1..n).rev() {
                let gm = g * w[m] + a * gn;
                out[m] += b0 * gn + b1 * gm;
                gn = gm;
            }
            let gm = g * w[0] + a * gn;
            out[0] += b0 * gn + self.init.re * gm;
            return;
        }
        let mut gn = C::new(0.0, 0.0);
        for m in (1..n).rev() {
            let gm = self.g * w[m] + self.a * gn;
            let mut t = self.b0 * gn;
            t += self.b1 * gm;
            out[m] += t.re;
            gn = gm;
        }
        let gm = self.g * w[0] + self.a * gn;
        let mut t = self.b0 * gn;
        t += self.init * gm;
        out[0] += t.re;
    }
}

/// Sampled sections in series with their state: the per-sample recursion, the record
/// pass from rest and its exact adjoint. The per-sample recursion never allocates; the
/// record passes keep one buffer of a record's length.
#[derive(Debug, Clone)]
pub struct Filter {
    poles: Vec<Pole>,
    /// Per section: poles `start..end` and the direct term.
    spans: Vec<(usize, usize, f64)>,
    z: Vec<C>,
    /// Per section: its previous input.
    prev: Vec<f64>,
    settled: bool,
    /// A section's input over a record ([`Filter::apply`], [`Filter::adjoint`]).
    buf: Vec<f64>,
}

impl Filter {
    /// The sections of `lti` sampled every `dt` seconds (its delay is not part of a
    /// filter: see `DelayLine`).
    pub fn new(lti: &Lti, dt: f64, d: Discretization) -> Self {
        Filter::of_sections(&lti.sections, dt, d)
    }

    /// Several blocks in series (the cascade of a fit).
    pub fn cascade(ltis: &[Lti], dt: f64, d: Discretization) -> Self {
        let sections: Vec<Section> = ltis.iter().flat_map(|l| l.sections.iter().cloned()).collect();
        Filter::of_sections(&sections, dt, d)
    }

    /// Sections in series.
    pub fn of(sections: &[Section], dt: f64, d: Discretization) -> Self {
        Filter::of_sections(sections, dt, d)
    }

    fn of_sections(sections: &[Section], dt: f64, d: Discretization) -> Self {
        let mut poles = Vec::new();
        let mut spans = Vec::with_capacity(sections.len());
        for s in sections {
            let start = poles.len();
            poles.extend(s.poles.iter().zip(&s.residues).map(|(&p, &r)| Pole::new(p, r, dt, d)));
            spans.push((start, poles.len(), s.direct));
        }
        let (np, ns) = (poles.len(), spans.len());
        Filter { poles, spans, z: vec![C::new(0.0, 0.0); np], prev: vec![0.0; ns], settled: false, buf: Vec::new() }
    }

    /// Whether the filter has no sections (the identity).
    pub fn is_identity(&self) -> bool {
        self.spans.is_empty()
    }

    /// Every state at rest with the constant input `x`; returns the output then.
    pub fn settle(&mut self, x: f64) -> f64 {
        let mut v = x;
        for (k, &(s, e, d)) in self.spans.iter().enumerate() {
            self.prev[k] = v;
            let mut out = d * v;
            for (f, z) in self.poles[s..e].iter().zip(&mut self.z[s..e]) {
                *z = f.init * v;
                out += (f.g * *z).re;
            }
            v = out;
        }
        self.settled = true;
        v
    }

    /// One sample. The first sample after construction or [`Filter::reset`] finds the
    /// filter at rest with it.
    #[inline]
    pub fn step(&mut self, x: f64) -> f64 {
        if !self.settled {
            return self.settle(x);
        }
        self.advance(x)
    }

    /// One sample of a settled filter.
    #[inline(always)]
    fn advance(&mut self, x: f64) -> f64 {
        let mut v = x;
        for (k, &(s, e, d)) in self.spans.iter().enumerate() {
            let vp = self.prev[k];
            let mut out = d * v;
            for (f, z) in self.poles[s..e].iter().zip(&mut self.z[s..e]) {
                *z = f.a * *z + f.b0 * vp + f.b1 * v;
                out += (f.g * *z).re;
            }
            self.prev[k] = v;
            v = out;
        }
        v
    }

    /// Back to rest: the next sample settles the filter.
    pub fn reset(&mut self) {
        self.settled = false;
    }

    /// The state as numbers: settled (0 or 1), the poles' states (re, im), the
    /// sections' previous inputs.
    pub fn state(&self) -> Vec<f64> {
        let mut s = vec![f64::from(u8::from(self.settled))];
        s.extend(self.z.iter().flat_map(|z| [z.re, z.im]));
        s.extend_from_slice(&self.prev);
        s
    }

    /// Restore [`Filter::state`] of a filter of the same sections; on error unchanged.
    pub fn set_state(&mut self, s: &[f64]) -> Result<()> {
        let (np, ns) = (self.z.len(), self.prev.len());
        if s.len() != 1 + 2 * np + ns || !(s[0] == 0.0 || s[0] == 1.0) {
            return Err(PreisachError::invalid(
                "state",
                format!("a filter state of {} numbers (settled 0/1 first) expected, got {}", 1 + 2 * np + ns, s.len()),
            ));
        }
        crate::error::check_finite("state", s)?;
        self.settled = s[0] == 1.0;
        for (k, z) in self.z.iter_mut().enumerate() {
            *z = C::new(s[1 + 2 * k], s[2 + 2 * k]);
        }
        self.prev.copy_from_slice(&s[1 + 2 * np..]);
        Ok(())
    }

    /// `y = L x` over a record, starting at rest with `x[0]`: section by section, each
    /// pole's recursion over the whole record (its state stays in registers; a pass per
    /// sample through every pole waits on memory), summed per sample in the order of
    /// [`Filter::step`], so bit for bit its output; two or three sections of one pole
    /// each run side by side (`Filter::apply_fused`). Leaves the filter settled at the
    /// record's end.
    pub fn apply(&mut self, x: &[f64], y: &mut [f64]) {
        self.reset();
        let n = x.len().min(y.len());
        if n == 0 {
            return;
        }
        let y = &mut y[..n];
        if self.spans.is_empty() {
            y.copy_from_slice(&x[..n]);
            return;
        }
        match (self.spans.len(), self.one_pole_each()) {
            (2, true) => return self.apply_fused::<2>(&x[..n], y),
            (3, true) => return self.apply_fused::<3>(&x[..n], y),
            _ => {}
        }
        for k in 0..self.spans.len() {
            // A section's input: the record, then the previous section's output.
            if k > 0 {
                self.buf.clear();
                self.buf.extend_from_slice(y);
            }
            let inp = if k == 0 { &x[..n] } else { &self.buf[..] };
            let (s, e, d) = self.spans[k];
            y.iter_mut().zip(inp).for_each(|(o, &v)| *o = d * v);
            for (f, z) in self.poles[s..e].iter().zip(&mut self.z[s..e]) {
                *z = f.run(inp, y);
            }
            self.prev[k] = inp[n - 1];
        }
        self.settled = true;
    }

    /// Whether every section has one pole (a mode, a creep element, a low-pass of order
    /// one or two): the record passes then run the sections side by side.
    fn one_pole_each(&self) -> bool {
        self.spans.iter().all(|&(s, e, _)| e == s + 1)
    }

    /// The poles and direct terms of `N` sections of one pole each.
    fn fused<const N: usize>(&self) -> ([Pole; N], [f64; N]) {
        (std::array::from_fn(|k| self.poles[self.spans[k].0]), std::array::from_fn(|k| self.spans[k].2))
    }

    /// [`Filter::apply`] for `N` sections of one pole each: settled on the first sample,
    /// then one pass over the record, a sample through every section in turn
    /// ([`Filter::advance`]'s operations in its order, so bit for bit the same), the
    /// states in registers. The sections' recursions then overlap instead of each
    /// waiting for the whole record's pass of the last.
    fn apply_fused<const N: usize>(&mut self, x: &[f64], y: &mut [f64]) {
        let (f, d) = self.fused::<N>();
        y[0] = self.settle(x[0]);
        let mut z: [C; N] = std::array::from_fn(|k| self.z[self.spans[k].0]);
        let mut prev: [f64; N] = std::array::from_fn(|k| self.prev[k]);
        for (o, &xn) in y[1..].iter_mut().zip(&x[1..]) {
            let mut v = xn;
            for k in 0..N {
                let mut out = d[k] * v;
                z[k] = f[k].a * z[k] + f[k].b0 * prev[k] + f[k].b1 * v;
                out += (f[k].g * z[k]).re;
                prev[k] = v;
                v = out;
            }
            *o = v;
        }
        for (k, &(s, _, _)) in self.spans.iter().enumerate() {
            self.z[s] = z[k];
            self.prev[k] = prev[k];
        }
    }

    /// [`Filter::adjoint`] for `N` sections of one pole each: one pass backwards in time,
    /// the sections' adjoints side by side in reverse order (each pole's operations in
    /// the order of the pass per section).
    fn adjoint_fused<const N: usize>(&self, w: &[f64], x: &mut [f64]) {
        let (f, d) = self.fused::<N>();
        let mut gn = [C::new(0.0, 0.0); N];
        for (o, &wm) in x[1..].iter_mut().zip(&w[1..]).rev() {
            *o = back_sample(&f, &d, &mut gn, wm, |p| p.b1);
        }
        x[0] = back_sample(&f, &d, &mut gn, w[0], |p| p.init);
    }

    /// `x = Lᵀ w`: the exact adjoint of [`Filter::apply`] (the at-rest start included),
    /// the sections' adjoints in reverse order, each pole backwards in time (two or three
    /// sections of one pole each side by side, `Filter::adjoint_fused`).
    pub fn adjoint(&mut self, w: &[f64], x: &mut [f64]) {
        let n = w.len().min(x.len());
        let x = &mut x[..n];
        self.settled = false;
        if n > 0 {
            match (self.spans.len(), self.one_pole_each()) {
                (2, true) => return self.adjoint_fused::<2>(&w[..n], x),
                (3, true) => return self.adjoint_fused::<3>(&w[..n], x),
                _ => {}
            }
        }
        x.copy_from_slice(&w[..n]);
        // G[m] = Σ_{k >= m} a^{k−m} g w[k]; x[m] gets b1 G[m] (m >= 1), b0 G[m+1]
        // (m <= n−2) and init G[0] (m = 0).
        for k in (0..self.spans.len()).rev() {
            if n == 0 {
                break;
            }
            self.buf.clear();
            self.buf.extend_from_slice(x);
            let (s, e, d) = self.spans[k];
            x.iter_mut().zip(&self.buf).for_each(|(o, &v)| *o = d * v);
            for f in &self.poles[s..e] {
                f.run_adjoint(&self.buf, x);
            }
        }
    }
}

/// One sample of [`Filter::adjoint_fused`]: `v` through the sections' adjoints in
/// reverse order, `gn` their states; `now` gives a pole's coefficient of the sample's own
/// term (`b1`, or `init` at the record's first sample, the at-rest start).
#[inline(always)]
fn back_sample<const N: usize>(
    f: &[Pole; N],
    d: &[f64; N],
    gn: &mut [C; N],
    mut v: f64,
    now: impl Fn(&Pole) -> C,
) -> f64 {
    for k in (0..N).rev() {
        let gm = f[k].g * v + f[k].a * gn[k];
        let mut t = f[k].b0 * gn[k];
        t += now(&f[k]) * gm;
        let mut out = d[k] * v;
        out += t.re;
        gn[k] = gm;
        v = out;
    }
    v
}

/// Largest delay accepted, in samples (keeps the ring buffer at most 128 MB).
pub const MAX_DELAY_SAMPLES: f64 = 16_000_000.0;

/// A pure delay `y[n] = x(n − D)`, `D` samples: an integer ring buffer plus linear
/// interpolation for the fractional part (exact for an input linear between samples).
/// At rest, the line holds the first input (the signal held it before the record).
#[derive(Debug, Clone)]
pub struct DelayLine {
    buf: Vec<f64>,
    mask: usize,
    head: usize,
    n_int: usize,
    frac: f64,
    settled: bool,
}

impl DelayLine {
    /// `delay_s` (>= 0, checked by the caller) at `sample_rate_hz`.
    pub fn new(delay_s: f64, sample_rate_hz: f64) -> Result<Self> {
        let d = delay_s * sample_rate_hz;
        if d > MAX_DELAY_SAMPLES {
            return Err(PreisachError::invalid(
                "delay_s",
                format!("{delay_s:e} s is {d:.3e} samples, above the limit of {MAX_DELAY_SAMPLES:.0}"),
            ));
        }
        let mut n_int = d.floor() as usize;
        let mut frac = d - n_int as f64;
        // Snap delays within rounding of an integer (e.g. 3e-5 s · 1e5 Hz) to it.
        if frac > 1.0 - 1e-9 {
            n_int += 1;
            frac = 0.0;
        } else if frac < 1e-9 {
            frac = 0.0;
        }
        // Power-of-two length: the index wraps with a mask, no division per sample.
        let len = (n_int + 2).next_power_of_two();
        Ok(DelayLine { buf: vec![0.0; len], mask: len - 1, head: 0, n_int, frac, settled: false })
    }

    /// Delay in samples (integer + fractional part).
    pub fn samples(&self) -> f64 {
        self.n_int as f64 + self.frac
    }

    /// Fill the line with `x`.
    pub fn settle(&mut self, x: f64) -> f64 {
        self.buf.iter_mut().for_each(|v| *v = x);
        self.settled = true;
        x
    }

    #[inline]
    pub fn step(&mut self, x: f64) -> f64 {
        if !self.settled {
            self.settle(x);
        }
        self.head = (self.head + 1) & self.mask;
        self.buf[self.head] = x;
        let a = self.buf[(self.head.wrapping_sub(self.n_int)) & self.mask];
        let b = self.buf[(self.head.wrapping_sub(self.n_int + 1)) & self.mask];
        a + self.frac * (b - a)
    }

    /// Back to rest: the next sample fills the line.
    pub fn reset(&mut self) {
        self.head = 0;
        self.settled = false;
    }

    /// The state as numbers: settled (0 or 1), the head, the ring buffer.
    pub fn state(&self) -> Vec<f64> {
        let mut s = vec![f64::from(u8::from(self.settled)), self.head as f64];
        s.extend_from_slice(&self.buf);
        s
    }

    /// Restore [`DelayLine::state`] of a line of the same delay; on error unchanged.
    pub fn set_state(&mut self, s: &[f64]) -> Result<()> {
        let n = self.buf.len();
        let ok =
            s.len() == 2 + n && (s[0] == 0.0 || s[0] == 1.0) && s[1] >= 0.0 && s[1] < n as f64 && s[1].fract() == 0.0;
        if !ok {
            return Err(PreisachError::invalid(
                "state",
                format!("a delay-line state of {} numbers (settled 0/1, head < {n}, buffer) expected", 2 + n),
            ));
        }
        crate::error::check_finite("state", s)?;
        self.settled = s[0] == 1.0;
        self.head = s[1] as usize;
        self.buf.copy_from_slice(&s[2..]);
        Ok(())
    }
}

/// A linear block at run time: its sampled sections, then its delay line.
#[derive(Debug, Clone)]
pub struct Linear {
    filter: Filter,
    delay: Option<DelayLine>,
}

impl Linear {
    pub fn new(lti: &Lti, sample_rate_hz: f64, d: Discretization) -> Result<Self> {
        let filter = Filter::new(lti, 1.0 / sample_rate_hz, d);
        let delay = DelayLine::new(lti.delay_s, sample_rate_hz)?;
        let delay = if delay.samples() > 0.0 { Some(delay) } else { None };
        Ok(Linear { filter, delay })
    }

    #[inline]
    pub fn step(&mut self, x: f64) -> f64 {
        let y = self.filter.step(x);
        match &mut self.delay {
            Some(d) => d.step(y),
            None => y,
        }
    }

    /// At rest with `x`; returns the output then.
    pub fn settle(&mut self, x: f64) -> f64 {
        let y = self.filter.settle(x);
        match &mut self.delay {
            Some(d) => d.settle(y),
            None => y,
        }
    }

    pub fn reset(&mut self) {
        self.filter.reset();
        if let Some(d) = &mut self.delay {
            d.reset();
        }
    }
}
