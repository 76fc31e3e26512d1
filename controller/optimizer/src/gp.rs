//! Gaussian-process regression on the unit cube: Matérn 5/2 ARD kernel with a
//! learned noise term, standardised outputs, hyperparameters by maximising the
//! log marginal likelihood (plus weak log-normal priors that keep them sane
//! with few points) with a deterministic multi-start projected L-BFGS.
//!
//! The L-BFGS is our own, not argmin's: argmin's L-BFGS has no box
//! constraints, and wrapped in a projection plus penalty it fitted no better
//! and took 13-24 % more CPU time while adding 16 crates (issue 16; numbers in
//! the crate's README).

use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::rng::Rng;

const SQRT5: f64 = 2.236_067_977_499_79;
const JITTER: f64 = 1e-9;

/// Kernel hyperparameters in log space (lengthscales in unit-cube units; signal
/// and noise variance relative to the standardised output).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Hyper {
    pub log_ls: Vec<f64>,
    pub log_sf2: f64,
    pub log_sn2: f64,
}

impl Hyper {
    /// The prior's centre for `dim` inputs.
    pub fn default_for(dim: usize) -> Self {
        Self {
            log_ls: vec![prior_ls_mean(dim); dim],
            log_sf2: 0.0,
            log_sn2: PRIOR_SN2_MEAN,
        }
    }

    fn to_vec(&self) -> Vec<f64> {
        let mut v = self.log_ls.clone();
        v.push(self.log_sf2);
        v.push(self.log_sn2);
        v
    }

    fn from_slice(v: &[f64]) -> Self {
        let d = v.len() - 2;
        Self {
            log_ls: v[..d].to_vec(),
            log_sf2: v[d],
            log_sn2: v[d + 1],
        }
    }
}

fn prior_ls_mean(dim: usize) -> f64 {
    // Longer lengthscales in more dimensions (distances in the cube grow like sqrt(d)).
    (0.35 * (dim as f64).sqrt().max(1.0)).ln()
}
const PRIOR_LS_SD: f64 = 1.0;
const PRIOR_SF2_SD: f64 = 1.5;
const PRIOR_SN2_MEAN: f64 = -6.9; // ~1e-3 of the output variance
const PRIOR_SN2_SD: f64 = 2.5;
const LOG_LS_BOUNDS: (f64, f64) = (-4.6, 3.0);
const LOG_SF2_BOUNDS: (f64, f64) = (-4.0, 4.0);
const LOG_SN2_BOUNDS: (f64, f64) = (-13.8, 1.0);

/// How hard to fit hyperparameters.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FitOptions {
    /// Random starting points besides the warm start and the prior centre; all
    /// starting points are screened by one posterior evaluation each.
    pub random_starts: usize,
    /// L-BFGS runs, from the best-screened starting points.
    pub local_runs: usize,
    /// L-BFGS iterations per run.
    pub max_iter: usize,
    /// Upper bound on every lengthscale (unit-cube units); safe exploration
    /// caps it so the constraint models cannot extrapolate far with confidence.
    pub max_lengthscale: Option<f64>,
    /// Lower bound on the signal variance (standardised units); safe
    /// exploration sets 1 so flat data cannot shrink the prior uncertainty.
    pub min_signal_var: Option<f64>,
    /// Smallest output scale used for standardisation (metric units), so that a
    /// handful of identical values do not make the model overconfident.
    pub min_scale: f64,
}

impl Default for FitOptions {
    fn default() -> Self {
        Self {
            random_starts: 4,
            local_runs: 1,
            max_iter: 20,
            max_lengthscale: None,
            min_signal_var: None,
            min_scale: 1e-9,
        }
    }
}

/// A fitted Gaussian process.
#[derive(Debug, Clone)]
pub struct Gp {
    x: Vec<Vec<f64>>,
    inv_ls2: Vec<f64>,
    sf2: f64,
    y_mean: f64,
    y_scale: f64,
    chol: DMatrix<f64>,
    alpha: DVector<f64>,
    hyper: Hyper,
}

