//! The smoother over light directions with which the RBF basis ([`super::rbf`]) resamples its
//! mean and principal components, and the render positions it resamples them at.
//!
//! With u = (l_x, l_y) the light projected on the image plane (PTM's (l_u, l_v)), values y_i at
//! the lights u_i are modelled as PTM's ridge quadratic plus Gaussian radial functions fitted to
//! what it leaves:
//!
//! ```text
//! s(u) = p(u)ᵀ b + Σ_i a_i G(|u − u_i|),   p = (1, u, v, u², v², uv),   G(r) = exp(−r² / ε²)   (1)
//! b = (PᵀP + ρ D)⁻¹ Pᵀ y = B y,             P_ik = p_k(u_i)                                   (2)
//! a = (G + λ I)⁻¹ (y − P b),                G_ij = G(|u_i − u_j|)                              (3)
//! ```
//!
//! (2) is PTM's ridge fit ([`super::Basis::roughness`]: D = π (0, 1, 1, 1, 1, 1/2), the
//! Dirichlet energy over the unit disk; ρ = 0 the plain least squares) and (3) Gaussian-process
//! regression of its residuals (e.g. Rasmussen & Williams 2006, "Gaussian processes for machine
//! learning", eq. 2.25: G has unit diagonal, so λ is the noise-to-signal variance ratio). λ = 0
//! interpolates the lights; λ → ∞ leaves PTM's ridge quadratic, so that candidate is PTM's own
//! fit; a quadratic y is reproduced exactly at every λ when ρ = 0 (its residual is 0). Past the
//! lights the Gaussians fade and s continues as the quadratic: it extrapolates as PTM does. A
//! Gaussian rather than a thin-plate kernel: it is positive definite, so (3) is well posed on
//! its own whatever the polynomial part, and the polynomial part can be PTM's ridge fit rather
//! than an unpenalised one; its width ε is the lights' spacing (the residual is carried to the
//! neighbours and no further).
//!
//! Closed form for every λ: G = V Λ Vᵀ, so (G + λ I)⁻¹ = V (Λ + λ I)⁻¹ Vᵀ. The value at x is
//! linear in y, s(x) = r(x) · y with
//!
//! ```text
//! r(x) = Bᵀ p(x) + (I − P B)ᵀ V (Λ + λ I)⁻¹ Vᵀ g(x),   g_i(x) = G(|x − u_i|)                 (4)
//! ```
//!
//! and a weighted sum of such rows, Σ_m c_m r(x_m), is (4) with p and g summed likewise.

use crate::base::error::{Error, Result};
use nalgebra::{DMatrix, DVector, SymmetricEigen};

/// Terms of the polynomial part: PTM's biquadratic.
pub const POLY: usize = 6;

/// The smallest ratio of the least to the greatest singular value of the lights' polynomial
/// matrix P (columns scaled to unit length) for which they determine a quadratic.
pub const MIN_CONDITION: f64 = 1e-6;

/// The polynomial terms at a light: 1, u, v, u², v², uv.
pub fn poly(l: [f64; 3]) -> [f64; POLY] {
    let (u, v) = (l[0], l[1]);
    [1.0, u, v, u * u, v * v, u * v]
}

/// PTM's roughness of the terms of [`poly`] (the diagonal D of (2)).
pub fn roughness() -> [f64; POLY] {
    use std::f64::consts::PI;
    [0.0, PI, PI, PI, PI, PI / 2.0]
}

/// The Gaussian of two lights' projections under width `eps`.
pub fn gauss(a: [f64; 3], b: [f64; 3], eps: f64) -> f64 {
    let r2 = (a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2);
    (-r2 / (eps * eps)).exp()
}

/// The smoother's nodes and the factors of (4).
#[derive(Clone, Debug)]
pub struct Smoother {
    nodes: Vec<[f64; 3]>,
    width: f64,
    /// B (6 × N).
    b: DMatrix<f64>,
    /// (I − P B)ᵀ V (N × N).
    resid_v: DMatrix<f64>,
    /// V (N × N).
    v: DMatrix<f64>,
    /// Λ.
    spectrum: Vec<f64>,
}

/// A right-hand side of (4) reduced: Bᵀ p and Vᵀ g.
#[derive(Clone, Debug)]
pub struct Reduced {
    poly_part: DVector<f64>,
    coords: DVector<f64>,
}

