//! The chi-square distribution, for gating (data association) and consistency checks
//! (NEES, NIS).

use crate::error::{Error, Result};

/// `ln Gamma(x)` for `x > 0` (Lanczos approximation, g = 7, n = 9; relative error below 1e-13).
fn ln_gamma(x: f64) -> f64 {
    const COEFFICIENTS: [f64; 9] = [
        0.999_999_999_999_809_9,
        676.520_368_121_885_1,
        -1_259.139_216_722_402_8,
        771.323_428_777_653_1,
        -176.615_029_162_140_6,
        12.507_343_278_686_905,
        -0.138_571_095_265_720_12,
        9.984_369_578_019_572e-6,
        1.505_632_735_149_311_6e-7,
    ];
    if x < 0.5 {
        // Reflection: Gamma(x) Gamma(1 - x) = pi / sin(pi x).
        let pi = std::f64::consts::PI;
        return (pi / (pi * x).sin()).ln() - ln_gamma(1.0 - x);
    }
    let x = x - 1.0;
    let t = x + 7.5;
    let series = COEFFICIENTS[1..]
        .iter()
        .enumerate()
        .fold(COEFFICIENTS[0], |sum, (i, c)| {
            sum + c / (x + i as f64 + 1.0)
        });
    0.5 * (2.0 * std::f64::consts::PI).ln() + (x + 0.5) * t.ln() - t + series.ln()
}

/// The regularized lower incomplete gamma function `P(a, x)` (series below `a + 1`, Lentz's
/// continued fraction above).
fn gamma_p(a: f64, x: f64) -> f64 {
    if x <= 0.0 {
        return 0.0;
    }
    let log_prefix = a * x.ln() - x - ln_gamma(a);
    if x < a + 1.0 {
        let (mut term, mut sum, mut n) = (1.0 / a, 1.0 / a, a);
        for _ in 0..1000 {
            n += 1.0;
            term *= x / n;
            sum += term;
            if term.abs() < sum.abs() * 1e-16 {
                break;
            }
        }
        (sum.ln() + log_prefix).exp().min(1.0)
    } else {
        let tiny = 1e-300;
        let mut b = x + 1.0 - a;
        let mut c = 1.0 / tiny;
        let mut d = 1.0 / b;
        let mut h = d;
        for i in 1..1000 {
            let an = -(i as f64) * (i as f64 - a);
            b += 2.0;
            d = an * d + b;
            if d.abs() < tiny {
                d = tiny;
            }
            c = b + an / c;
            if c.abs() < tiny {
                c = tiny;
            }
            d = 1.0 / d;
            let delta = d * c;
            h *= delta;
            if (delta - 1.0).abs() < 1e-16 {
                break;
            }
        }
        (1.0 - (h.ln() + log_prefix).exp()).max(0.0)
    }
}

/// The chi-square cumulative distribution function with `dof` degrees of freedom.
///
/// ```
/// let p = slam_core::chi2_cdf(5.991464547107979, 2).unwrap();
/// assert!((p - 0.95).abs() < 1e-10);
/// ```
pub fn chi2_cdf(x: f64, dof: usize) -> Result<f64> {
    if dof == 0 || x.is_nan() {
        return Err(Error::InvalidArgument(format!(
            "chi-square cdf needs dof >= 1 and a number, got dof {dof}, x {x}"
        )));
    }
    Ok(gamma_p(0.5 * dof as f64, 0.5 * x.max(0.0)))
}

/// The `probability` quantile of the chi-square distribution with `dof` degrees of freedom:
/// the gate of a Mahalanobis test and the bounds of a NEES / NIS band.
///
/// ```
/// let gate = slam_core::chi2_quantile(0.99, 2).unwrap();
/// assert!((gate - 9.210340371976184).abs() < 1e-8);
/// ```
pub fn chi2_quantile(probability: f64, dof: usize) -> Result<f64> {
    if !(probability > 0.0 && probability < 1.0) || dof == 0 {
        return Err(Error::InvalidArgument(format!(
            "chi-square quantile needs 0 < p < 1 and dof >= 1, got p {probability}, dof {dof}"
        )));
    }
    let (mut lo, mut hi) = (0.0, dof as f64 + 10.0 * (2.0 * dof as f64).sqrt() + 50.0);
    while gamma_p(0.5 * dof as f64, 0.5 * hi) < probability {
        hi *= 2.0;
    }
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if gamma_p(0.5 * dof as f64, 0.5 * mid) < probability {
            lo = mid;
        } else {
            hi = mid;
        }
        if hi - lo < 1e-12 * hi.max(1.0) {
            break;
        }
    }
    Ok(0.5 * (lo + hi))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantiles_match_tables() {
        // Reference values from scipy.stats.chi2.ppf(p, k) (scipy 1.x).
        let table = [
            (0.95, 1, 3.841458820694124),
            (0.99, 1, 6.634896601021214),
            (0.95, 3, 7.814727903251178),
            (0.025, 3, 0.2157952826238981),
            (0.975, 3, 9.348403604496145),
            (0.025, 150, 117.9845154029029),
            (0.975, 150, 185.80044700379327),
            (0.9999, 2, 18.420680743952584),
            (0.5, 40, 39.33534484661134),
        ];
        for (p, k, expected) in table {
            let q = chi2_quantile(p, k).unwrap();
            assert!(
                (q - expected).abs() < 1e-7 * expected.max(1.0),
                "chi2_quantile({p}, {k}) = {q}, expected {expected}"
            );
            assert!((chi2_cdf(q, k).unwrap() - p).abs() < 1e-10);
        }
    }

    #[test]
    fn bad_arguments_are_errors() {
        assert!(chi2_quantile(1.0, 2).is_err());
        assert!(chi2_quantile(0.5, 0).is_err());
        assert!(chi2_cdf(f64::NAN, 2).is_err());
        assert_eq!(chi2_cdf(-1.0, 2).unwrap(), 0.0);
    }
}
