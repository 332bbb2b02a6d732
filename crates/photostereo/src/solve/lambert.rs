//! The Lambertian kernel every estimator, the detector and the recursive driver share: the
//! channel mean, least squares per pixel over any subset of lights (with the 3×3 normal
//! matrices cached per subset), the per-channel albedo with the normal fixed, and the per-light
//! statuses. It sits just above the capture and names no module above it.
//!
//! Image model (ALGORITHMS.md §1): I_kc = ρ_c · max(0, l_k · n) per light k and channel c, with
//! the intensities already divided by the lights' intensities. Normals are unit vectors in the
//! camera frame (x right, y up, z toward the camera); albedo is per channel, in the units of the
//! intensity-normalised images (full scale = 1).

use crate::base::codes2::Codes2;
use crate::base::progress::Progress;
use crate::model::capture::Capture;
use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;
use std::collections::HashMap;

/// Per-pixel results of an estimator, in mask-pixel order (see [`Capture::pixels`]).
#[derive(Clone, Debug, Default)]
pub struct Estimate {
    /// Unit normal per mask pixel; (0, 0, 0) where the normal is undetermined.
    pub normals: Vec<[f32; 3]>,
    /// Albedo per mask pixel and channel (`n_pixels * channels`).
    pub albedo: Vec<f32>,
    /// Per-light status of every mask pixel (`n_pixels * n_lights`, values of [`status`]), when
    /// the estimator decides which lights it used.
    pub light_status: Option<Vec<u8>>,
}

/// Values of `light_status` (CONVENTIONS.md): which lights a pixel's estimate used.
pub mod status {
    /// The light was used.
    pub const USED: u8 = 0;
    /// The pixel is in the light's attached or cast shadow.
    pub const SHADOW: u8 = 1;
    /// The light causes a highlight at the pixel.
    pub const HIGHLIGHT: u8 = 2;
    /// Rejected for another reason.
    pub const REJECTED: u8 = 3;
    /// Outside the mask.
    pub const OUTSIDE: u8 = 255;
}

/// Per-light statuses of every mask pixel, read a pixel at a time: one byte a status
/// (`n_pixels * n_lights`, pixel-major) or 2-bit codes ([`Codes2`], one row a pixel), which
/// hold the four statuses of a mask pixel in a quarter of the bytes.
pub trait Statuses: Sync {
    /// Pixel `p`'s statuses of its `row.len()` lights into `row`, one a byte.
    fn row_into(&self, p: usize, row: &mut [u8]);

    /// Pixel `p`'s usable-light flags (true = [`status::USED`]) of its `used.len()` lights.
    fn used_into(&self, p: usize, used: &mut [bool]);
}

impl Statuses for [u8] {
    #[inline]
    fn row_into(&self, p: usize, row: &mut [u8]) {
        let n = row.len();
        row.copy_from_slice(&self[p * n..(p + 1) * n]);
    }

    #[inline]
    fn used_into(&self, p: usize, used: &mut [bool]) {
        let n = used.len();
        for (u, &st) in used.iter_mut().zip(&self[p * n..(p + 1) * n]) {
            *u = st == status::USED;
        }
    }
}

impl Statuses for Vec<u8> {
    #[inline]
    fn row_into(&self, p: usize, row: &mut [u8]) {
        self.as_slice().row_into(p, row)
    }

    #[inline]
    fn used_into(&self, p: usize, used: &mut [bool]) {
        self.as_slice().used_into(p, used)
    }
}

impl Statuses for Codes2 {
    #[inline]
    fn row_into(&self, p: usize, row: &mut [u8]) {
        self.unpack_row(p, row)
    }

    #[inline]
    fn used_into(&self, p: usize, used: &mut [bool]) {
        let packed = self.row(p);
        for (k, u) in used.iter_mut().enumerate() {
            *u = crate::base::codes2::get_in(packed, k) == status::USED;
        }
    }
}

/// Pixels per parallel work item.
pub const CHUNK: usize = 2048;