/// Pairwise squared differences per dimension, `d[k][a * n + b]`.
struct Pairs {
    n: usize,
    d: Vec<Vec<f64>>,
}

impl Pairs {
    fn new(x: &[Vec<f64>]) -> Self {
        let n = x.len();
        let dim = x.first().map_or(0, Vec::len);
        let d = (0..dim)
            .map(|k| {
                let mut m = vec![0.0; n * n];
                for a in 0..n {
                    for b in 0..a {
                        let t = x[a][k] - x[b][k];
                        m[a * n + b] = t * t;
                        m[b * n + a] = t * t;
                    }
                }
                m
            })
            .collect();
        Self { n, d }
    }

    fn r2(&self, inv_ls2: &[f64]) -> Vec<f64> {
        let mut r2 = vec![0.0; self.n * self.n];
        for (dk, &w) in self.d.iter().zip(inv_ls2) {
            for (r, &v) in r2.iter_mut().zip(dk) {
                *r += v * w;
            }
        }
        r2
    }
}

fn matern52(r: f64) -> f64 {
    let s = SQRT5 * r;
    (1.0 + s + s * s / 3.0) * (-s).exp()
}

fn standardise(y: &[f64], min_scale: f64) -> (f64, f64, Vec<f64>) {
    let n = y.len().max(1) as f64;
    let mean = y.iter().sum::<f64>() / n;
    let var = y.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / n;
    let scale = var.sqrt().max(min_scale).max(1e-12);
    (mean, scale, y.iter().map(|v| (v - mean) / scale).collect())
}

fn log_prior(h: &[f64], dim: usize) -> (f64, Vec<f64>) {
    let mut lp = 0.0;
    let mut g = vec![0.0; h.len()];
    let mut add = |i: usize, mean: f64, sd: f64| {
        let z = (h[i] - mean) / sd;
        lp -= 0.5 * z * z;
        g[i] -= z / sd;
    };
    for i in 0..dim {
        add(i, prior_ls_mean(dim), PRIOR_LS_SD);
    }
    add(dim, 0.0, PRIOR_SF2_SD);
    add(dim + 1, PRIOR_SN2_MEAN, PRIOR_SN2_SD);
    (lp, g)
}

