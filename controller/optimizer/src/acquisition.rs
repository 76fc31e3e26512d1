//! Acquisition math: the standard normal distribution, expected improvement,
//! probability of feasibility and their product, constrained EI (Gardner et
//! al. 2014). All for maximisation. The normal CDF is `libm`'s `erfc` (Rust's
//! port of the FreeBSD/musl implementation).

use std::f64::consts::{FRAC_1_SQRT_2, PI};

use crate::problem::Sense;

/// Standard normal density.
pub fn norm_pdf(z: f64) -> f64 {
    (-0.5 * z * z).exp() / (2.0 * PI).sqrt()
}

/// Standard normal cumulative distribution.
pub fn norm_cdf(z: f64) -> f64 {
    0.5 * libm::erfc(-z * FRAC_1_SQRT_2)
}

/// Expected improvement over `best` of a normal `N(mean, sd^2)`, maximising.
pub fn expected_improvement(mean: f64, sd: f64, best: f64) -> f64 {
    if sd <= 1e-12 {
        return (mean - best).max(0.0);
    }
    let z = (mean - best) / sd;
    (sd * (z * norm_cdf(z) + norm_pdf(z))).max(0.0)
}

/// Probability that a constraint with predictive `N(mean, sd^2)` holds.
pub fn probability_of_feasibility(mean: f64, sd: f64, threshold: f64, sense: Sense) -> f64 {
    let margin = match sense {
        Sense::AtLeast => mean - threshold,
        Sense::AtMost => threshold - mean,
    };
    if sd <= 1e-12 {
        return if margin >= 0.0 { 1.0 } else { 0.0 };
    }
    norm_cdf(margin / sd)
}

/// Constrained EI: `EI × Π_j PoF_j`; with no feasible incumbent (`best = None`)
/// it is `Π_j PoF_j` alone, i.e. pure feasibility search.
pub fn constrained_ei(ei: Option<f64>, pofs: &[f64]) -> f64 {
    let p: f64 = pofs.iter().product();
    match ei {
        Some(ei) => ei * p,
        None => p,
    }
}

/// `ln Φ(z)`, finite far into the lower tail.
pub fn log_norm_cdf(z: f64) -> f64 {
    if z > -30.0 {
        norm_cdf(z).max(f64::MIN_POSITIVE).ln()
    } else {
        // Mills-ratio asymptotics: Φ(z) ≈ φ(z) / |z|.
        -0.5 * z * z - (-z).ln() - 0.5 * (2.0 * PI).ln()
    }
}

/// `ln EI` for a normal `N(mean, sd^2)` over `best`, finite where EI underflows.
pub fn log_expected_improvement(mean: f64, sd: f64, best: f64) -> f64 {
    if sd <= 1e-12 {
        return (mean - best).max(0.0).ln();
    }
    let z = (mean - best) / sd;
    let h = if z > -25.0 {
        (z * norm_cdf(z) + norm_pdf(z)).max(f64::MIN_POSITIVE).ln()
    } else {
        // z Φ(z) + φ(z) ≈ φ(z) / z^2 for z → -∞.
        -0.5 * z * z - 0.5 * (2.0 * PI).ln() - 2.0 * (-z).ln()
    };
    sd.ln() + h
}

