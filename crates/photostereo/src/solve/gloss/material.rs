//! Lobes shared by the pixels of a material: the recursive method's `--reflectance material`.
//!
//! The per-pixel lobe fit ([`crate::solve::gloss`]) gives every pixel its own lobe, and its
//! significance rests on that pixel's readings alone. Most surfaces are made of a few materials,
//! and the shape of a material's reflectance is the same at all its pixels: here it is fitted
//! once per material from all its pixels, so that each pixel only adds its normal, its diffuse
//! albedo ρ and a specular strength s:
//!
//! I_k = ρ f(n · l_k) + s g(n · h_k),   ρ ≥ 0, s ≥ 0,
//!
//! with h_k the half vector of light k and the orthographic camera, g a monotone lobe (g = 1 at
//! the peak, falling to 0 at [`LOBE_KNOTS`] × [`LOBE_STEP_DEG`] from it; piecewise linear in
//! 1 − n · h between knots at whole multiples of the step in the half-vector angle) and f a
//! monotone diffuse falloff (f(0) = 0, f(1) = 1; Lambert is f(c) = c; piecewise linear with
//! [`DIFFUSE_KNOTS`] knots). Monotone shapes with non-negative ramp weights cover the isotropic
//! lobes of common BRDFs (Blinn–Phong, Torrance–Sparrow, Ward) without naming one. The readings
//! are weighted by their noise as in the per-pixel fit; shadows and clipped readings stay
//! excluded (the recursion's USED and HIGHLIGHT lights that the camera did not clip are
//! fitted).
//!
//! Steps:
//! 1. *Materials*: k-means of the Lambertian albedo's rg chromaticity (ln ρ for grey captures),
//!    k = 1..=[`MAX_MATERIALS`] by the least BIC of spherical Gaussians; clusters with fewer than
//!    [`MIN_MATERIAL_SAMPLE`] sampled pixels join the nearest other one.
//! 2. *Shapes*: over at most [`SAMPLE_PIXELS`] pixels of the material with
//!    [`crate::solve::gloss::MIN_LIGHTS`] lights out of shadow, alternately (a) each pixel's
//!    normal, ρ and s by Levenberg–Marquardt from the recursion's normal and (b) the shapes'
//!    ramp weights by non-negative least squares over all the pixels' readings, from the
//!    capture's exponential lobe, [`ROUNDS`] times.
//! 3. *Evidence*: the material's pooled χ² with the lobe (χ²_B) and without it (χ²_A, the
//!    diffuse falloff alone), each pixel's normal refitted; the lobe's Δp parameters (one s per
//!    pixel and the lobe's weights) are kept where Schwarz's criterion for N readings with
//!    unknown noise prefers them: N ln(χ²_A / χ²_B) > Δp ln N. The criterion scales the
//!    penalty with ln N rather than asking for a lowering beyond noise, so that model error
//!    pooled over thousands of pixels — a camera response, interreflection — does not pass
//!    for a lobe, while a lobe that explains a large share of the residual does.
//! 4. Every pixel of a material with a lobe (and [`crate::solve::gloss::MIN_LIGHTS`] lights
//!    out of shadow) takes the fitted normal where it faces the camera and its lit lights,
//!    whether its own strength is positive or zero (its roughness map then NaN); the other
//!    materials keep the recursion's estimate unchanged.
//!
//! *Fewer than [`MIN_LIGHTS`] lights* (the paper's four): a pixel's own s would take the one
//! reading beyond its normal and ρ that tests the model, and no pixel could measure the
//! capture's sharpness. There the strength is the material's (the lobe's amplitude, fitted with
//! its shape), the diffuse falloff stays Lambert's, the shapes start from an exponential lobe
//! of roughness 0.2, the pixels with [`MIN_SHARED_LIGHTS`] lights out of shadow are sampled,
//! and the alternation goes on until the pooled χ² settles ([`MAX_SHARED_ROUNDS`],
//! [`SHARED_TOLERANCE`]): the normals and one lobe pull on each other slowly. The evidence
//! counts the lobe's weights alone; a pixel takes the fit only where the lobe reaches one of
//! its readings beyond noise (the χ² quantile of one degree of freedom), the others keep the
//! recursion's estimate.
//!
//! The strength map gives s, the roughness map the material's lobe as the roughness √(2x₁/ₑ)
//! of the exponential lobe exp(−m x) falling to 1/e at the same x = 1 − n · h (m = 1/x₁/ₑ).
//! Cost: a few descents per fitted pixel and, per round, normal equations of
//! [`LOBE_KNOTS`] + [`DIFFUSE_KNOTS`] unknowns over the sample; memory: the sample's readings
//! (N_lights × 57 bytes per sampled pixel) and one byte per pixel for the materials.

