//! Estimator tests on analytic Lambertian surfaces.

use crate::base::progress::Silent;
use crate::fixtures::{lambert_sphere, ring};
use crate::solve::metrics::angular_error_deg;

#[test]
fn least_squares_recovers_an_analytic_sphere() {
    let (capture, truth) = lambert_sphere(96, 40.0, &ring(8, 30.0));
    use crate::solve::estimate::Estimator;
    let est = crate::solve::estimate::LeastSquares
        .estimate(&capture, &Silent)
        .unwrap();
    let mut sum = 0.0;
    for (n, t) in est.normals.iter().zip(&truth) {
        sum += angular_error_deg(*n, [t[0] as f32, t[1] as f32, t[2] as f32]);
    }
    let mean = sum / truth.len() as f64;
    assert!(capture.n_pixels() > 3000);
    assert!(mean < 0.01, "mean error {mean}°");
    for (p, a) in est.albedo.chunks(3).enumerate() {
        assert!(
            (a[0] - 0.8).abs() < 1e-4 && (a[1] - 0.6).abs() < 1e-4 && (a[2] - 0.4).abs() < 1e-4,
            "pixel {p}: {a:?}"
        );
    }
}

#[test]
fn permuting_lights_gives_the_same_normals() {
    let dirs = ring(7, 40.0);
    let (capture, _) = lambert_sphere(64, 28.0, &dirs);
    let order = [3, 0, 6, 2, 5, 1, 4];
    let permuted = capture.select_lights(&order).unwrap();
    use crate::solve::estimate::Estimator;
    let a = crate::solve::estimate::LeastSquares
        .estimate(&capture, &Silent)
        .unwrap();
    let b = crate::solve::estimate::LeastSquares
        .estimate(&permuted, &Silent)
        .unwrap();
    for (x, y) in a.normals.iter().zip(&b.normals) {
        assert!(angular_error_deg(*x, *y) < 1e-3);
    }
}

#[test]
fn subsets_drop_lights_exactly() {
    // Corrupt light 2 everywhere; excluding it through the usable flags restores the truth.
    let dirs = ring(6, 35.0);
    let (mut capture, truth) = lambert_sphere(64, 28.0, &dirs);
    let n = capture.n_lights();
    let c = capture.channels;
    for p in 0..capture.n_pixels() {
        for ch in 0..c {
            capture.samples[(p * n + 2) * c + ch] += 0.3;
        }
    }
    let mut usable = vec![true; capture.n_pixels() * n];
    for p in 0..capture.n_pixels() {
        usable[p * n + 2] = false;
    }
    let est = crate::solve::estimate::solve_subsets(&capture, Some(&usable), &Silent);
    let worst = est
        .normals
        .iter()
        .zip(&truth)
        .map(|(a, t)| angular_error_deg(*a, [t[0] as f32, t[1] as f32, t[2] as f32]))
        .fold(0.0, f64::max);
    assert!(worst < 0.01, "worst {worst}");
    // With only two usable lights the normal is undetermined.
    let mut two = vec![false; capture.n_pixels() * n];
    for p in 0..capture.n_pixels() {
        two[p * n] = true;
        two[p * n + 1] = true;
    }
    let est = crate::solve::estimate::solve_subsets(&capture, Some(&two), &Silent);
    assert!(est.normals.iter().all(|v| *v == [0.0; 3]));
}