impl Smoother {
    /// The smoother over the unit lights `nodes` with ridge weight `ridge` (ρ ≥ 0) and Gaussian
    /// width `width` (ε > 0); an error when the lights are fewer than 6 or do not determine a
    /// quadratic (on a line or a conic, e.g. one ring of equal elevation).
    pub fn new(nodes: &[[f64; 3]], ridge: f64, width: f64) -> Result<Smoother> {
        let n = nodes.len();
        if n < POLY {
            return Err(Error::invalid(format!(
                "rbf resamples its basis on PTM's quadratic (6 terms) of the light; {n} lights \
                 do not determine it"
            )));
        }
        let p = DMatrix::from_fn(n, POLY, |i, k| poly(nodes[i])[k]);
        check_quadratic(&p)?;
        let mut normal = p.transpose() * &p;
        for (k, d) in roughness().iter().enumerate() {
            normal[(k, k)] += ridge * d;
        }
        let inv = normal
            .try_inverse()
            .ok_or_else(|| Error::invalid("rbf: the lights' quadratic is singular"))?;
        let b = inv * p.transpose();
        let resid = DMatrix::identity(n, n) - &p * &b;
        let g = DMatrix::from_fn(n, n, |i, j| gauss(nodes[i], nodes[j], width));
        let eig = SymmetricEigen::new(g);
        let resid_v = resid.transpose() * &eig.eigenvectors;
        Ok(Smoother {
            nodes: nodes.to_vec(),
            width,
            b,
            resid_v,
            v: eig.eigenvectors,
            spectrum: eig.eigenvalues.iter().copied().collect(),
        })
    }

    /// The nodes.
    pub fn nodes(&self) -> &[[f64; 3]] {
        &self.nodes
    }

    /// The Gaussians g(x) at the light `x`.
    pub fn gaussians(&self, x: [f64; 3]) -> DVector<f64> {
        let g = self.nodes.iter().map(|&u| gauss(x, u, self.width));
        DVector::from_iterator(self.nodes.len(), g)
    }

    /// The right-hand side (p, g) of (4) reduced.
    pub fn reduce(&self, g: &DVector<f64>, p: &[f64; POLY]) -> Reduced {
        Reduced {
            poly_part: self.b.transpose() * DVector::from_row_slice(p),
            coords: self.v.transpose() * g,
        }
    }

    /// (Λ + λ)⁻¹ on `coords`, a pseudo-inverse where Λ + λ vanishes (λ infinite: 0).
    fn shrink(&self, coords: &DVector<f64>, lambda: f64) -> DVector<f64> {
        let top = self.spectrum.iter().fold(0.0f64, |a, &s| a.max(s.abs()));
        DVector::from_iterator(
            coords.len(),
            coords.iter().zip(&self.spectrum).map(|(&c, &s)| {
                let d = s + lambda;
                if lambda.is_finite() && d > 1e-10 * top {
                    c / d
                } else {
                    0.0
                }
            }),
        )
    }

    /// The row (4) of a reduced right-hand side under smoothing `lambda` (≥ 0, or infinite).
    pub fn solve(&self, r: &Reduced, lambda: f64) -> DVector<f64> {
        &r.poly_part + &self.resid_v * self.shrink(&r.coords, lambda)
    }

    /// The row r(x) with s(x) = r(x) · y.
    pub fn row(&self, x: [f64; 3], lambda: f64) -> DVector<f64> {
        self.solve(&self.reduce(&self.gaussians(x), &poly(x)), lambda)
    }

    /// The coefficients a (N) and b (6) of (1) for the values `y`.
    pub fn coefficients(&self, y: &DVector<f64>, lambda: f64) -> (DVector<f64>, DVector<f64>) {
        let b = &self.b * y;
        let a = &self.v * self.shrink(&(self.resid_v.transpose() * y), lambda);
        (a, b)
    }