/// Negative log posterior (up to a constant) and its gradient, or `None` when
/// the covariance is not positive definite.
fn neg_log_posterior(h: &[f64], pairs: &Pairs, z: &DVector<f64>) -> Option<(f64, Vec<f64>)> {
    let n = pairs.n;
    let dim = h.len() - 2;
    let inv_ls2: Vec<f64> = h[..dim].iter().map(|l| (-2.0 * l).exp()).collect();
    let sf2 = h[dim].exp();
    let sn2 = h[dim + 1].exp();
    let r2 = pairs.r2(&inv_ls2);
    let mut k = DMatrix::<f64>::zeros(n, n);
    // common[a*n+b] = sf2 * 5/3 * (1 + sqrt5 r) exp(-sqrt5 r): d k / d log ls_k = common * d_k / ls_k^2
    let mut common = vec![0.0; n * n];
    for a in 0..n {
        for b in 0..n {
            let r = r2[a * n + b].sqrt();
            let e = (-SQRT5 * r).exp();
            k[(a, b)] = sf2 * (1.0 + SQRT5 * r + 5.0 / 3.0 * r * r) * e;
            common[a * n + b] = sf2 * 5.0 / 3.0 * (1.0 + SQRT5 * r) * e;
        }
        k[(a, a)] += sn2 + JITTER;
    }
    let chol = k.clone().cholesky()?;
    let alpha = chol.solve(z);
    let logdet: f64 = chol
        .l_dirty()
        .diagonal()
        .iter()
        .map(|v| v.ln())
        .sum::<f64>();
    let nll = 0.5 * z.dot(&alpha) + logdet + 0.5 * n as f64 * (2.0 * std::f64::consts::PI).ln();
    // K^-1 = L^-T L^-1: one triangular solve and one matrix product.
    let linv = chol
        .l_dirty()
        .solve_lower_triangular(&DMatrix::identity(n, n))
        .unwrap_or_else(|| DMatrix::identity(n, n));
    let kinv = linv.tr_mul(&linv);
    // W = alpha alpha^T - K^-1; d lml / d theta = 0.5 tr(W dK)
    let mut grad = vec![0.0; dim + 2];
    let mut tr_w_kf = 0.0;
    let mut tr_w = 0.0;
    for a in 0..n {
        for b in 0..n {
            let w = alpha[a] * alpha[b] - kinv[(a, b)];
            let kf = k[(a, b)] - if a == b { sn2 + JITTER } else { 0.0 };
            tr_w_kf += w * kf;
            if a == b {
                tr_w += w;
            }
            let c = w * common[a * n + b];
            if c != 0.0 && a != b {
                for (g, (dk, il)) in grad.iter_mut().zip(pairs.d.iter().zip(&inv_ls2)) {
                    *g += c * dk[a * n + b] * il;
                }
            }
        }
    }
    for g in grad.iter_mut().take(dim) {
        *g *= -0.5;
    }
    grad[dim] = -0.5 * tr_w_kf;
    grad[dim + 1] = -0.5 * sn2 * tr_w;
    let (lp, glp) = log_prior(h, dim);
    for (g, gp) in grad.iter_mut().zip(glp) {
        *g -= gp;
    }
    let f = nll - lp;
    f.is_finite().then_some((f, grad))
}

fn bounds(dim: usize, max_ls: Option<f64>, min_sf2: Option<f64>) -> (Vec<f64>, Vec<f64>) {
    let sf2_lo = min_sf2.map_or(LOG_SF2_BOUNDS.0, |m| {
        m.ln().clamp(LOG_SF2_BOUNDS.0, LOG_SF2_BOUNDS.1 - 0.1)
    });
    let ls_hi = max_ls.map_or(LOG_LS_BOUNDS.1, |m| {
        m.ln().clamp(LOG_LS_BOUNDS.0 + 0.1, LOG_LS_BOUNDS.1)
    });
    let mut lo = vec![LOG_LS_BOUNDS.0; dim];
    let mut hi = vec![ls_hi; dim];
    lo.extend([sf2_lo, LOG_SN2_BOUNDS.0]);
    hi.extend([LOG_SF2_BOUNDS.1, LOG_SN2_BOUNDS.1]);
    (lo, hi)
}

/// A function value with its gradient, `None` where it cannot be evaluated.
type ValueGrad<'a> = &'a dyn Fn(&[f64]) -> Option<(f64, Vec<f64>)>;

