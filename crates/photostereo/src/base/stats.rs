//! Distribution functions the detectors need: χ² and normal quantiles (from the regularised
//! incomplete gamma function) and the F distribution's (from the regularised incomplete beta
//! function), for tests that compare two nested fits.

/// ln Γ(x) for x > 0 (Lanczos approximation, |error| < 1e-13 in this range).
pub fn ln_gamma(x: f64) -> f64 {
    const G: f64 = 7.0;
    const C: [f64; 9] = [
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
        let pi = std::f64::consts::PI;
        return (pi / (pi * x).sin()).ln() - ln_gamma(1.0 - x);
    }
    let x = x - 1.0;
    let mut a = C[0];
    let t = x + G + 0.5;
    for (i, c) in C.iter().enumerate().skip(1) {
        a += c / (x + i as f64);
    }
    0.5 * (2.0 * std::f64::consts::PI).ln() + (x + 0.5) * t.ln() - t + a.ln()
}

/// Regularised lower incomplete gamma P(a, x).
pub fn gamma_p(a: f64, x: f64) -> f64 {
    if x <= 0.0 {
        return 0.0;
    }
    let gln = ln_gamma(a);
    if x < a + 1.0 {
        // Series.
        let mut sum = 1.0 / a;
        let mut del = sum;
        let mut ap = a;
        for _ in 0..1000 {
            ap += 1.0;
            del *= x / ap;
            sum += del;
            if del.abs() < sum.abs() * 1e-15 {
                break;
            }
        }
        (sum.ln() - x + a * x.ln() - gln).exp()
    } else {
        // Continued fraction (modified Lentz) for Q, then P = 1 − Q.
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
            let del = d * c;
            h *= del;
            if (del - 1.0).abs() < 1e-15 {
                break;
            }
        }
        1.0 - (-x + a * x.ln() - gln).exp() * h
    }
}

/// CDF of χ² with `dof` degrees of freedom.
pub fn chi2_cdf(x: f64, dof: usize) -> f64 {
    gamma_p(dof as f64 / 2.0, x / 2.0)
}

/// Quantile of χ² with `dof` degrees of freedom: the x with CDF(x) = p, for 0 < p < 1.
pub fn chi2_quantile(p: f64, dof: usize) -> f64 {
    assert!(p > 0.0 && p < 1.0 && dof > 0, "chi2_quantile domain");
    let k = dof as f64;
    quantile_of(|x| chi2_cdf(x, dof), p, k + 10.0 * (2.0 * k).sqrt() + 50.0)
}

/// The x ≥ 0 with `cdf(x)` = p of a monotone CDF on [0, ∞): bracketed from `hi` (doubled until
/// it holds p), then bisected to full f64 precision.
fn quantile_of(cdf: impl Fn(f64) -> f64, p: f64, mut hi: f64) -> f64 {
    let mut lo = 0.0;
    while cdf(hi) < p {
        hi *= 2.0;
    }
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if cdf(mid) < p {
            lo = mid;
        } else {
            hi = mid;
        }
        if hi - lo < 1e-12 * hi.max(1.0) {
            break;
        }
    }
    0.5 * (lo + hi)
}

/// Upper quantile of the standard normal: the z with P(Z > z) = q, for 0 < q < 0.5.
pub fn normal_upper_quantile(q: f64) -> f64 {
    chi2_quantile(1.0 - 2.0 * q, 1).sqrt()
}