    /// The smoother's values at `points` of each of the value vectors `ys`: `[y][point]`.
    pub fn values(&self, ys: &[DVector<f64>], lambda: f64, points: &[[f64; 3]]) -> Vec<Vec<f64>> {
        let basis: Vec<(DVector<f64>, [f64; POLY])> = points
            .iter()
            .map(|&x| (self.gaussians(x), poly(x)))
            .collect();
        ys.iter()
            .map(|y| {
                let (a, b) = self.coefficients(y, lambda);
                basis
                    .iter()
                    .map(|(g, p)| {
                        g.dot(&a) + p.iter().zip(b.iter()).map(|(x, y)| x * y).sum::<f64>()
                    })
                    .collect()
            })
            .collect()
    }
}

/// Refuses lights that do not determine a quadratic: the least singular value of P with its
/// columns scaled to unit length below [`MIN_CONDITION`] × the greatest.
fn check_quadratic(p: &DMatrix<f64>) -> Result<()> {
    let mut scaled = p.clone();
    for mut col in scaled.column_iter_mut() {
        let norm = col.norm();
        col /= norm.max(f64::MIN_POSITIVE);
    }
    let sv = scaled.singular_values();
    let (lo, hi) = sv.iter().fold((f64::INFINITY, 0.0f64), |(lo, hi), &s| {
        (lo.min(s), hi.max(s))
    });
    if lo > hi * MIN_CONDITION {
        return Ok(());
    }
    Err(Error::invalid(format!(
        "rbf resamples its basis on PTM's quadratic of the light; the {} lights lie on a line or \
         a conic (one ring of equal elevation) and do not determine it (condition {:.1e} < \
         {MIN_CONDITION:.0e})",
        p.nrows(),
        lo / hi
    )))
}

/// The most render positions [`render_positions`] places.
pub const MAX_POSITIONS: usize = 256;

/// The render positions of lights: a square grid in the (l_x, l_y) plane, anchored at the view
/// axis (0, 0), over the lights' convex hull grown by g and within the horizon (|u| ≤ 1); g is
/// the rig's largest gap, the greatest distance in that plane from a light to its nearest
/// other (a light left out of the rig lies within its own nearest-neighbour distance of the
/// others, so the grid of the others reaches it, and a viewer's light one gap beyond the
/// outermost lights is rendered from the smoother's extrapolation rather than from the edge's
/// values); its spacing is the finest that keeps at most [`MAX_POSITIONS`] points. Returns the unit vectors (z = √(1 − |u|²)) and the grid
/// spacing (0, with the lights themselves, when they span no area).
pub fn render_positions(lights: &[[f64; 3]]) -> (Vec<[f64; 3]>, f64) {
    let pts: Vec<[f64; 2]> = lights.iter().map(|l| [l[0], l[1]]).collect();
    let h = nearest_distances(&pts).into_iter().fold(0.0, f64::max);
    let hull = convex_hull(&pts);
    if hull.len() < 3 || h.is_nan() || h <= 0.0 {
        return (lights.to_vec(), 0.0);
    }
    let m = hull.len();
    let edges = || (0..m).map(|i| (hull[i], hull[(i + 1) % m]));
    let area: f64 = edges().map(|(a, b)| a[0] * b[1] - a[1] * b[0]).sum::<f64>() / 2.0;
    let perimeter: f64 = edges().map(|(a, b)| dist(a, b)).sum();
    // Steiner: the area of the hull grown by h.
    let grown = area + perimeter * h + std::f64::consts::PI * h * h;
    let (lo, hi) = pts.iter().fold(([1f64; 2], [-1f64; 2]), |(lo, hi), p| {
        (
            [lo[0].min(p[0]), lo[1].min(p[1])],
            [hi[0].max(p[0]), hi[1].max(p[1])],
        )
    });
    let inside = |p: [f64; 2]| p[0] * p[0] + p[1] * p[1] <= 1.0 && hull_distance(&hull, p) <= h;
    let mut step = (grown / MAX_POSITIONS as f64).sqrt();
    loop {
        let (i0, i1) = (
            ((lo[0] - h) / step).floor() as i64,
            ((hi[0] + h) / step).ceil() as i64,
        );
        let (j0, j1) = (
            ((lo[1] - h) / step).floor() as i64,
            ((hi[1] + h) / step).ceil() as i64,
        );
        let grid: Vec<[f64; 3]> = (j0..=j1)
            .flat_map(|j| (i0..=i1).map(move |i| [i as f64 * step, j as f64 * step]))
            .filter(|&p| inside(p))
            .map(|p| {
                [
                    p[0],
                    p[1],
                    (1.0 - p[0] * p[0] - p[1] * p[1]).max(0.0).sqrt(),
                ]
            })
            .collect();
        if grid.len() <= MAX_POSITIONS {
            return (grid, step);
        }
        step *= 1.02;
    }
}