/// Projected L-BFGS with Armijo backtracking; minimises `f` inside the box.
fn lbfgs(
    f: ValueGrad<'_>,
    x0: Vec<f64>,
    lo: &[f64],
    hi: &[f64],
    max_iter: usize,
) -> Option<(Vec<f64>, f64)> {
    const M: usize = 6;
    let clamp = |x: &mut [f64]| {
        for ((v, l), h) in x.iter_mut().zip(lo).zip(hi) {
            *v = v.clamp(*l, *h);
        }
    };
    let mut x = x0;
    clamp(&mut x);
    let (mut fx, mut g) = f(&x)?;
    let mut mem: Vec<(Vec<f64>, Vec<f64>, f64)> = Vec::new();
    let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
    for it in 0..max_iter {
        if g.iter().all(|v| v.abs() < 1e-4) {
            break; // stationary (e.g. a warm start at the previous optimum)
        }
        // Two-loop recursion for d = -H g.
        let mut q = g.clone();
        let mut alphas = Vec::with_capacity(mem.len());
        for (s, y, rho) in mem.iter().rev() {
            let a = rho * dot(s, &q);
            for (qi, yi) in q.iter_mut().zip(y) {
                *qi -= a * yi;
            }
            alphas.push(a);
        }
        let gamma = mem.last().map_or_else(
            || 1.0 / dot(&g, &g).sqrt().max(1.0),
            |(s, y, _)| dot(s, y) / dot(y, y),
        );
        for qi in q.iter_mut() {
            *qi *= gamma;
        }
        for ((s, y, rho), a) in mem.iter().zip(alphas.into_iter().rev()) {
            let b = rho * dot(y, &q);
            for (qi, si) in q.iter_mut().zip(s) {
                *qi += (a - b) * si;
            }
        }
        let mut d: Vec<f64> = q.iter().map(|v| -v).collect();
        if dot(&d, &g) >= 0.0 {
            mem.clear();
            d = g.iter().map(|v| -v).collect();
        }
        if mem.is_empty() {
            // Without curvature information, take at most a 0.3 step in log space.
            let norm = dot(&d, &d).sqrt();
            if norm > 0.3 {
                d.iter_mut().for_each(|v| *v *= 0.3 / norm);
            }
        }
        let mut t = 1.0;
        let mut accepted = None;
        for _ in 0..12 {
            let mut xn: Vec<f64> = x.iter().zip(&d).map(|(a, b)| a + t * b).collect();
            clamp(&mut xn);
            let step: Vec<f64> = xn.iter().zip(&x).map(|(a, b)| a - b).collect();
            if let Some((fn_, gn)) = f(&xn)
                && fn_ <= fx + 1e-4 * dot(&g, &step)
            {
                accepted = Some((xn, fn_, gn, step));
                break;
            }
            t *= 0.5;
        }
        let Some((xn, fn_, gn, s)) = accepted else {
            break;
        };
        let y: Vec<f64> = gn.iter().zip(&g).map(|(a, b)| a - b).collect();
        let sy = dot(&s, &y);
        if sy > 1e-12 {
            if mem.len() == M {
                mem.remove(0);
            }
            mem.push((s, y, 1.0 / sy));
        }
        let improvement = fx - fn_;
        x = xn;
        fx = fn_;
        g = gn;
        if it > 0 && improvement.abs() < 1e-6 * (1.0 + fx.abs()) {
            break;
        }
    }
    Some((x, fx))
}

impl Gp {
    /// Fits hyperparameters (warm start, prior centre, random starts) and conditions on the data.
    pub fn fit(
        x: &[Vec<f64>],
        y: &[f64],
        opts: &FitOptions,
        warm: Option<&Hyper>,
        rng: &mut Rng,
    ) -> Result<Self> {
        let dim = x.first().map_or(0, Vec::len);
        let (_, _, z) = standardise(y, opts.min_scale);
        let z = DVector::from_vec(z);
        let pairs = Pairs::new(x);
        let (lo, hi) = bounds(dim, opts.max_lengthscale, opts.min_signal_var);
        let mut starts = Vec::new();
        if let Some(w) = warm.filter(|w| w.log_ls.len() == dim) {
            starts.push(w.to_vec());
        }
        starts.push(Hyper::default_for(dim).to_vec());
        for _ in 0..opts.random_starts {
            let mut h = Hyper::default_for(dim).to_vec();
            for v in h.iter_mut().take(dim) {
                *v += PRIOR_LS_SD * rng.normal();
            }
            h[dim] += 0.5 * rng.normal();
            h[dim + 1] += 1.5 * rng.normal();
            starts.push(h);
        }
        let f = |h: &[f64]| neg_log_posterior(h, &pairs, &z);
        let mut best: Option<(Vec<f64>, f64)> = None;
        if x.len() >= 2 {
            // Screen every starting point with one evaluation, optimise from the best few.
            let mut screened: Vec<(f64, Vec<f64>)> = starts
                .into_iter()
                .filter_map(|mut s| {
                    for ((v, l), h) in s.iter_mut().zip(&lo).zip(&hi) {
                        *v = v.clamp(*l, *h);
                    }
                    f(&s).map(|(v, _)| (v, s))
                })
                .collect();
            screened.sort_by(|a, b| a.0.total_cmp(&b.0));
            for (_, s) in screened.into_iter().take(opts.local_runs.max(1)) {
                if let Some((h, fh)) = lbfgs(&f, s, &lo, &hi, opts.max_iter)
                    && best.as_ref().is_none_or(|(_, fb)| fh < *fb)
                {
                    best = Some((h, fh));
                }
            }
        }
        let hyper = match best {
            Some((h, _)) => Hyper::from_slice(&h),
            None => {
                let mut h = warm
                    .cloned()
                    .unwrap_or_else(|| Hyper::default_for(dim))
                    .to_vec();
                for ((v, l), u) in h.iter_mut().zip(&lo).zip(&hi) {
                    *v = v.clamp(*l, *u);
                }
                Hyper::from_slice(&h)
            }
        };
        Self::condition(x, y, hyper, opts.min_scale)
    }