/// Solves least squares per pixel over the lights marked usable in `usable`
/// (`n_pixels * n_lights` flags, true = use), or over all lights when `usable` is `None`.
///
/// The normal comes from the channel mean; each channel's albedo is then fitted with that normal
/// fixed. Pixels with fewer than three usable lights, a singular subset or a zero fit get a
/// zero normal and zero albedo.
pub fn solve_subsets(
    capture: &Capture,
    usable: Option<&[bool]>,
    progress: &dyn Progress,
) -> Estimate {
    let n = capture.n_lights();
    let used_at = |p: usize| usable.map(|f| &f[p * n..(p + 1) * n]);
    if let Some(near) = capture.lights.near.as_deref() {
        // Near lights: each pixel's own light vectors at the current surface (ALGORITHMS.md
        // §9), its 3×3 normal matrix formed and solved per pixel.
        let c = capture.channels;
        return solve_per_pixel(
            capture,
            progress,
            || {
                crate::model::lightmodel::PixelLights::new(
                    &capture.lights.directions,
                    Some(near),
                    capture.width,
                )
            },
            |lights, p, samples, grey, out_n, out_a| {
                let used = used_at(p);
                let dirs = lights.at(capture.pixels[p] as usize);
                let m = solve_with(dirs, used, grey)?;
                write_normal_albedo_with(dirs, c, samples, &m, used, out_n, out_a);
                Some(())
            },
        );
    }
    let all = SubsetSolver::all_lights(capture);
    solve_per_pixel(
        capture,
        progress,
        || SubsetCache::new(capture),
        |cache, p, samples, grey, out_n, out_a| {
            let m = match used_at(p) {
                None => all.solve(grey),
                Some(used) => cache.solve(used, grey),
            }?;
            write_normal_albedo(capture, samples, &m, used_at(p), out_n, out_a);
            Some(())
        },
    )
}

/// [`solve_subsets`] with distant lights over the USED lights of `light_status`
/// (`n_pixels * n_lights`), at the mask pixels `ids` only, written into `est` (the other
/// pixels keep their values): each pixel's result is exactly `solve_subsets`'s, so an estimate
/// is brought up to date by re-solving the pixels whose usable lights changed. `capture` must
/// answer `pixel_samples` for `ids` (a [`Capture::sampled`] view of a tiled capture).
///
/// `factors` (one per light, or empty for none): the lights' noise factors c_k of
/// [`crate::solve::detect::NoiseModel::light_factor`]; the normal is then the weighted least-squares
/// fit with weights 1 / c_k² (the albedo fit keeps equal weights).
pub fn resolve_subsets_at(
    capture: &Capture,
    light_status: &(impl Statuses + ?Sized),
    ids: &[usize],
    est: &mut Estimate,
    factors: &[f64],
) {
    debug_assert!(capture.lights.near.is_none());
    let (n, c) = (capture.n_lights(), capture.channels);
    let weighted = factors.len() == n;
    // Weighted least squares is least squares on the vectors and readings divided by c_k.
    let scaled: Vec<[f64; 3]> = capture
        .lights
        .directions
        .iter()
        .enumerate()
        .map(|(k, d)| {
            let f = if weighted { 1.0 / factors[k] } else { 1.0 };
            [d[0] * f, d[1] * f, d[2] * f]
        })
        .collect();
    let parts: Vec<(Vec<[f32; 3]>, Vec<f32>)> = ids
        .par_chunks(CHUNK)
        .map_init(
            || {
                let cache = SubsetCache::with_directions(&scaled);
                (cache, vec![0f64; n], vec![false; n])
            },
            |(cache, grey, used), chunk| {
                let mut normals = vec![[0f32; 3]; chunk.len()];
                let mut albedo = vec![0f32; chunk.len() * c];
                for (j, &p) in chunk.iter().enumerate() {
                    let samples = capture.pixel_samples(p);
                    channel_mean(samples, c, grey);
                    if weighted {
                        for (g, &f) in grey.iter_mut().zip(factors) {
                            *g /= f;
                        }
                    }
                    light_status.used_into(p, used);
                    if let Some(m) = cache.solve(used, grey) {
                        let out_a = &mut albedo[j * c..(j + 1) * c];
                        write_normal_albedo(
                            capture,
                            samples,
                            &m,
                            Some(used),
                            &mut normals[j],
                            out_a,
                        );
                    }
                }
                (normals, albedo)
            },
        )
        .collect();
    for (chunk, (normals, albedo)) in ids.chunks(CHUNK).zip(parts) {
        for (j, &p) in chunk.iter().enumerate() {
            est.normals[p] = normals[j];
            est.albedo[p * c..(p + 1) * c].copy_from_slice(&albedo[j * c..(j + 1) * c]);
        }
    }
}