/// The distance from p to the counter-clockwise convex polygon `hull` (0 inside).
fn hull_distance(hull: &[[f64; 2]], p: [f64; 2]) -> f64 {
    let m = hull.len();
    let mut outside = false;
    let mut best = f64::INFINITY;
    for i in 0..m {
        let (a, b) = (hull[i], hull[(i + 1) % m]);
        let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
        if dx * (p[1] - a[1]) - dy * (p[0] - a[0]) < 0.0 {
            outside = true;
        }
        let len2 = (dx * dx + dy * dy).max(f64::MIN_POSITIVE);
        let t = (((p[0] - a[0]) * dx + (p[1] - a[1]) * dy) / len2).clamp(0.0, 1.0);
        best = best.min(dist(p, [a[0] + t * dx, a[1] + t * dy]));
    }
    if outside {
        best
    } else {
        0.0
    }
}

fn dist(a: [f64; 2], b: [f64; 2]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt()
}

/// The spacing of lights in the (l_x, l_y) plane: the median over the lights of the distance
/// to the nearest other (the width ε of the smoother's Gaussians).
pub fn spacing(lights: &[[f64; 3]]) -> f64 {
    let pts: Vec<[f64; 2]> = lights.iter().map(|l| [l[0], l[1]]).collect();
    median_spacing(&pts)
}

/// Per point, the distance to the nearest other.
fn nearest_distances(pts: &[[f64; 2]]) -> Vec<f64> {
    (0..pts.len())
        .map(|i| {
            (0..pts.len())
                .filter(|&j| j != i)
                .map(|j| dist(pts[i], pts[j]))
                .fold(f64::INFINITY, f64::min)
        })
        .collect()
}

/// The median over the points of the distance to the nearest other.
fn median_spacing(pts: &[[f64; 2]]) -> f64 {
    let mut nn = nearest_distances(pts);
    nn.sort_by(f64::total_cmp);
    nn.get(nn.len() / 2).copied().unwrap_or(0.0)
}