use crate::base::error::Result;
use crate::model::capture::Capture;
use crate::solve::gloss::{
    descend, descend_by, dot, refit_pixels, start_of, GlossMaps, GlossSummary, Lights, Reflectance,
    Scratch, Taken, MIN_LIGHTS,
};
use crate::solve::lambert::{status, Estimate, Statuses};
use crate::solve::near_lobe::{fit_at, PairSums, PixelData};
use nalgebra::{Matrix4, Vector4};
use rayon::prelude::*;
use serde::Serialize;

/// Spacing of the lobe's knots in the half-vector angle, degrees.
pub const LOBE_STEP_DEG: f64 = 2.0;
/// Knots of the lobe: it reaches zero 60° from its peak.
pub const LOBE_KNOTS: usize = 30;
/// Knots of the diffuse falloff, evenly spaced in n · l.
pub const DIFFUSE_KNOTS: usize = 20;
/// Alternations of per-pixel fits and shape fits.
pub const ROUNDS: usize = 3;
/// Alternations at most with the material's one strength (fewer than six lights).
pub const MAX_SHARED_ROUNDS: usize = 100;
/// With the material's one strength, a round's pooled χ² is a new least only where it is lower
/// by this share of it.
pub const SHARED_TOLERANCE: f64 = 1e-4;
/// Rounds in a row without a new least χ² that end the alternation.
const PATIENCE: usize = 3;
/// Pixels sampled per material for its shapes and evidence.
pub const SAMPLE_PIXELS: usize = 3000;
/// Materials at most.
pub const MAX_MATERIALS: usize = 4;
/// Sampled pixels a material needs of its own.
pub const MIN_MATERIAL_SAMPLE: usize = 50;

/// One material in `report.json`.
#[derive(Clone, Debug, Serialize)]
pub struct MaterialSummary {
    /// Its centre: rg chromaticity of the albedo, or (ln ρ, 0) for grey captures.
    pub center: [f64; 2],
    /// Mask pixels assigned to it.
    pub pixels: usize,
    /// Of them, sampled for the shapes and the evidence.
    pub sample_pixels: usize,
    /// N ln(χ²_A / χ²_B) − Δp ln N: positive where the lobe is kept.
    pub evidence: Option<f64>,
    /// Whether its pixels take the lobe fit.
    pub lobe: bool,
    /// The lobe's roughness √(2x₁/ₑ) (see the module documentation).
    pub roughness: Option<f64>,
    /// The lobe's value at the knots 0°, 6°, 12°, … of the half-vector angle.
    pub lobe_shape: Vec<f64>,
    /// The diffuse falloff f at n · l = 0, 0.1, …, 1.
    pub diffuse_shape: Vec<f64>,
}

/// The result of [`model_materials`].
pub(crate) struct Materials {
    pub summary: GlossSummary,
    pub maps: GlossMaps,
}

/// Piecewise-linear monotone shape: knots `x` (increasing), ramp weights `a[1..]` ≥ 0.
/// As a lobe, x = 1 − n · h and the value Σ_{j} a_j clamp((x_j − x)/(x_j − x_{j−1}), 0, 1)
/// falls from Σa at x_0 = 0 to 0 at the last knot; as a diffuse falloff, x = n · l and the
/// value Σ_j a_j clamp((x − x_{j−1})/(x_j − x_{j−1}), 0, 1) rises from 0.
#[derive(Clone, Debug)]
pub(crate) struct Shape {
    x: Vec<f64>,
    a: Vec<f64>,
    /// Value at each knot.
    at: Vec<f64>,
    falling: bool,
}

impl Shape {
    /// The lobe exp(−m (1 − n · h)) at the knots.
    fn lobe(m: f64) -> Self {
        let x: Vec<f64> = (0..=LOBE_KNOTS)
            .map(|j| 1.0 - (j as f64 * LOBE_STEP_DEG).to_radians().cos())
            .collect();
        let g = |j: usize| {
            if j < LOBE_KNOTS {
                (-m * x[j]).exp()
            } else {
                0.0
            }
        };
        let a = (0..=LOBE_KNOTS)
            .map(|j| if j == 0 { 0.0 } else { g(j - 1) - g(j) })
            .collect();
        Shape::new(x, a, true)
    }

    /// Lambert's f(c) = c.
    fn lambert() -> Self {
        let step = 1.0 / DIFFUSE_KNOTS as f64;
        let x = (0..=DIFFUSE_KNOTS).map(|j| j as f64 * step).collect();
        let a = (0..=DIFFUSE_KNOTS)
            .map(|j| if j == 0 { 0.0 } else { step })
            .collect();
        Shape::new(x, a, false)
    }

    fn new(x: Vec<f64>, a: Vec<f64>, falling: bool) -> Self {
        let mut s = Shape {
            at: vec![0.0; x.len()],
            x,
            a,
            falling,
        };
        s.set(&[]);
        s
    }

    fn knots(&self) -> usize {
        self.x.len() - 1
    }