/// The per-pixel skeleton of the least-squares solvers: rows of pixels in parallel, the channel
/// mean of each pixel's samples, and `solve(state, p, samples, grey, normal, albedo)` writing the
/// pixel's normal and albedo; `None` leaves a zero normal and albedo.
fn solve_per_pixel<S>(
    capture: &Capture,
    progress: &dyn Progress,
    init: impl Fn() -> S + Sync + Send,
    solve: impl Fn(&mut S, usize, &[f32], &[f64], &mut [f32; 3], &mut [f32]) -> Option<()> + Sync + Send,
) -> Estimate {
    let n = capture.n_lights();
    let c = capture.channels;
    let np = capture.n_pixels();
    let mut normals = vec![[0f32; 3]; np];
    let mut albedo = vec![0f32; np * c];
    progress.begin("estimating", np as u64);
    normals
        .par_chunks_mut(CHUNK)
        .zip(albedo.par_chunks_mut(CHUNK * c))
        .enumerate()
        .for_each_init(
            || (init(), vec![0f64; n]),
            |(state, grey), (chunk, (nrm, alb))| {
                let p0 = chunk * CHUNK;
                for (dp, out_n) in nrm.iter_mut().enumerate() {
                    let p = p0 + dp;
                    let samples = capture.pixel_samples(p);
                    channel_mean(samples, c, grey);
                    let out_a = &mut alb[dp * c..(dp + 1) * c];
                    if solve(state, p, samples, grey, out_n, out_a).is_none() {
                        *out_n = [0.0; 3];
                        out_a.fill(0.0);
                    }
                }
                progress.advance(nrm.len() as u64);
            },
        );
    progress.end();
    Estimate {
        normals,
        albedo,
        light_status: None,
    }
}

/// Least squares m = (LᵀL)⁻¹ Lᵀ I over the lights flagged in `used` (all when `None`) with
/// light vectors `dirs` (any length: scaled near-light vectors too); `None` when fewer than
/// three are used or they do not span three dimensions (the test of [`SubsetSolver::new`]).
#[inline]
pub fn solve_with(dirs: &[[f64; 3]], used: Option<&[bool]>, grey: &[f64]) -> Option<Vector3<f64>> {
    let mut g = Matrix3::<f64>::zeros();
    let mut b = Vector3::<f64>::zeros();
    let mut count = 0;
    for (k, d) in dirs.iter().enumerate() {
        if used.is_some_and(|u| !u[k]) {
            continue;
        }
        let v = Vector3::from(*d);
        g += v * v.transpose();
        b += v * grey[k];
        count += 1;
    }
    if count < 3 || !spans_three_dimensions(&g) {
        return None;
    }
    Some(g.try_inverse()? * b)
}

/// Whether the Gram matrix G = Σ l lᵀ of some light vectors has its smallest eigenvalue above
/// 1e-8 times its largest: the lights span three dimensions (not coplanar). The eigenvalues of
/// the symmetric 3×3 matrix in closed form (the trigonometric solution of its characteristic
/// cubic), not by iteration: this runs once per pixel and subset.
#[inline]
pub fn spans_three_dimensions(g: &Matrix3<f64>) -> bool {
    let (min, max) = symmetric_eigen_range(g);
    min > 1e-8 * max
}

/// The smallest and largest eigenvalue of a symmetric 3×3 matrix, in closed form.
fn symmetric_eigen_range(a: &Matrix3<f64>) -> (f64, f64) {
    let off = a[(0, 1)] * a[(0, 1)] + a[(0, 2)] * a[(0, 2)] + a[(1, 2)] * a[(1, 2)];
    let q = (a[(0, 0)] + a[(1, 1)] + a[(2, 2)]) / 3.0;
    let d = [a[(0, 0)] - q, a[(1, 1)] - q, a[(2, 2)] - q];
    let p2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2] + 2.0 * off;
    if p2 <= 0.0 {
        // A multiple of the identity.
        return (q, q);
    }
    let p = (p2 / 6.0).sqrt();
    // B = (A − q I) / p; r = det(B) / 2 lies in [−1, 1] up to rounding.
    let b = (a - Matrix3::identity() * q) / p;
    let r = (b.determinant() / 2.0).clamp(-1.0, 1.0);
    let phi = r.acos() / 3.0;
    let largest = q + 2.0 * p * phi.cos();
    let smallest = q + 2.0 * p * (phi + 2.0 * std::f64::consts::FRAC_PI_3).cos();
    (smallest, largest)
}

