//! The stable inverse of linear blocks, limited to a bandwidth (`docs/method/inversion.md`,
//! "Inverting a chain").
//!
//! A section `S(s) = K Π(s − z_j) / Π(s − p_k)` of relative degree `d` (its zeros `z_j`
//! found as the roots of its numerator) is inverted as `T = S⁻¹ F_d`, where `F_d` is a
//! Butterworth low-pass of order `d` at the bandwidth (static gain 1): `T` is proper,
//! and stable when `S` is minimum phase (every zero in the left half plane). `T` is
//! returned as a [`Section`] in partial fractions (its poles: the zeros of `S` and the
//! poles of `F_d`), so it is sampled like any linear block.
//!
//! The low-pass delays the signal by its group delay at low frequency,
//! `τ_F = Σ −Re(1/q)` over its poles `q`; a Butterworth filter matches the delay to
//! second order (`F(s) e^{sτ_F} = 1 + O(s³)`), so taking `τ_F` back by preview leaves
//! an error of order `(f / f_bandwidth)³` at a frequency `f` of the reference.

use nalgebra::DMatrix;

use super::lti::{Lti, Section, C};
use crate::error::{PreisachError, Result};

/// The inverse of a series of linear blocks: sections to run, and the preview (seconds)
/// the reference must be taken ahead by (the blocks' delay plus the low-passes' group
/// delay).
#[derive(Debug, Clone, PartialEq)]
pub struct LinearInverse {
    pub sections: Vec<Section>,
    pub preview_s: f64,
}

/// Relative tolerance on a zero's real part (at or above it: not minimum phase).
const MIN_PHASE_TOL: f64 = 1e-9;

/// The poles of a Butterworth low-pass of order `d` at `wb` rad/s (all of them,
/// conjugates included).
fn butterworth_poles(d: usize, wb: f64) -> Vec<C> {
    (0..d)
        .map(|k| {
            let p = C::from_polar(wb, std::f64::consts::PI * (2 * k + d + 1) as f64 / (2 * d) as f64);
            if p.im.abs() <= 1e-12 * wb {
                C::new(p.re, 0.0)
            } else {
                p
            }
        })
        .collect()
}

/// Ascending coefficients of `Π (x − r)`.
fn poly_from_roots(roots: &[C]) -> Vec<C> {
    let mut c = vec![C::new(1.0, 0.0)];
    for &r in roots {
        let mut next = vec![C::new(0.0, 0.0); c.len() + 1];
        for (k, &ck) in c.iter().enumerate() {
            next[k + 1] += ck;
            next[k] -= r * ck;
        }
        c = next;
    }
    c
}

/// `p(x)` and `p'(x)` by Horner (ascending coefficients).
fn horner(c: &[f64], x: C) -> (C, C) {
    let (mut p, mut dp) = (C::new(0.0, 0.0), C::new(0.0, 0.0));
    for &ck in c.iter().rev() {
        dp = dp * x + p;
        p = p * x + ck;
    }
    (p, dp)
}

/// Roots of the real polynomial with ascending coefficients `c` (leading one non-zero):
/// eigenvalues of the companion matrix, polished by Newton's method, conjugate pairs
/// made exact.
fn poly_roots(c: &[f64]) -> Vec<C> {
    let m = c.len() - 1;
    if m == 0 {
        return Vec::new();
    }
    let lead = c[m];
    let mut comp = DMatrix::<f64>::zeros(m, m);
    for k in 0..m {
        comp[(0, k)] = -c[m - 1 - k] / lead;
        if k + 1 < m {
            comp[(k + 1, k)] = 1.0;
        }
    }
    let mut roots: Vec<C> = comp.complex_eigenvalues().iter().copied().collect();
    for z in &mut roots {
        for _ in 0..8 {
            let (p, dp) = horner(c, *z);
            if dp.norm() == 0.0 {
                break;
            }
            let next = *z - p / dp;
            if horner(c, next).0.norm() >= p.norm() {
                break;
            }
            *z = next;
        }
        if z.im.abs() <= 1e-8 * z.norm() {
            z.im = 0.0;
        }
    }
    // Conjugate pairs exact: keep the upper member, mirror it.
    let upper: Vec<C> = roots.iter().copied().filter(|z| z.im > 0.0).collect();
    let mut out: Vec<C> = roots.into_iter().filter(|z| z.im == 0.0).collect();
    for z in upper {
        out.push(z);
        out.push(z.conj());
    }
    out
}