    /// Replaces the ramp weights (`a[j − 1]` for j = 1..=J) unless empty, scaled so that the
    /// shape's extreme is 1; false where they are all zero.
    fn set(&mut self, a: &[f64]) -> bool {
        let j = self.knots();
        if !a.is_empty() {
            let total: f64 = a.iter().sum();
            if total <= 0.0 {
                return false;
            }
            for i in 1..=j {
                self.a[i] = a[i - 1] / total;
            }
        }
        if self.falling {
            self.at[j] = 0.0;
            for i in (0..j).rev() {
                self.at[i] = self.at[i + 1] + self.a[i + 1];
            }
        } else {
            self.at[0] = 0.0;
            for i in 1..=j {
                self.at[i] = self.at[i - 1] + self.a[i];
            }
        }
        true
    }

    /// The segment j of x: x_{j−1} < x ≤ x_j, clamped to 1..=J (J + 1 beyond a lobe's end).
    #[inline]
    fn segment(&self, x: f64) -> usize {
        let j = self.knots();
        if self.falling {
            // Knots at whole steps of the half-vector angle θ, x = 1 − cos θ.
            let theta = (1.0 - x).clamp(-1.0, 1.0).acos();
            ((theta / LOBE_STEP_DEG.to_radians()).ceil() as usize).max(1)
        } else {
            ((x * j as f64).ceil() as usize).clamp(1, j)
        }
    }

    /// The shape and its derivative at c (c = n · h for a lobe, n · l for a falloff).
    #[inline]
    fn eval(&self, c: f64) -> (f64, f64) {
        let x = if self.falling { 1.0 - c } else { c };
        if !self.falling && x <= 0.0 {
            return (0.0, 0.0);
        }
        let j = self.segment(x);
        if j > self.knots() {
            return (0.0, 0.0);
        }
        let dx = self.x[j] - self.x[j - 1];
        let t = ((x - self.x[j - 1]) / dx).clamp(0.0, 1.0);
        // d/dc: the lobe falls in x = 1 − c, the falloff rises in x = c.
        (
            self.at[j - 1] + (self.at[j] - self.at[j - 1]) * t,
            self.a[j] / dx,
        )
    }

    /// The ramps at c into `out[j − 1]`, j = 1..=J.
    fn ramps(&self, c: f64, out: &mut [f64]) {
        let x = if self.falling { 1.0 - c } else { c };
        for j in 1..=self.knots() {
            let t = (x - self.x[j - 1]) / (self.x[j] - self.x[j - 1]);
            out[j - 1] = if self.falling {
                (1.0 - t).clamp(0.0, 1.0)
            } else if x > 0.0 {
                t.clamp(0.0, 1.0)
            } else {
                0.0
            };
        }
    }

    /// A lobe's roughness √(2x₁/ₑ): the exponential lobe falling to 1/e at the same x.
    fn roughness(&self) -> f64 {
        let target = (-1.0f64).exp();
        let j = (1..=self.knots())
            .find(|&j| self.at[j] <= target)
            .unwrap_or(self.knots());
        let (g0, g1) = (self.at[j - 1], self.at[j]);
        let t = if g0 > g1 {
            ((g0 - target) / (g0 - g1)).clamp(0.0, 1.0)
        } else {
            0.0
        };
        (2.0 * (self.x[j - 1] + t * (self.x[j] - self.x[j - 1]))).sqrt()
    }
}

/// A material's shapes: the diffuse falloff f(n · l) and the lobe g(n · h).
#[derive(Clone, Debug)]
pub(crate) struct Shapes {
    diffuse: Shape,
    lobe: Shape,
    /// The material's one strength, where the rig has too few lights for a strength per pixel
    /// (fewer than [`MIN_LIGHTS`]): every pixel's s, fitted with the shapes.
    shared: Option<f64>,
}

/// The fit at normal `n` with the shapes: (χ², ρ, s), ρ and s non-negative least squares.
fn fit_with(d: &PixelData, n: [f64; 3], shapes: &Shapes) -> (f64, f64, f64) {
    if let Some(strength) = shapes.shared {
        return fit_shared(d, n, shapes, strength);
    }
    let mut sums = PairSums::default();
    for k in (0..d.v.len()).filter(|&k| d.used[k]) {
        let a = d.b[k] * shapes.diffuse.eval(dot(d.v[k], n) / d.b[k]).0;
        let b = d.b[k] * shapes.lobe.eval(dot(d.h[k], n)).0;
        sums.add(a, b, d.g[k]);
    }
    sums.solve()
}