/// Mean over channels of each light's sample, into `grey` (length N).
#[inline]
pub fn channel_mean(samples: &[f32], channels: usize, grey: &mut [f64]) {
    if channels == 1 {
        for (g, s) in grey.iter_mut().zip(samples) {
            *g = *s as f64;
        }
    } else {
        let inv = 1.0 / channels as f64;
        for (g, px) in grey.iter_mut().zip(samples.chunks_exact(channels)) {
            *g = px.iter().map(|&v| v as f64).sum::<f64>() * inv;
        }
    }
}

/// From the scaled normal m = ρ n: writes n and the per-channel albedo fitted with n fixed
/// (ρ_c = Σ s_k I_kc / Σ s_k², s_k = l_k · n, over the used lights).
#[inline]
pub fn write_normal_albedo(
    capture: &Capture,
    samples: &[f32],
    m: &Vector3<f64>,
    used: Option<&[bool]>,
    out_n: &mut [f32; 3],
    out_a: &mut [f32],
) {
    write_normal_albedo_with(
        &capture.lights.directions,
        capture.channels,
        samples,
        m,
        used,
        out_n,
        out_a,
    )
}

/// [`write_normal_albedo`] with explicit light vectors `dirs` (a pixel's own near-light
/// vectors, or the distant directions) and channel count `c`.
#[inline]
pub fn write_normal_albedo_with(
    dirs: &[[f64; 3]],
    c: usize,
    samples: &[f32],
    m: &Vector3<f64>,
    used: Option<&[bool]>,
    out_n: &mut [f32; 3],
    out_a: &mut [f32],
) {
    let rho = m.norm();
    if rho.is_nan() || rho <= 1e-12 || !rho.is_finite() {
        *out_n = [0.0; 3];
        out_a.fill(0.0);
        return;
    }
    let nrm = m / rho;
    *out_n = [nrm.x as f32, nrm.y as f32, nrm.z as f32];
    let mut num = [0f64; 3];
    let mut den = 0f64;
    for (k, d) in dirs.iter().enumerate() {
        if let Some(u) = used {
            if !u[k] {
                continue;
            }
        }
        let s = d[0] * nrm.x + d[1] * nrm.y + d[2] * nrm.z;
        den += s * s;
        for ch in 0..c {
            num[ch] += s * samples[k * c + ch] as f64;
        }
    }
    for ch in 0..c {
        out_a[ch] = if den > 0.0 {
            (num[ch] / den) as f32
        } else {
            0.0
        };
    }
}

/// Least squares over a fixed set of lights: m = (LᵀL)⁻¹ Lᵀ I with the pseudo-inverse cached.
#[derive(Clone, Debug)]
pub struct SubsetSolver {
    /// 3 × N pseudo-inverse, row-major; zero columns for unused lights.
    pinv: Vec<[f64; 3]>,
}

impl SubsetSolver {
    /// The solver for all lights of the capture.
    pub fn all_lights(capture: &Capture) -> Self {
        let used = vec![true; capture.n_lights()];
        Self::new(&capture.lights.directions, &used)
            .expect("capture lights were checked to have rank 3")
    }

    /// The solver for the lights flagged in `used`; `None` when fewer than three are used or
    /// they do not span three dimensions.
    pub fn new(directions: &[[f64; 3]], used: &[bool]) -> Option<Self> {
        let mut g = Matrix3::<f64>::zeros();
        let mut count = 0;
        for (d, &u) in directions.iter().zip(used) {
            if u {
                let v = Vector3::from(*d);
                g += v * v.transpose();
                count += 1;
            }
        }
        // Refuse subsets whose smallest eigenvalue is negligible (coplanar lights).
        if count < 3 || !spans_three_dimensions(&g) {
            return None;
        }
        let inv = g.try_inverse()?;
        let pinv = directions
            .iter()
            .zip(used)
            .map(|(d, &u)| {
                if u {
                    let v = inv * Vector3::from(*d);
                    [v.x, v.y, v.z]
                } else {
                    [0.0; 3]
                }
            })
            .collect();
        Some(SubsetSolver { pinv })
    }