    /// Conditions on the data with fixed hyperparameters.
    pub fn condition(x: &[Vec<f64>], y: &[f64], hyper: Hyper, min_scale: f64) -> Result<Self> {
        let n = x.len();
        let (y_mean, y_scale, z) = standardise(y, min_scale);
        let inv_ls2: Vec<f64> = hyper.log_ls.iter().map(|l| (-2.0 * l).exp()).collect();
        let sf2 = hyper.log_sf2.exp();
        let sn2 = hyper.log_sn2.exp();
        let pairs = Pairs::new(x);
        let r2 = pairs.r2(&inv_ls2);
        let mut jitter = JITTER;
        for _ in 0..6 {
            let k = DMatrix::from_fn(n, n, |a, b| {
                sf2 * matern52(r2[a * n + b].sqrt()) + if a == b { sn2 + jitter } else { 0.0 }
            });
            if let Some(chol) = k.cholesky() {
                let alpha = chol.solve(&DVector::from_column_slice(&z));
                return Ok(Self {
                    x: x.to_vec(),
                    inv_ls2,
                    sf2,
                    y_mean,
                    y_scale,
                    chol: chol.unpack(),
                    alpha,
                    hyper,
                });
            }
            jitter *= 100.0;
        }
        Err(Error::Singular { n })
    }

    pub fn hyper(&self) -> &Hyper {
        &self.hyper
    }

    /// Posterior mean and standard deviation of the latent function, in output units.
    pub fn predict(&self, u: &[f64]) -> (f64, f64) {
        self.predict_many(std::slice::from_ref(&u.to_vec()))[0]
    }