/// [`fit_with`] with the material's one strength: ρ alone by non-negative least squares.
fn fit_shared(d: &PixelData, n: [f64; 3], shapes: &Shapes, strength: f64) -> (f64, f64, f64) {
    let (mut aa, mut ar) = (0.0, 0.0);
    let terms = |k: usize| {
        let a = d.b[k] * shapes.diffuse.eval(dot(d.v[k], n) / d.b[k]).0;
        (
            a,
            d.g[k] - strength * d.b[k] * shapes.lobe.eval(dot(d.h[k], n)).0,
        )
    };
    for k in (0..d.v.len()).filter(|&k| d.used[k]) {
        let (a, r) = terms(k);
        aa += a * a;
        ar += a * r;
    }
    let rho = if aa > 0.0 { (ar / aa).max(0.0) } else { 0.0 };
    let chi2 = (0..d.v.len())
        .filter(|&k| d.used[k])
        .map(|k| {
            let (a, r) = terms(k);
            (r - rho * a).powi(2)
        })
        .sum();
    (chi2, rho, strength)
}

/// The least χ² normal near `from` with the shapes (returns (χ², normal)): the per-pixel fit's
/// Levenberg–Marquardt descent ([`crate::solve::gloss`]) with f and g in place of n · l and the
/// exponential lobe.
fn descend_with(d: &PixelData, from: [f64; 3], shapes: &Shapes) -> (f64, [f64; 3]) {
    descend_by(
        from,
        |n| fit_with(d, n, shapes),
        |n, (t1, t2), rho, s| {
            let (mut jtj, mut jtr) = (Matrix4::<f64>::zeros(), Vector4::<f64>::zeros());
            for k in (0..d.v.len()).filter(|&k| d.used[k]) {
                let (fl, df) = shapes.diffuse.eval(dot(d.v[k], n) / d.b[k]);
                let (gl, dg) = shapes.lobe.eval(dot(d.h[k], n));
                let (a, lobe) = (d.b[k] * fl, d.b[k] * gl);
                let r = d.g[k] - rho * a - s * lobe;
                let j = Vector4::new(
                    rho * df * dot(d.v[k], t1) + s * d.b[k] * dg * dot(d.h[k], t1),
                    rho * df * dot(d.v[k], t2) + s * d.b[k] * dg * dot(d.h[k], t2),
                    a,
                    lobe,
                );
                jtj += j * j.transpose();
                jtr += j * r;
            }
            if shapes.shared.is_some() {
                // The strength is the material's: no step in it.
                for i in 0..4 {
                    (jtj[(3, i)], jtj[(i, 3)]) = (0.0, 0.0);
                }
                (jtj[(3, 3)], jtr[3]) = (1.0, 0.0);
            }
            (jtj, jtr)
        },
    )
}

/// A sampled pixel: its loaded readings, the recursion's normal and the current fit.
struct Sampled {
    v: Vec<[f64; 3]>,
    b: Vec<f64>,
    g: Vec<f64>,
    used: Vec<bool>,
    start: [f64; 3],
    normal: [f64; 3],
    rho: f64,
    s: f64,
}

impl Sampled {
    fn data<'a>(&'a self, half: &'a [[f64; 3]]) -> PixelData<'a> {
        PixelData {
            v: &self.v,
            h: half,
            b: &self.b,
            g: &self.g,
            used: &self.used,
        }
    }
}

/// The shapes' ramp weights from the sampled pixels at their current normal, ρ and s: the
/// readings are linear in them (ρ ramps of f, s ramps of g); non-negative least squares by
/// projected Gauss–Seidel on the normal equations. `None` where the lobe's weights all vanish.
fn fit_shapes(pixels: &[Sampled], half: &[[f64; 3]], shapes: &Shapes) -> Option<Shapes> {
    use nalgebra::{DMatrix, DVector};
    // With the material's one strength the diffuse falloff stays Lambert's: a pixel's one
    // reading beyond its normal and ρ cannot also shape f.
    let jg = shapes.lobe.knots();
    let jf = if shapes.shared.is_some() {
        0
    } else {
        shapes.diffuse.knots()
    };
    let dim = jg + jf;
    let zero = || (DMatrix::<f64>::zeros(dim, dim), DVector::<f64>::zeros(dim));
    let (h, q) = pixels
        .par_iter()
        .fold(
            || (zero(), vec![0.0; dim]),
            |((mut h, mut q), mut row), p| {
                for k in (0..p.v.len()).filter(|&k| p.used[k]) {
                    shapes.lobe.ramps(dot(half[k], p.normal), &mut row[..jg]);
                    let c = dot(p.v[k], p.normal) / p.b[k];
                    if jf > 0 {
                        shapes.diffuse.ramps(c, &mut row[jg..]);
                    }
                    let scale = |j: usize| if j < jg { p.s * p.b[k] } else { p.rho * p.b[k] };
                    let r = DVector::from_fn(dim, |j, _| row[j] * scale(j));
                    // A fixed falloff's part of the reading is taken off the target.
                    let fixed = if jf == 0 {
                        p.rho * p.b[k] * shapes.diffuse.eval(c).0
                    } else {
                        0.0
                    };
                    h.syger(1.0, &r, &r, 1.0);
                    q.axpy(p.g[k] - fixed, &r, 1.0);
                }
                ((h, q), row)
            },
        )
        .map(|(hq, _)| hq)
        .reduce(zero, |a, b| (a.0 + b.0, a.1 + b.1));
    // syger fills the lower triangle.
    let h = DMatrix::from_fn(dim, dim, |i, j| h[(i.max(j), i.min(j))]);
    let mut a = DVector::from_fn(dim, |j, _| {
        if j < jg {
            shapes.lobe.a[j + 1]
        } else {
            shapes.diffuse.a[j - jg + 1]
        }
    });
    for _ in 0..NNLS_SWEEPS {
        for j in 0..dim {
            if h[(j, j)] > 0.0 {
                let ha = h.row(j).dot(&a.transpose());
                a[j] = (a[j] + (q[j] - ha) / h[(j, j)]).max(0.0);
            }
        }
    }
    let mut out = shapes.clone();
    let weights: Vec<f64> = a.iter().copied().collect();
    if !out.lobe.set(&weights[..jg]) {
        return None;
    }
    // The lobe's ramps were scaled by the pixels' (shared) strength: its amplitude moves into
    // the new strength, the shape is kept with its extreme at 1.
    out.shared = shapes.shared.map(|s| s * weights[..jg].iter().sum::<f64>());
    out.diffuse.set(&weights[jg..]);
    Some(out)
}