/// Regularised incomplete beta function I_x(a, b) for a, b > 0 and 0 ≤ x ≤ 1: its continued
/// fraction (modified Lentz), evaluated where it converges fast (x below the mean
/// (a + 1)/(a + b + 2)) and through I_x(a, b) = 1 − I_{1−x}(b, a) elsewhere.
pub fn beta_i(a: f64, b: f64, x: f64) -> f64 {
    if x <= 0.0 {
        return 0.0;
    }
    if x >= 1.0 {
        return 1.0;
    }
    if x > (a + 1.0) / (a + b + 2.0) {
        return 1.0 - beta_i(b, a, 1.0 - x);
    }
    let ln_front = ln_gamma(a + b) - ln_gamma(a) - ln_gamma(b) + a * x.ln() + b * (1.0 - x).ln();
    let tiny = 1e-300;
    let clamp = |v: f64| if v.abs() < tiny { tiny } else { v };
    // Terms d_{2m+1} = −(a+m)(a+b+m)x / ((a+2m)(a+2m+1)), d_{2m} = m(b−m)x / ((a+2m−1)(a+2m)).
    let mut c = 1.0;
    let mut d = 1.0 / clamp(1.0 - (a + b) * x / (a + 1.0));
    let mut h = d;
    for m in 1..1000 {
        let m = m as f64;
        let even = m * (b - m) * x / ((a + 2.0 * m - 1.0) * (a + 2.0 * m));
        d = 1.0 / clamp(1.0 + even * d);
        c = clamp(1.0 + even / c);
        h *= d * c;
        let odd = -(a + m) * (a + b + m) * x / ((a + 2.0 * m) * (a + 2.0 * m + 1.0));
        d = 1.0 / clamp(1.0 + odd * d);
        c = clamp(1.0 + odd / c);
        let del = d * c;
        h *= del;
        if (del - 1.0).abs() < 1e-15 {
            break;
        }
    }
    ln_front.exp() * h / a
}

/// CDF of the F distribution with (`d1`, `d2`) degrees of freedom.
pub fn f_cdf(f: f64, d1: usize, d2: usize) -> f64 {
    if f <= 0.0 {
        return 0.0;
    }
    let (a, b) = (d1 as f64, d2 as f64);
    beta_i(a / 2.0, b / 2.0, a * f / (a * f + b))
}

/// Quantile of the F distribution with (`d1`, `d2`) degrees of freedom: the f with
/// CDF(f) = p, for 0 < p < 1.
pub fn f_quantile(p: f64, d1: usize, d2: usize) -> f64 {
    assert!(p > 0.0 && p < 1.0 && d1 > 0 && d2 > 0, "f_quantile domain");
    quantile_of(|f| f_cdf(f, d1, d2), p, 10.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn chi2_quantiles_match_tables() {
        // Standard table values.
        for (p, d, x) in [
            (0.95, 1, 3.841_458_8),
            (0.95, 2, 5.991_464_5),
            (0.95, 5, 11.070_497_7),
            (0.99, 10, 23.209_251_2),
            (0.25, 1, 0.101_531_0),
            (0.95, 93, 116.511_0),
        ] {
            let q = chi2_quantile(p, d);
            assert!((q - x).abs() < 1e-4 * x.max(1.0), "p={p} d={d}: {q} vs {x}");
        }
        assert!((normal_upper_quantile(0.025) - 1.959_964).abs() < 1e-5);
    }

    #[test]
    fn f_quantiles_match_tables_and_limits() {
        // Standard table values.
        for (p, d1, d2, f) in [
            (0.95, 1, 10, 4.964_603),
            (0.99, 1, 10, 10.044_289),
            (0.95, 2, 20, 3.492_828),
            (0.99, 2, 5, 13.273_934),
            (0.95, 5, 30, 2.533_555),
        ] {
            let q = f_quantile(p, d1, d2);
            assert!((q - f).abs() < 1e-4 * f, "p={p} d=({d1},{d2}): {q} vs {f}");
        }
        // d1·F(d1, d2) tends to χ²(d1) as d2 grows; F(1, d2) is Student's t² (t_{0.975}(4) = 2.776445).
        let chi = chi2_quantile(0.99, 2);
        assert!((2.0 * f_quantile(0.99, 2, 100_000) - chi).abs() < 1e-3 * chi);
        assert!((f_quantile(0.95, 1, 4) - 2.776_445f64.powi(2)).abs() < 1e-4);
        // I_x(a, b) against closed forms: I_x(1, b) = 1 − (1 − x)^b, I_x(a, 1) = x^a.
        assert!((beta_i(1.0, 3.5, 0.3) - (1.0 - 0.7f64.powf(3.5))).abs() < 1e-12);
        assert!((beta_i(2.5, 1.0, 0.8) - 0.8f64.powf(2.5)).abs() < 1e-12);
    }
}