    /// The scaled normal m = ρ n for intensities `grey` (one per light).
    #[inline]
    pub fn solve(&self, grey: &[f64]) -> Option<Vector3<f64>> {
        let mut m = [0f64; 3];
        for (p, &i) in self.pinv.iter().zip(grey) {
            m[0] += p[0] * i;
            m[1] += p[1] * i;
            m[2] += p[2] * i;
        }
        Some(Vector3::new(m[0], m[1], m[2]))
    }
}

/// Per-thread cache of [`SubsetSolver`]s keyed by the set of usable lights.
pub struct SubsetCache<'a> {
    directions: &'a [[f64; 3]],
    map: HashMap<Vec<u64>, Option<SubsetSolver>>,
    key: Vec<u64>,
}

impl<'a> SubsetCache<'a> {
    /// An empty cache for the capture's lights.
    pub fn new(capture: &'a Capture) -> Self {
        Self::with_directions(&capture.lights.directions)
    }

    /// An empty cache for the light vectors `directions` (e.g. divided by per-light factors).
    pub fn with_directions(directions: &'a [[f64; 3]]) -> Self {
        SubsetCache {
            directions,
            map: HashMap::new(),
            key: vec![0; directions.len().div_ceil(64)],
        }
    }

    /// Least squares over the lights flagged in `used`; `None` if the subset cannot determine a
    /// normal.
    pub fn solve(&mut self, used: &[bool], grey: &[f64]) -> Option<Vector3<f64>> {
        self.key.fill(0);
        for (k, &u) in used.iter().enumerate() {
            if u {
                self.key[k / 64] |= 1 << (k % 64);
            }
        }
        if let Some(s) = self.map.get(&self.key) {
            return s.as_ref()?.solve(grey);
        }
        // Bounded cache: many distinct subsets (rare) fall back to solving without caching.
        let solver = SubsetSolver::new(self.directions, used);
        let result = solver.as_ref().and_then(|s| s.solve(grey));
        if self.map.len() < 4096 {
            self.map.insert(self.key.clone(), solver);
        }
        result
    }
}

/// Usable-light flags (true = [`status::USED`]) from per-light statuses.
pub fn usable(light_status: &[u8]) -> Vec<bool> {
    light_status.iter().map(|&s| s == status::USED).collect()
}

/// Usable-light flags of the mask pixels `range` (`range.len() * n` flags) from statuses of
/// `n` lights per pixel.
pub fn usable_of(
    light_status: &(impl Statuses + ?Sized),
    range: std::ops::Range<usize>,
    n: usize,
) -> Vec<bool> {
    let mut flags = vec![false; range.len() * n];
    if n > 0 {
        flags
            .par_chunks_mut(n)
            .zip(range)
            .for_each(|(used, p)| light_status.used_into(p, used));
    }
    flags
}

/// What a method's "shadow" labels mean, measured against its own Lambertian fit: of the
/// (pixel, light) pairs labelled [`status::SHADOW`], the share that face away from the light
/// (n · l ≤ 0 with the final normal) and the share that read more than half of the prediction
/// ρ · n · l (grey albedo and normal of the estimate) — lit readings a shadow label should not
/// have taken.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct ShadowLabels {
    /// Pairs labelled shadow.
    pub pairs: usize,
    /// Share of all (pixel, light) pairs labelled shadow.
    pub share_of_all: f64,
    /// Share of the shadow pairs with n · l ≤ 0.
    pub facing_away: f64,
    /// Share of the shadow pairs reading more than half of the Lambertian prediction.
    pub lit: f64,
}

/// [`ShadowLabels`] of an estimate with per-light statuses (`light_status`, per mask pixel).
pub fn shadow_labels(capture: &Capture, est: &Estimate, light_status: &[u8]) -> ShadowLabels {
    let counts = shadow_label_counts(capture, est, light_status);
    ShadowLabels::from_counts(counts, capture.n_lights(), capture.n_pixels())
}