/// Sweeps of projected Gauss–Seidel in [`fit_shapes`].
const NNLS_SWEEPS: usize = 2000;

/// Fits the materials of `est` (per mask pixel; `light_status` the recursion's statuses) and
/// refits the pixels of those with a lobe (see the module documentation); `m` is the capture's
/// exponential lobe sharpness, the shapes' start.
pub(crate) fn model_materials(
    capture: &Capture,
    light_status: &(impl Statuses + ?Sized),
    est: &mut Estimate,
    lights: &Lights,
    m: f64,
) -> Result<Materials> {
    let (n, c, np) = (capture.n_lights(), capture.channels, capture.n_pixels());
    let mut summary = GlossSummary::nothing_fitted(Reflectance::Material);
    let mut maps = GlossMaps {
        strength: vec![f32::NAN; np],
        roughness: vec![f32::NAN; np],
    };
    let mut st = vec![0u8; n];
    // Under fewer than MIN_LIGHTS lights a pixel's own strength would take the one reading
    // that tests its model: the material's one strength instead.
    let shared = n < MIN_LIGHTS;
    let min_lit = if shared {
        MIN_SHARED_LIGHTS
    } else {
        MIN_LIGHTS
    };
    let candidates: Vec<usize> = (0..np)
        .filter(|&p| {
            light_status.row_into(p, &mut st);
            lit(&st) >= min_lit && start_of(est.normals[p]).is_some()
        })
        .collect();
    let features: Vec<Option<[f64; 2]>> = (0..np)
        .map(|p| feature(&est.albedo[p * c..(p + 1) * c]))
        .collect();
    let spaced = |ids: &[usize], most: usize| -> Vec<usize> {
        ids.iter()
            .step_by(ids.len().div_ceil(most.max(1)).max(1))
            .copied()
            .collect()
    };
    let sample: Vec<[f64; 2]> = spaced(&candidates, SAMPLE_PIXELS)
        .iter()
        .filter_map(|&p| features[p])
        .collect();
    let centers = materials_of(&sample);
    let labels: Vec<u8> = features
        .iter()
        .map(|f| f.map_or(0, |f| nearest(&centers, f) as u8))
        .collect();
    let mut shapes: Vec<Option<Shapes>> = Vec::new();
    for (k, &center) in centers.iter().enumerate() {
        let own: Vec<usize> = candidates
            .iter()
            .copied()
            .filter(|&p| labels[p] as usize == k)
            .collect();
        let ids = spaced(&own, SAMPLE_PIXELS);
        let (fitted, evidence) =
            material_shapes(capture, light_status, est, lights, (m, shared), &ids)?;
        let lobe = evidence.is_some_and(|e| e > 0.0);
        summary.materials.push(MaterialSummary {
            center,
            pixels: labels.iter().filter(|&&l| l as usize == k).count(),
            sample_pixels: ids.len(),
            evidence,
            lobe,
            roughness: fitted.as_ref().map(|s| s.lobe.roughness()),
            lobe_shape: fitted.as_ref().map_or(Vec::new(), |s| {
                s.lobe.at.iter().step_by(3).copied().collect()
            }),
            diffuse_shape: fitted.as_ref().map_or(Vec::new(), |s| {
                (0..=10)
                    .map(|i| s.diffuse.eval(i as f64 / 10.0).0)
                    .collect()
            }),
        });
        shapes.push(fitted.filter(|_| lobe));
    }
    if shapes.iter().all(Option::is_none) {
        return Ok(Materials { summary, maps });
    }
    let counts = refit_pixels(
        capture,
        light_status,
        est,
        &mut maps,
        |scratch, samples, st, p, start, counts: &mut [usize; 2]| {
            let shape = shapes[labels[p] as usize].as_ref()?;
            if scratch.load(lights, samples, c, st, true) < min_lit {
                return None;
            }
            counts[0] += 1;
            let d = scratch.data(lights);
            let (_, fit) = descend_with(&d, start, shape);
            let (_, rho, s) = fit_with(&d, fit, shape);
            let physical = fit[2] > 0.0 && (0..n).all(|k| !d.used[k] || dot(d.v[k], fit) > 0.0);
            // With the material's one strength a pixel takes the fit only where the lobe
            // reaches a reading beyond noise (its χ² quantile of one degree of freedom): the
            // others have no reading the lobe explains and keep the recursion's estimate.
            if shared {
                let seen = (0..n).any(|k| {
                    d.used[k]
                        && (s * d.b[k] * shape.lobe.eval(dot(d.h[k], fit)).0).powi(2) > lights.q[1]
                });
                if !seen {
                    return Some(None);
                }
            }
            // The material's model holds at each of its pixels, with or without a lobe of its
            // own there (s = 0 is the strength's bound, not a different model): the fit over
            // the unclipped lit lights, with the material's diffuse falloff, replaces the
            // recursion's Lambertian estimate over the lights it kept.
            if !physical {
                return Some(None);
            }
            counts[1] += 1;
            Some(Some(Taken {
                normal: fit,
                rho,
                strength: s,
                roughness: if s > 0.0 {
                    shape.lobe.roughness()
                } else {
                    f64::NAN
                },
            }))
        },
    )?;
    summary.fitted_pixels = counts[0];
    summary.refined_pixels = counts[1];
    summary.refined_share = counts[1] as f64 / np.max(1) as f64;
    if counts[1] > 0 {
        summary.chosen = "lobe";
    }
    summary.roughness = summary
        .materials
        .iter()
        .find(|s| s.lobe)
        .and_then(|s| s.roughness);
    summary.exponent = summary.roughness.map(|r| 2.0 / (r * r));
    Ok(Materials { summary, maps })
}