    /// [`Gp::predict`] for many points at once.
    pub fn predict_many(&self, us: &[Vec<f64>]) -> Vec<(f64, f64)> {
        let n = self.x.len();
        let m = us.len();
        if n == 0 {
            return vec![(self.y_mean, self.y_scale * self.sf2.sqrt()); m];
        }
        let mut ks = DMatrix::<f64>::zeros(n, m);
        for (j, u) in us.iter().enumerate() {
            for (i, xi) in self.x.iter().enumerate() {
                let r2: f64 = xi
                    .iter()
                    .zip(u)
                    .zip(&self.inv_ls2)
                    .map(|((a, b), w)| (a - b) * (a - b) * w)
                    .sum();
                ks[(i, j)] = self.sf2 * matern52(r2.sqrt());
            }
        }
        let means = ks.tr_mul(&self.alpha);
        let v = self.chol.solve_lower_triangular(&ks).unwrap_or(ks);
        (0..m)
            .map(|j| {
                let vv: f64 = v.column(j).iter().map(|a| a * a).sum();
                let var = (self.sf2 - vv).max(1e-12 * self.sf2);
                (
                    self.y_mean + self.y_scale * means[j],
                    self.y_scale * var.sqrt(),
                )
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn truth(u: &[f64]) -> f64 {
        (6.0 * u[0]).sin() + 0.5 * (4.0 * u[1]).cos() + 10.0
    }

    #[test]
    fn fits_a_known_function_and_variance_shrinks_at_data() {
        let mut rng = Rng::seed_from_u64(11);
        let x: Vec<Vec<f64>> = (0..40)
            .map(|_| vec![rng.uniform(), rng.uniform()])
            .collect();
        let y: Vec<f64> = x.iter().map(|u| truth(u)).collect();
        let gp = Gp::fit(&x, &y, &FitOptions::default(), None, &mut rng).unwrap();
        let mut max_err: f64 = 0.0;
        let mut far_sd = 0.0;
        for _ in 0..200 {
            let u = vec![0.1 + 0.8 * rng.uniform(), 0.1 + 0.8 * rng.uniform()];
            let (m, s) = gp.predict(&u);
            max_err = max_err.max((m - truth(&u)).abs());
            far_sd += s / 200.0;
        }
        assert!(
            max_err < 0.15,
            "max error {max_err} on a function of range 3"
        );
        for (u, yv) in x.iter().zip(&y).take(10) {
            let (m, s) = gp.predict(u);
            assert!((m - yv).abs() < 0.02, "mean at data {m} vs {yv}");
            assert!(s < 0.5 * far_sd, "sd at data {s} vs average {far_sd}");
        }
        // Far outside the data the prior variance comes back.
        let (_, s_out) = gp.predict(&[3.0, 3.0]);
        assert!(s_out > 5.0 * far_sd);
    }

    #[test]
    fn noise_is_learned_from_noisy_data() {
        let mut rng = Rng::seed_from_u64(2);
        let x: Vec<Vec<f64>> = (0..60).map(|_| vec![rng.uniform()]).collect();
        let y: Vec<f64> = x
            .iter()
            .map(|u| (5.0 * u[0]).sin() + 0.2 * rng.normal())
            .collect();
        let gp = Gp::fit(&x, &y, &FitOptions::default(), None, &mut rng).unwrap();
        // Standardised y has variance ~ 0.5 + 0.04; noise share should be near 0.04/0.54.
        let noise_var_units = gp.hyper().log_sn2.exp() * gp.y_scale * gp.y_scale;
        assert!(
            (0.01..0.09).contains(&noise_var_units),
            "noise variance {noise_var_units}, true 0.04"
        );
        let (m, _) = gp.predict(&[0.3]);
        assert!((m - (1.5f64).sin()).abs() < 0.2);
    }

    #[test]
    fn gradient_matches_finite_differences() {
        let mut rng = Rng::seed_from_u64(4);
        let x: Vec<Vec<f64>> = (0..12)
            .map(|_| vec![rng.uniform(), rng.uniform(), rng.uniform()])
            .collect();
        let y: Vec<f64> = x
            .iter()
            .map(|u| u[0] * 3.0 + (u[1] * 4.0).sin() + rng.normal() * 0.1)
            .collect();
        let (_, _, z) = standardise(&y, 0.0);
        let z = DVector::from_vec(z);
        let pairs = Pairs::new(&x);
        let h = vec![-0.5, 0.2, -1.0, 0.3, -3.0];
        let (_, g) = neg_log_posterior(&h, &pairs, &z).unwrap();
        for i in 0..h.len() {
            let mut hp = h.clone();
            let mut hm = h.clone();
            hp[i] += 1e-5;
            hm[i] -= 1e-5;
            let fd = (neg_log_posterior(&hp, &pairs, &z).unwrap().0
                - neg_log_posterior(&hm, &pairs, &z).unwrap().0)
                / 2e-5;
            assert!(
                (fd - g[i]).abs() < 1e-4 * (1.0 + fd.abs()),
                "param {i}: analytic {} fd {fd}",
                g[i]
            );
        }
    }
}