impl ShadowLabels {
    /// From the counts of [`shadow_label_counts`] over `n_pixels` pixels and `n` lights.
    pub fn from_counts(
        (pairs, away, lit): (usize, usize, usize),
        n: usize,
        n_pixels: usize,
    ) -> Self {
        let d = pairs.max(1) as f64;
        ShadowLabels {
            pairs,
            share_of_all: pairs as f64 / (n * n_pixels).max(1) as f64,
            facing_away: away as f64 / d,
            lit: lit as f64 / d,
        }
    }
}

/// The counts behind [`shadow_labels`]: shadow pairs, those facing away from the light, those
/// reading more than half of the Lambertian prediction.
pub fn shadow_label_counts(
    capture: &Capture,
    est: &Estimate,
    light_status: &[u8],
) -> (usize, usize, usize) {
    let n = capture.n_lights();
    let c = capture.channels;
    (0..capture.n_pixels())
        .into_par_iter()
        .map_init(
            || vec![0f64; n],
            |grey, p| {
                let st = &light_status[p * n..(p + 1) * n];
                if !st.contains(&status::SHADOW) {
                    return (0usize, 0usize, 0usize);
                }
                channel_mean(capture.pixel_samples(p), c, grey);
                let nrm = est.normals[p];
                let rho = est.albedo[p * c..(p + 1) * c].iter().sum::<f32>() as f64 / c as f64;
                let (mut pairs, mut away, mut lit) = (0, 0, 0);
                for (k, l) in capture.lights.directions.iter().enumerate() {
                    if st[k] != status::SHADOW {
                        continue;
                    }
                    pairs += 1;
                    let s = l[0] * nrm[0] as f64 + l[1] * nrm[1] as f64 + l[2] * nrm[2] as f64;
                    if s <= 0.0 {
                        away += 1;
                    } else if grey[k] > 0.5 * rho * s {
                        lit += 1;
                    }
                }
                (pairs, away, lit)
            },
        )
        .reduce(|| (0, 0, 0), |a, b| (a.0 + b.0, a.1 + b.1, a.2 + b.2))
}

#[cfg(test)]
mod eigen_tests {
    use super::*;

    /// The closed-form eigenvalue range agrees with nalgebra's iterative solver on Gram matrices
    /// of random light sets (3 to 12 lights), of coplanar sets (rank 2) and of nearly coplanar
    /// ones, and the coplanarity verdict is the same.
    #[test]
    fn closed_form_eigenvalues_match_the_iterative_solver() {
        let mut rng = crate::base::rng::Pcg32::new(11, 3);
        let mut unit = |z_scale: f64| {
            let v = [
                rng.next_normal(),
                rng.next_normal(),
                rng.next_normal() * z_scale,
            ];
            let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            [v[0] / n, v[1] / n, v[2] / n]
        };
        let mut checked = 0;
        for case in 0..3000 {
            let count = 3 + case % 10;
            // Every third set is coplanar (z = 0) or nearly so.
            let z_scale = match case % 3 {
                0 => 1.0,
                1 => 0.0,
                _ => 1e-5,
            };
            let dirs: Vec<[f64; 3]> = (0..count).map(|_| unit(z_scale)).collect();
            let mut g = Matrix3::<f64>::zeros();
            for d in &dirs {
                let v = Vector3::from(*d);
                g += v * v.transpose();
            }
            let eig = nalgebra::SymmetricEigen::new(g).eigenvalues;
            let (min, max) = symmetric_eigen_range(&g);
            assert!(
                (max - eig.max()).abs() <= 1e-12 * eig.max(),
                "{max} vs {eig}"
            );
            assert!(
                (min - eig.min()).abs() <= 1e-12 * eig.max(),
                "{min} vs {eig}"
            );
            assert_eq!(
                spans_three_dimensions(&g),
                eig.min() > 1e-8 * eig.max(),
                "case {case}: {eig}"
            );
            checked += 1;
        }
        assert_eq!(checked, 3000);
        // Multiples of the identity.
        let (min, max) = symmetric_eigen_range(&(Matrix3::identity() * 2.5));
        assert_eq!((min, max), (2.5, 2.5));
    }
}