/// Lights out of shadow a pixel needs for the material's fit with its one strength: the normal
/// and ρ, and one reading beyond them.
pub const MIN_SHARED_LIGHTS: usize = 4;

/// The least-squares albedo at normal `n` from the pixel's diffuse readings (the recursion's
/// USED lights), the shared fit's start.
fn diffuse_albedo(scratch: &Scratch, n: [f64; 3]) -> f64 {
    let (mut aa, mut ag) = (0.0, 0.0);
    for k in (0..scratch.v.len()).filter(|&k| scratch.diffuse[k]) {
        let a = dot(scratch.v[k], n).max(0.0);
        aa += a * a;
        ag += a * scratch.g[k];
    }
    if aa > 0.0 {
        (ag / aa).max(0.0)
    } else {
        0.0
    }
}

/// The lights out of shadow in a pixel's statuses.
fn lit(st: &[u8]) -> usize {
    st.iter()
        .filter(|&&s| s == status::USED || s == status::HIGHLIGHT)
        .count()
}

/// One material's shapes from its sampled pixels `ids` and the evidence for its lobe,
/// N ln(χ²_A / χ²_B) − Δp ln N; `None` for the shapes where the lobe vanished, for the
/// evidence where no pixel was sampled.
fn material_shapes(
    capture: &Capture,
    light_status: &(impl Statuses + ?Sized),
    est: &Estimate,
    lights: &Lights,
    (m, shared): (f64, bool),
    ids: &[usize],
) -> Result<(Option<Shapes>, Option<f64>)> {
    let n = capture.n_lights();
    let mut st = vec![0u8; n];
    let mut scratch = Scratch::new(n);
    let mut pixels = Vec::with_capacity(ids.len());
    capture.for_ids_by_tile(ids, |sub, view| {
        for &p in sub {
            light_status.row_into(p, &mut st);
            scratch.load(lights, view.pixel_samples(p), capture.channels, &st, true);
            let start = start_of(est.normals[p]).expect("a candidate has a normal");
            let d = scratch.data(lights);
            let (normal, rho, s) = if shared {
                (start, diffuse_albedo(&scratch, start), 1.0)
            } else {
                let (_, normal) = descend(&d, start, m);
                let (_, rho, s) = fit_at(&d, normal, m);
                (normal, rho, s)
            };
            pixels.push(Sampled {
                v: scratch.v.clone(),
                b: scratch.b.clone(),
                g: scratch.g.clone(),
                used: scratch.used.clone(),
                start,
                normal,
                rho,
                s,
            });
        }
        Ok(())
    })?;
    if ids.len() < MIN_MATERIAL_SAMPLE {
        return Ok((None, None));
    }
    let half = &lights.half;
    let mut shapes = Shapes {
        diffuse: Shape::lambert(),
        lobe: Shape::lobe(m),
        shared: shared.then_some(1.0),
    };
    // Alternation: a fixed number of rounds with a strength per pixel; with the material's one
    // strength (few lights) the normals and the lobe pull on each other slowly, and the
    // rounds go on until the pooled χ² settles.
    let (rounds, tolerance) = if shared {
        (MAX_SHARED_ROUNDS, SHARED_TOLERANCE)
    } else {
        (ROUNDS, 0.0)
    };
    // The pooled χ² may rise by a little in a round (the shapes' sweeps stop short of the
    // exact minimum): the rounds stop once PATIENCE of them in a row bring no new least χ²
    // lower by `tolerance` of it.
    let (mut best, mut stalled) = (f64::INFINITY, 0);
    for _ in 0..rounds {
        let Some(next) = fit_shapes(&pixels, half, &shapes) else {
            return Ok((None, Some(f64::NEG_INFINITY)));
        };
        shapes = next;
        let chi2: f64 = pixels
            .par_iter_mut()
            .map(|p| {
                let d = p.data(half);
                let (_, normal) = descend_with(&d, p.start, &shapes);
                let (chi2, rho, s) = fit_with(&d, normal, &shapes);
                (p.normal, p.rho, p.s) = (normal, rho, s);
                chi2
            })
            .sum();
        if chi2 < best * (1.0 - tolerance) {
            (best, stalled) = (chi2, 0);
        } else {
            stalled += 1;
            if stalled >= PATIENCE {
                break;
            }
        }
    }
    // The same falloff without the lobe: g = 0.
    let mut flat = shapes.clone();
    flat.lobe.a.iter_mut().for_each(|a| *a = 0.0);
    flat.lobe.set(&[]);
    let (with, without, readings) = pixels
        .par_iter()
        .map(|p| {
            let d = p.data(half);
            let with = descend_with(&d, p.start, &shapes).0;
            let without = descend_with(&d, p.start, &flat).0;
            (with, without, p.used.iter().filter(|&&u| u).count())
        })
        .reduce(|| (0.0, 0.0, 0), |a, b| (a.0 + b.0, a.1 + b.1, a.2 + b.2));
    let big_n = readings as f64;
    let per_pixel = if shared { 0 } else { pixels.len() };
    let extra = (per_pixel + shapes.lobe.knots()) as f64;
    let evidence = big_n * (without / with.max(1e-300)).ln() - extra * big_n.ln();
    Ok((Some(shapes), Some(evidence)))
}