/// Every pole of a section with its residue (conjugates included).
fn full_terms(s: &Section) -> Vec<(C, C)> {
    let mut t = Vec::new();
    for (&p, &r) in s.poles().iter().zip(s.residues()) {
        t.push((p, r));
        if p.im != 0.0 {
            t.push((p.conj(), r.conj()));
        }
    }
    t
}

/// `S(s) = K Π(s − z)/Π(s − p)`: the zeros (conjugates included) and `K`.
fn zeros_and_gain(s: &Section) -> Result<(Vec<C>, f64)> {
    let terms = full_terms(s);
    let n = terms.len();
    if n == 0 {
        return Ok((Vec::new(), s.direct()));
    }
    // Scale s by the fastest pole so the numerator's coefficients are of order one.
    let w = terms.iter().map(|(p, _)| p.norm()).fold(0.0, f64::max);
    let poles: Vec<C> = terms.iter().map(|&(p, _)| p / w).collect();
    let mut num = poly_from_roots(&poles);
    num.iter_mut().for_each(|c| *c *= s.direct());
    let mut scale = s.direct().abs();
    for (k, &(_, r)) in terms.iter().enumerate() {
        let others: Vec<C> = poles.iter().enumerate().filter(|&(j, _)| j != k).map(|(_, &p)| p).collect();
        for (c, o) in num.iter_mut().zip(poly_from_roots(&others)) {
            *c += r / w * o;
        }
        scale += (r / w).norm();
    }
    let tol = 1e-9 * scale * (1u64 << n.min(60)) as f64;
    let mut re: Vec<f64> = num.iter().map(|c| c.re).collect();
    while re.len() > 1 && re.last().is_some_and(|c| c.abs() <= tol) {
        re.pop();
    }
    if re.iter().all(|c| c.abs() <= tol) {
        return Err(PreisachError::invalid("section", "its gain is zero at every frequency: it cannot be inverted"));
    }
    let zeros: Vec<C> = poly_roots(&re).into_iter().map(|z| z * w).collect();
    // K from one point away from every pole and zero (in the right half plane).
    let s0 = C::new(w, w);
    let num_s0: C = zeros.iter().map(|&z| s0 - z).product();
    let den_s0: C = terms.iter().map(|&(p, _)| s0 - p).product();
    let k = (s.at(s0) * den_s0 / num_s0).re;
    Ok((zeros, k))
}

/// `S⁻¹ F_d` for one section (see the module doc), and the group delay of `F_d`.
fn invert_section(s: &Section, wb: f64) -> Result<(Section, f64)> {
    let (zeros, k) = zeros_and_gain(s)?;
    if let Some(z) = zeros.iter().find(|z| z.re >= -MIN_PHASE_TOL * z.norm()) {
        let what = if z.norm() == 0.0 {
            "a zero at s = 0 (no static gain)".to_string()
        } else {
            format!("a zero at {z:.4e} rad/s")
        };
        return Err(PreisachError::invalid(
            "section",
            format!("not minimum phase ({what}): its inverse would be unstable"),
        ));
    }
    let poles: Vec<C> = full_terms(s).into_iter().map(|(p, _)| p).collect();
    let d = poles.len() - zeros.len();
    let q = butterworth_poles(d, wb);
    let fgain: f64 = q.iter().map(|&p| -p).product::<C>().re;
    let delay: f64 = q.iter().map(|&p| -(1.0 / p).re).sum();
    let sigma: Vec<C> = zeros.iter().chain(&q).copied().collect();
    for (a, &x) in sigma.iter().enumerate() {
        if sigma[a + 1..].iter().any(|&y| (x - y).norm() <= 1e-9 * x.norm()) {
            return Err(PreisachError::invalid(
                "bandwidth_hz",
                format!(
                    "a pole of the low-pass falls on a zero of the block ({x:.4e} rad/s): choose another bandwidth"
                ),
            ));
        }
    }
    let direct = fgain / k;
    let mut terms = Vec::new();
    for (a, &x) in sigma.iter().enumerate() {
        if x.im < 0.0 {
            continue;
        }
        let num: C = poles.iter().map(|&p| x - p).product::<C>() * direct;
        let den: C = sigma.iter().enumerate().filter(|&(b, _)| b != a).map(|(_, &y)| x - y).product();
        let r = num / den;
        terms.push((x, if x.im == 0.0 { C::new(r.re, 0.0) } else { r }));
    }
    Ok((Section::new(direct, terms)?, delay))
}

