//! Distribution functions the detectors need: χ² and normal quantiles (from the regularised
//! incomplete gamma function).

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
    // Bracket, then bisect on the monotone CDF (60 halvings: full f64 precision).
    let mut lo = 0.0;
    let mut hi = k + 10.0 * (2.0 * k).sqrt() + 50.0;
    while chi2_cdf(hi, dof) < p {
        hi *= 2.0;
    }
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if chi2_cdf(mid, dof) < p {
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
}