/// The clustering feature of an albedo: rg chromaticity for colour, (ln ρ, 0) for grey;
/// `None` without a positive albedo.
fn feature(albedo: &[f32]) -> Option<[f64; 2]> {
    if albedo.len() >= 3 {
        let (r, g, b) = (albedo[0] as f64, albedo[1] as f64, albedo[2] as f64);
        let t = r + g + b;
        (t > 0.0 && r >= 0.0 && g >= 0.0 && b >= 0.0).then(|| [r / t, g / t])
    } else {
        let a = albedo[0] as f64;
        (a > 0.0).then(|| [a.ln(), 0.0])
    }
}

fn nearest(centers: &[[f64; 2]], f: [f64; 2]) -> usize {
    (0..centers.len())
        .min_by(|&a, &b| d2(centers[a], f).total_cmp(&d2(centers[b], f)))
        .unwrap_or(0)
}

fn d2(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)
}

/// The materials' centres: k-means (farthest-point start, Lloyd) for k = 1..=[`MAX_MATERIALS`],
/// the k of least BIC (spherical Gaussians of one variance per feature dimension used, hard
/// assignment); then clusters with fewer than [`MIN_MATERIAL_SAMPLE`] members are dropped
/// (their pixels go to the nearest centre left).
pub(crate) fn materials_of(x: &[[f64; 2]]) -> Vec<[f64; 2]> {
    let nf = x.len() as f64;
    if x.len() < 2 * MIN_MATERIAL_SAMPLE {
        let mean = x.iter().fold([0.0; 2], |a, p| [a[0] + p[0], a[1] + p[1]]);
        return vec![[mean[0] / nf.max(1.0), mean[1] / nf.max(1.0)]];
    }
    // Grey features vary in one dimension only.
    let dims = if x.iter().all(|p| p[1] == 0.0) {
        1.0
    } else {
        2.0
    };
    let mut best: Option<(f64, Vec<[f64; 2]>, Vec<usize>)> = None;
    for k in 1..=MAX_MATERIALS {
        let (centers, counts) = kmeans(x, k);
        let sse: f64 = x
            .iter()
            .map(|p| d2(centers[nearest(&centers, *p)], *p))
            .sum();
        let var = (sse / (nf * dims)).max(1e-300);
        let ll = -0.5 * nf * dims * ((2.0 * std::f64::consts::PI * var).ln() + 1.0)
            + counts
                .iter()
                .filter(|&&c| c > 0)
                .map(|&c| c as f64 * (c as f64 / nf).ln())
                .sum::<f64>();
        // k centres of `dims` coordinates, k − 1 weights, one variance.
        let params = k as f64 * (dims + 1.0);
        let bic = -2.0 * ll + params * nf.ln();
        if best.as_ref().is_none_or(|b| bic < b.0) {
            best = Some((bic, centers, counts));
        }
    }
    let (_, centers, counts) = best.expect("k = 1 at least");
    let kept: Vec<[f64; 2]> = centers
        .iter()
        .zip(&counts)
        .filter(|(_, &c)| c >= MIN_MATERIAL_SAMPLE)
        .map(|(c, _)| *c)
        .collect();
    if kept.is_empty() {
        centers[..1].to_vec()
    } else {
        kept
    }
}