/// The convex hull of points, counter-clockwise, without collinear vertices (Andrew's
/// monotone chain).
fn convex_hull(pts: &[[f64; 2]]) -> Vec<[f64; 2]> {
    let mut p = pts.to_vec();
    p.sort_by(|a, b| a[0].total_cmp(&b[0]).then(a[1].total_cmp(&b[1])));
    p.dedup();
    if p.len() < 3 {
        return p;
    }
    let cross = |o: [f64; 2], a: [f64; 2], b: [f64; 2]| {
        (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])
    };
    let mut hull: Vec<[f64; 2]> = Vec::with_capacity(2 * p.len());
    for pass in 0..2 {
        let start = hull.len();
        let iter: Box<dyn Iterator<Item = &[f64; 2]>> = if pass == 0 {
            Box::new(p.iter())
        } else {
            Box::new(p.iter().rev())
        };
        for &q in iter {
            while hull.len() >= start + 2
                && cross(hull[hull.len() - 2], hull[hull.len() - 1], q) <= 0.0
            {
                hull.pop();
            }
            hull.push(q);
        }
        hull.pop();
    }
    hull
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Scattered unit lights within 60° of the view axis.
    fn lights(n: usize) -> Vec<[f64; 3]> {
        (0..n)
            .map(|i| {
                let t = (i as f64 + 0.5) / n as f64;
                let r = 0.85 * t.sqrt();
                let a = 2.39996 * i as f64;
                [r * a.cos(), r * a.sin(), (1.0 - r * r).sqrt()]
            })
            .collect()
    }

    fn quadratic(l: [f64; 3]) -> f64 {
        let (u, v) = (l[0], l[1]);
        0.3 - 0.7 * u + 0.2 * v + 1.1 * u * u - 0.4 * v * v + 0.9 * u * v
    }

    #[test]
    fn the_smoother_reproduces_quadratics_at_every_smoothing() {
        let ls = lights(17);
        let s = Smoother::new(&ls, 0.0, 0.3).unwrap();
        let y = DVector::from_iterator(ls.len(), ls.iter().map(|&l| quadratic(l)));
        let mut probes = render_positions(&ls).0;
        probes.push([0.95, 0.0, (1.0f64 - 0.95 * 0.95).sqrt()]);
        for lambda in [0.0, 1e-3, 1.0, 1e6, f64::INFINITY] {
            let values = s.values(std::slice::from_ref(&y), lambda, &probes);
            for (&x, &v) in probes.iter().zip(&values[0]) {
                let got = s.row(x, lambda).dot(&y);
                assert!(
                    (got - quadratic(x)).abs() < 1e-9,
                    "λ {lambda} at {x:?}: {got}"
                );
                assert!((v - got).abs() < 1e-9, "λ {lambda} at {x:?}: {v} vs {got}");
            }
        }
    }

    #[test]
    fn lambda_zero_interpolates_and_infinity_is_ptm_ridge_fit() {
        let ls = lights(15);
        let y = DVector::from_iterator(ls.len(), (0..ls.len()).map(|i| ((i * 7) % 5) as f64));
        for ridge in [0.0, 0.5] {
            let s = Smoother::new(&ls, ridge, 0.25).unwrap();
            for (i, &l) in ls.iter().enumerate() {
                assert!((s.row(l, 0.0).dot(&y) - y[i]).abs() < 1e-6);
            }
            // PTM's ridge fit by its normal equations, (PᵀP + ρ D) c = Pᵀ y.
            let p = DMatrix::from_fn(ls.len(), POLY, |i, k| poly(ls[i])[k]);
            let d = DMatrix::from_diagonal(&DVector::from_row_slice(&roughness()));
            let c = (p.transpose() * &p + d * ridge).try_inverse().unwrap() * p.transpose() * &y;
            let x = [0.2, -0.1, (1.0f64 - 0.05).sqrt()];
            let want: f64 = poly(x).iter().zip(c.iter()).map(|(a, b)| a * b).sum();
            assert!((s.row(x, f64::INFINITY).dot(&y) - want).abs() < 1e-9);
            assert!((s.row(x, 1e12).dot(&y) - want).abs() < 1e-6);
        }
    }

    #[test]
    fn degenerate_rigs_are_refused() {
        let ring: Vec<[f64; 3]> = (0..12)
            .map(|i| {
                let a = i as f64 * std::f64::consts::FRAC_PI_6;
                [0.5 * a.cos(), 0.5 * a.sin(), 0.75f64.sqrt()]
            })
            .collect();
        let e = Smoother::new(&ring, 0.0, 0.2).unwrap_err().to_string();
        assert!(e.contains("conic"), "{e}");
        let e = Smoother::new(&lights(5), 0.0, 0.2).unwrap_err().to_string();
        assert!(e.contains("5 lights"), "{e}");
    }

    #[test]
    fn the_grid_covers_the_lights_and_reaches_beyond_them() {
        let ls = lights(30);
        let (pos, step) = render_positions(&ls);
        assert!(
            pos.len() <= MAX_POSITIONS && pos.len() > MAX_POSITIONS / 2,
            "{}",
            pos.len()
        );
        let r = |l: &[f64; 3]| (l[0] * l[0] + l[1] * l[1]).sqrt();
        let outer = ls.iter().map(r).fold(0.0, f64::max);
        for p in &pos {
            assert!(((p[0] * p[0] + p[1] * p[1] + p[2] * p[2]) - 1.0).abs() < 1e-12);
            // On the lattice anchored at the view axis.
            for x in &p[..2] {
                assert!((x / step - (x / step).round()).abs() < 1e-9);
            }
        }
        // Every light has a position within half a diagonal step, and beyond the outermost
        // light there are positions in every direction.
        for l in &ls {
            let near = pos
                .iter()
                .map(|p| ((p[0] - l[0]).powi(2) + (p[1] - l[1]).powi(2)).sqrt());
            assert!(near.fold(f64::INFINITY, f64::min) <= step * 0.7072);
        }
        for k in 0..36 {
            let a = k as f64 * 10f64.to_radians();
            let beyond = pos.iter().any(|p| {
                let t = p[1].atan2(p[0]) - a;
                t.cos() > 0.98 && r(p) > outer + 0.5 * step
            });
            assert!(beyond, "no position beyond the lights toward {a}");
        }
    }
}