/// The inverse of `ltis` in series (see the module doc) with low-passes at
/// `bandwidth_hz`. Errors name the block (`blocks[k] (kind)`) through `name_of`.
pub fn invert_ltis(ltis: &[(String, Lti)], bandwidth_hz: f64) -> Result<LinearInverse> {
    let wb = std::f64::consts::TAU * bandwidth_hz;
    let mut sections = Vec::new();
    let mut preview_s = 0.0;
    for (name, lti) in ltis {
        for s in &lti.sections {
            let (t, tau) = invert_section(s, wb).map_err(|e| match e {
                PreisachError::Invalid { name: n, problem } if n == "section" => {
                    PreisachError::invalid(name.clone(), problem)
                }
                other => other,
            })?;
            sections.push(t);
            preview_s += tau;
        }
        preview_s += lti.delay_s;
    }
    Ok(LinearInverse { sections, preview_s })
}

/// The fastest natural frequency (Hz) among the sections that need a low-pass (relative
/// degree > 0), or `None` if none does.
pub fn fastest_lag_hz(ltis: &[(String, Lti)]) -> Result<Option<f64>> {
    let mut f: Option<f64> = None;
    for (_, lti) in ltis {
        for s in &lti.sections {
            let (zeros, _) = zeros_and_gain(s)?;
            let poles = full_terms(s);
            if poles.len() > zeros.len() {
                let w = poles.iter().map(|(p, _)| p.norm()).fold(0.0, f64::max);
                let hz = w / std::f64::consts::TAU;
                f = Some(f.map_or(hz, |g| g.max(hz)));
            }
        }
    }
    Ok(f)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::blocks::{CreepParams, LowpassParams, Mode, VibrationParams};

    fn check_product(lti: &Lti, bw: f64) {
        let inv = invert_ltis(&[("b".into(), lti.clone())], bw).unwrap();
        let wb = std::f64::consts::TAU * bw;
        for f in [0.0, 3.0, 100.0, 777.0, 5e3] {
            let s = C::new(0.0, std::f64::consts::TAU * f);
            let g: C = lti.sections.iter().map(|x| x.at(s)).product();
            let t: C = inv.sections.iter().map(|x| x.at(s)).product();
            // Every section's low-pass is a Butterworth at wb of the section's degree.
            let fl: C = lti
                .sections
                .iter()
                .map(|x| {
                    let (z, _) = zeros_and_gain(x).unwrap();
                    let d = full_terms(x).len() - z.len();
                    butterworth_poles(d, wb).iter().map(|&q| -q / (s - q)).product::<C>()
                })
                .product();
            assert!((g * t - fl).norm() < 1e-9, "f = {f}: {} vs {}", g * t, fl);
        }
    }

    #[test]
    fn inverse_times_block_is_the_lowpass() {
        check_product(&CreepParams::log_law(0.01, 0.1, 100.0).lti().unwrap(), 2e3);
        let modes = vec![Mode { frequency_hz: 780.0, damping: 0.02 }, Mode { frequency_hz: 1300.0, damping: 1.5 }];
        check_product(&VibrationParams { modes }.lti().unwrap(), 3e3);
        for order in 1..=4 {
            check_product(&LowpassParams { cutoff_hz: 900.0, order }.lti().unwrap(), 4e3);
        }
    }

    #[test]
    fn non_minimum_phase_is_refused() {
        // 1 − 2/(1 + s): a zero at s = +1.
        let s = Section::new(1.0, [(C::new(-1.0, 0.0), C::new(-2.0, 0.0))]).unwrap();
        let e = invert_ltis(&[("blocks[1] (creep)".into(), Lti::series(vec![s]))], 10.0).unwrap_err();
        assert!(e.to_string().contains("blocks[1] (creep): not minimum phase"), "{e}");
    }
}