/// k-means with a farthest-point start: (centres, members).
fn kmeans(x: &[[f64; 2]], k: usize) -> (Vec<[f64; 2]>, Vec<usize>) {
    let nf = x.len() as f64;
    let mean = x
        .iter()
        .fold([0.0; 2], |a, p| [a[0] + p[0] / nf, a[1] + p[1] / nf]);
    let mut centers = vec![mean];
    while centers.len() < k {
        let spread = |p: &[f64; 2]| d2(centers[nearest(&centers, *p)], *p);
        let far = *x
            .iter()
            .max_by(|a, b| spread(a).total_cmp(&spread(b)))
            .expect("points");
        centers.push(far);
    }
    let mut counts = vec![0usize; k];
    for _ in 0..KMEANS_ROUNDS {
        let mut sums = vec![[0.0f64; 2]; k];
        counts.iter_mut().for_each(|c| *c = 0);
        for p in x {
            let j = nearest(&centers, *p);
            sums[j][0] += p[0];
            sums[j][1] += p[1];
            counts[j] += 1;
        }
        let mut moved = false;
        for j in 0..k {
            if counts[j] > 0 {
                let c = [sums[j][0] / counts[j] as f64, sums[j][1] / counts[j] as f64];
                moved |= c != centers[j];
                centers[j] = c;
            }
        }
        if !moved {
            break;
        }
    }
    (centers, counts)
}

/// Lloyd iterations of [`kmeans`] at most.
const KMEANS_ROUNDS: usize = 100;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shapes_match_their_closed_forms() {
        // The lobe exp(−m x) at every knot and, between knots, linearly in x; its 1/e point
        // x = 1/m gives the roughness √(2/m).
        let m = 100.0;
        let lobe = Shape::lobe(m);
        for j in 0..LOBE_KNOTS {
            let c = (j as f64 * LOBE_STEP_DEG).to_radians().cos();
            assert!((lobe.eval(c).0 - (-m * (1.0 - c)).exp()).abs() < 1e-12);
        }
        assert!((lobe.roughness() / (2.0f64 / m).sqrt() - 1.0).abs() < 0.03);
        // Lambert's falloff is c, slope 1, and zero behind the surface.
        let f = Shape::lambert();
        for c in [0.03, 0.25, 0.5, 0.77, 1.0] {
            let (v, d) = f.eval(c);
            assert!(
                (v - c).abs() < 1e-12 && (d - 1.0).abs() < 1e-9,
                "{c}: {v} {d}"
            );
        }
        assert_eq!(f.eval(-0.2), (0.0, 0.0));
    }

    #[test]
    fn two_separated_colours_make_two_materials_and_one_makes_one() {
        let mut rng = crate::base::rng::Pcg32::new(5, 1);
        let mut blob = |c: [f64; 2], n: usize| -> Vec<[f64; 2]> {
            (0..n)
                .map(|_| {
                    [
                        c[0] + 0.01 * rng.next_normal(),
                        c[1] + 0.01 * rng.next_normal(),
                    ]
                })
                .collect()
        };
        let one = blob([0.4, 0.3], 1000);
        assert_eq!(materials_of(&one).len(), 1);
        let mut two = blob([0.5, 0.3], 600);
        two.extend(blob([0.2, 0.35], 400));
        let mut centers = materials_of(&two);
        centers.sort_by(|a, b| a[0].total_cmp(&b[0]));
        assert_eq!(centers.len(), 2, "{centers:?}");
        assert!(d2(centers[0], [0.2, 0.35]).sqrt() < 0.005, "{centers:?}");
        assert!(d2(centers[1], [0.5, 0.3]).sqrt() < 0.005, "{centers:?}");
    }
}
