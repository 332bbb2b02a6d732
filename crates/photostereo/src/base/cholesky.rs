//! Dense Cholesky factorisation of small symmetric positive definite systems (row-major
//! `n × n`, `f64`): the coarsest multigrid level and the per-pixel normal equations of the
//! relighting fits.

/// What [`factor`] does with a pivot at or below `1e-12` of the largest diagonal entry (a
/// matrix that is singular to working precision).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SmallPivot {
    /// Stop and report the matrix as rank deficient.
    Refuse,
    /// Replace the pivot by that bound and go on (a tiny regularisation of an operator known to
    /// be definite, where round-off brought a pivot near zero).
    Raise,
}

/// Factors the symmetric `n × n` matrix `a` (row-major, lower triangle read) in place into its
/// lower Cholesky factor `L` (`a = L Lᵀ`). False when a pivot is too small (or NaN) and `small`
/// is [`SmallPivot::Refuse`]; `a` is then left partly factored.
pub fn factor(a: &mut [f64], n: usize, small: SmallPivot) -> bool {
    let scale = (0..n).map(|i| a[i * n + i]).fold(0.0f64, f64::max);
    let least = 1e-12 * scale;
    for j in 0..n {
        let mut d = a[j * n + j];
        for k in 0..j {
            d -= a[j * n + k] * a[j * n + k];
        }
        let d = if d > least {
            d.sqrt()
        } else {
            match small {
                SmallPivot::Refuse => return false,
                SmallPivot::Raise => least.max(1e-42).sqrt(),
            }
        };
        a[j * n + j] = d;
        for i in j + 1..n {
            let mut s = a[i * n + j];
            for k in 0..j {
                s -= a[i * n + k] * a[j * n + k];
            }
            a[i * n + j] = s / d;
        }
    }
    true
}

/// Solves `L Lᵀ x = b` in place (`b` becomes `x`) with the factor `l` made by [`factor`].
pub fn solve(l: &[f64], n: usize, b: &mut [f64]) {
    for i in 0..n {
        let mut s = b[i];
        for k in 0..i {
            s -= l[i * n + k] * b[k];
        }
        b[i] = s / l[i * n + i];
    }
    for i in (0..n).rev() {
        let mut s = b[i];
        for k in i + 1..n {
            s -= l[k * n + i] * b[k];
        }
        b[i] = s / l[i * n + i];
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A random SPD system (B Bᵀ + n I) solved, checked by multiplying back.
    #[test]
    fn solves_a_symmetric_positive_definite_system() {
        let n = 7;
        let mut rng = crate::base::rng::Pcg32::new(3, 0);
        let b: Vec<f64> = (0..n * n).map(|_| rng.next_f64() - 0.5).collect();
        let mut a = vec![0.0; n * n];
        for i in 0..n {
            for j in 0..n {
                a[i * n + j] = (0..n).map(|k| b[i * n + k] * b[j * n + k]).sum::<f64>();
            }
            a[i * n + i] += n as f64;
        }
        let rhs: Vec<f64> = (0..n).map(|i| i as f64 - 2.0).collect();
        let mut l = a.clone();
        assert!(factor(&mut l, n, SmallPivot::Refuse));
        let mut x = rhs.clone();
        solve(&l, n, &mut x);
        for i in 0..n {
            let ax: f64 = (0..n).map(|j| a[i * n + j] * x[j]).sum();
            assert!((ax - rhs[i]).abs() < 1e-12, "row {i}: {ax} vs {}", rhs[i]);
        }
    }

    /// A rank-deficient matrix is refused, or factored with a raised pivot.
    #[test]
    fn a_singular_matrix_is_refused_or_raised() {
        let a0 = [1.0, 1.0, 1.0, 1.0];
        let mut a = a0;
        assert!(!factor(&mut a, 2, SmallPivot::Refuse));
        let mut a = a0;
        assert!(factor(&mut a, 2, SmallPivot::Raise));
        assert!(a[3] > 0.0 && a[3].is_finite());
    }
}