/// Mean and standard deviation of `min(X, Y)` for independent normals
/// `X ~ N(mx, sx^2)`, `Y ~ N(my, sy^2)`: exact first two moments (Clark
/// 1961), used to moment-match the min by a normal. A constant is `sd = 0`.
pub fn normal_min_moments(x: (f64, f64), y: (f64, f64)) -> (f64, f64) {
    let ((mx, sx), (my, sy)) = (x, y);
    let theta = (sx * sx + sy * sy).sqrt();
    if theta <= 1e-12 {
        return (mx.min(my), 0.0);
    }
    // min(X, Y) = -max(-X, -Y); Clark's formulas for the max of (-X, -Y).
    let (a1, a2) = (-mx, -my);
    let alpha = (a1 - a2) / theta;
    let (p, q, d) = (norm_cdf(alpha), norm_cdf(-alpha), norm_pdf(alpha));
    let m1 = a1 * p + a2 * q + theta * d;
    let m2 = (a1 * a1 + sx * sx) * p + (a2 * a2 + sy * sy) * q + (a1 + a2) * theta * d;
    (-m1, (m2 - m1 * m1).max(0.0).sqrt())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn normal_distribution_matches_reference_values() {
        // Reference values (Abramowitz & Stegun tables / high-precision evaluation).
        let table = [
            (0.0, 0.5),
            (1.0, 0.841_344_746_068_542_9),
            (-1.0, 0.158_655_253_931_457_05),
            (1.959_963_984_540_054, 0.975),
            (-3.0, 0.001_349_898_031_630_094_6),
            (-5.0, 2.866_515_718_791_939e-7),
            (-10.0, 7.619_853_024_160_527e-24),
            (2.5, 0.993_790_334_674_223_8),
        ];
        for (z, want) in table {
            let got = norm_cdf(z);
            assert!(
                ((got - want) / want).abs() < 1e-12,
                "Phi({z}) = {got}, want {want}"
            );
        }
        assert!((norm_pdf(0.0) - 0.398_942_280_401_432_7).abs() < 1e-15);
        assert!((norm_pdf(1.0) - 0.241_970_724_519_143_37).abs() < 1e-15);
        assert!((libm::erfc(0.5) - 0.479_500_122_186_953_5).abs() < 1e-14);
    }

    #[test]
    fn expected_improvement_by_hand() {
        // mean = best: EI = sd * phi(0) = 2 * 0.39894 = 0.79788
        assert!(
            (expected_improvement(1.0, 2.0, 1.0) - 2.0 * 0.398_942_280_401_432_7).abs() < 1e-12
        );
        // z = 1: EI = sd (Phi(1) + phi(1)) = 0.5 * (0.841345 + 0.241971) = 0.541658
        let want = 0.5 * (0.841_344_746_068_542_9 + 0.241_970_724_519_143_37);
        assert!((expected_improvement(1.5, 0.5, 1.0) - want).abs() < 1e-12);
        // z = -1: EI = sd (-Phi(-1) + phi(1)) = 0.241971 - 0.158655 = 0.083315
        let want = 0.241_970_724_519_143_37 - 0.158_655_253_931_457_05;
        assert!((expected_improvement(0.0, 1.0, 1.0) - want).abs() < 1e-12);
        // No uncertainty: plain improvement.
        assert_eq!(expected_improvement(3.0, 0.0, 1.0), 2.0);
        assert_eq!(expected_improvement(0.0, 0.0, 1.0), 0.0);
    }

    #[test]
    fn feasibility_and_constrained_ei_by_hand() {
        // cmd_vel ~ N(40, 5^2), needs >= 35: P = Phi(1)
        let p = probability_of_feasibility(40.0, 5.0, 35.0, Sense::AtLeast);
        assert!((p - 0.841_344_746_068_542_9).abs() < 1e-12);
        // latency ~ N(110, 10^2), needs <= 100: P = Phi(-1)
        let q = probability_of_feasibility(110.0, 10.0, 100.0, Sense::AtMost);
        assert!((q - 0.158_655_253_931_457_05).abs() < 1e-12);
        let ei = 0.5;
        assert!((constrained_ei(Some(ei), &[p, q]) - ei * p * q).abs() < 1e-15);
        assert!((constrained_ei(None, &[p, q]) - p * q).abs() < 1e-15);
        assert_eq!(constrained_ei(Some(ei), &[]), ei);
    }

    #[test]
    fn min_of_normals_matches_monte_carlo_and_limits() {
        // Equal N(0, 1): E[min] = -1/sqrt(pi), Var = 1 - 1/pi.
        let (m, s) = normal_min_moments((0.0, 1.0), (0.0, 1.0));
        assert!((m + 1.0 / PI.sqrt()).abs() < 1e-12, "{m}");
        assert!((s - (1.0 - 1.0 / PI).sqrt()).abs() < 1e-12, "{s}");
        // Far apart: the lower one.
        let (m, s) = normal_min_moments((0.0, 1.0), (50.0, 2.0));
        assert!(m.abs() < 1e-9 && (s - 1.0).abs() < 1e-9);
        // Against a constant cap: E[min(X, c)] = mu - sd * (phi(z) + z (1 - Phi(z))) with z = (c - mu)/sd... check by sampling.
        let mut rng = crate::rng::Rng::seed_from_u64(1);
        let (n, mut s1, mut s2) = (200_000, 0.0, 0.0);
        for _ in 0..n {
            let v = (0.8 + 0.3 * rng.normal()).min(1.0);
            s1 += v;
            s2 += v * v;
        }
        let mean = s1 / n as f64;
        let sd = (s2 / n as f64 - mean * mean).sqrt();
        let (m, s) = normal_min_moments((0.8, 0.3), (1.0, 0.0));
        assert!(
            (m - mean).abs() < 3e-3 && (s - sd).abs() < 3e-3,
            "{m} {s} vs {mean} {sd}"
        );
    }

    #[test]
    fn log_forms_agree_and_stay_finite_in_the_tail() {
        for z in [-3.0, -1.0, 0.0, 2.0] {
            assert!((log_norm_cdf(z) - norm_cdf(z).ln()).abs() < 1e-12);
            let (m, s) = (z * 2.0, 2.0);
            assert!(
                (log_expected_improvement(m, s, 0.0) - expected_improvement(m, s, 0.0).ln()).abs()
                    < 1e-9
            );
        }
        assert!(log_norm_cdf(-50.0).is_finite() && log_norm_cdf(-50.0) < log_norm_cdf(-40.0));
        let far = log_expected_improvement(-100.0, 1.0, 0.0);
        assert!(far.is_finite() && far < log_expected_improvement(-30.0, 1.0, 0.0));
    }
}
