//! The few distribution functions the tracker's tests of a fit need, computed rather than tabulated: a test whose
//! degrees of freedom follow the frame rate (a window of 0.2 s is 7 frames at 30 Hz, 13 at 60) cannot use one
//! constant. Written from the textbook definitions: the F distribution's CDF is a regularised incomplete beta
//! function, evaluated by its continued fraction (modified Lentz), with ln Γ from Lanczos' approximation.

/// ln Γ(x) for x > 0, by Lanczos' approximation (g = 7, nine terms; relative error below 1e-14 on the range the
/// incomplete beta needs).
fn ln_gamma(x: f64) -> f64 {
    const G: f64 = 7.0;
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
        // Reflection: Γ(x) Γ(1 − x) = π / sin(πx).
        let pi = std::f64::consts::PI;
        return (pi / (pi * x).sin()).ln() - ln_gamma(1.0 - x);
    }
    let x = x - 1.0;
    let mut sum = COEFFICIENTS[0];
    for (i, c) in COEFFICIENTS.iter().enumerate().skip(1) {
        sum += c / (x + i as f64);
    }
    let t = x + G + 0.5;
    0.5 * (2.0 * std::f64::consts::PI).ln() + (x + 0.5) * t.ln() - t + sum.ln()
}

/// The continued fraction of the incomplete beta function, I_x(a, b) = front · 1 / (1 + d₁ / (1 + d₂ / …)),
/// by the modified Lentz method. Converges fast for x < (a + 1) / (a + b + 2).
fn beta_continued_fraction(a: f64, b: f64, x: f64) -> f64 {
    const TINY: f64 = 1e-300;
    const MAX_TERMS: usize = 300;
    let mut c = 1.0;
    let mut d = 1.0 - (a + b) * x / (a + 1.0);
    if d.abs() < TINY {
        d = TINY;
    }
    d = 1.0 / d;
    let mut value = d;
    for m in 1..MAX_TERMS {
        let m = m as f64;
        // The even term, then the odd one.
        for coefficient in [
            m * (b - m) * x / ((a + 2.0 * m - 1.0) * (a + 2.0 * m)),
            -(a + m) * (a + b + m) * x / ((a + 2.0 * m) * (a + 2.0 * m + 1.0)),
        ] {
            d = 1.0 + coefficient * d;
            if d.abs() < TINY {
                d = TINY;
            }
            c = 1.0 + coefficient / c;
            if c.abs() < TINY {
                c = TINY;
            }
            d = 1.0 / d;
            value *= d * c;
        }
        if (d * c - 1.0).abs() < 1e-15 {
            break;
        }
    }
    value
}

/// The regularised incomplete beta function I_x(a, b), for a, b > 0 and x in [0, 1].
fn incomplete_beta(a: f64, b: f64, x: f64) -> f64 {
    if x <= 0.0 {
        return 0.0;
    }
    if x >= 1.0 {
        return 1.0;
    }
    let ln_front = ln_gamma(a + b) - ln_gamma(a) - ln_gamma(b) + a * x.ln() + b * (1.0 - x).ln();
    if x < (a + 1.0) / (a + b + 2.0) {
        ln_front.exp() * beta_continued_fraction(a, b, x) / a
    } else {
        // I_x(a, b) = 1 − I_{1−x}(b, a), where the fraction converges.
        1.0 - ln_front.exp() * beta_continued_fraction(b, a, 1.0 - x) / b
    }
}

/// The `p` quantile of the F distribution with `d1` and `d2` degrees of freedom (`p` in (0, 1)): the f with
/// P(F ≤ f) = p, to a relative 1e-12, by bisection on the incomplete beta's argument (monotone, so it cannot
/// miss).
pub(crate) fn f_quantile(p: f64, d1: f64, d2: f64) -> f64 {
    let (a, b) = (0.5 * d1, 0.5 * d2);
    let (mut lo, mut hi) = (0.0f64, 1.0f64);
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if incomplete_beta(a, b, mid) < p {
            lo = mid;
        } else {
            hi = mid;
        }
        if hi - lo <= 1e-13 * hi {
            break;
        }
    }
    let x = 0.5 * (lo + hi);
    d2 * x / (d1 * (1.0 - x))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// P(F ≤ f) for F with `d1` and `d2` degrees of freedom.
    fn f_cdf(f: f64, d1: f64, d2: f64) -> f64 {
        if f <= 0.0 {
            return 0.0;
        }
        incomplete_beta(0.5 * d1, 0.5 * d2, d1 * f / (d1 * f + d2))
    }

    /// Values from printed F tables (upper 5 % and 1 % points), to their four or five figures.
    #[test]
    fn f_quantiles_match_the_tables() {
        for (p, d1, d2, table) in [
            (0.95, 3.0, 12.0, 3.4903),
            (0.95, 3.0, 30.0, 2.9223),
            (0.95, 1.0, 1.0, 161.45),
            (0.95, 3.0, 3.0, 9.2766),
            (0.95, 5.0, 10.0, 3.3258),
            (0.99, 3.0, 12.0, 5.9525),
            (0.95, 3.0, 120.0, 2.6802),
        ] {
            let f = f_quantile(p, d1, d2);
            assert!((f - table).abs() < 5e-4 * table, "F({d1}, {d2}) at {p}: {f}, the table says {table}");
            assert!((f_cdf(f, d1, d2) - p).abs() < 1e-10);
        }
    }

    /// χ²₃'s 95 % point is 3 · F(3, ∞): the tracker's stereo threshold comes out of a very long window.
    #[test]
    fn a_long_window_gives_the_chi_square_point() {
        let f = f_quantile(0.95, 3.0, 1e7);
        assert!((3.0 * f - crate::optim::CHI2_STEREO).abs() < 1e-3, "{}", 3.0 * f);
    }

    #[test]
    fn ln_gamma_meets_factorials() {
        for (n, factorial) in [(1.0, 1.0), (2.0, 1.0), (5.0, 24.0), (11.0, 3_628_800.0f64)] {
            assert!((ln_gamma(n) - factorial.ln()).abs() < 1e-12, "Γ({n})");
        }
        assert!((ln_gamma(0.5) - std::f64::consts::PI.sqrt().ln()).abs() < 1e-12);
    }
}
