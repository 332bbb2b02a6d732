//! The occluding contour: the normals of the mask's outermost pixels where its edge is the
//! object's silhouette.
//!
//! Where a smooth surface turns away from an orthographic camera, its normal is perpendicular
//! to the viewing direction and to the silhouette (n_z = 0, the azimuth the silhouette's
//! outward normal; Ikeuchi & Horn's boundary condition). A pixel on the edge of the mask sees
//! that surface through the lens's blur, which mixes in the readings of the pixel inside it
//! and of the background: its estimate takes the normal of the surface a pixel further in
//! (on DiLiGenT, n_z 0.3 where the truth is 0.1). Photometry cannot undo that mixing; the
//! contour's geometry can.
//!
//! Near the contour, a smooth surface's depth grows as the square root of the distance `d`
//! from it (a circle of curvature radius R: z ≈ √(2 R d)), so its normal's n_z ≈ a √d with
//! a = √(2 / R) (eq. 1). The edge pixels take n_z from eq. 1, with `a` fitted by least squares
//! to the estimates of the pixels one to three steps further in along the silhouette's
//! inward normal, and the silhouette's outward azimuth. An edge pixel keeps its estimate
//! unless the pixels inside it say that the edge is such a contour:
//!
//! - their normals lean outward, within 45° of the silhouette's outward normal, and none has
//!   n_z above 0.78, where eq. 1 leaves a circle's profile by 10%;
//! - pooled over the edge pixels nearby, their n_z rises inward significantly (a flat face
//!   meeting its edge — a coin seen face-on, a plane the mask cuts — is flat up to noise);
//! - pooled the same way, the edge pixels' albedo differs from the inner pixels' by more than
//!   a tenth: they are mixtures (a render sampled at pixel centres mixes nothing);
//! - eq. 1 puts the edge pixel's n_z below its estimate (the blur raises n_z at a contour).
//!
//! The edge of the frame is not a contour: an object the frame cuts keeps its estimates there.
//! Orthographic cameras only (a perspective camera's contour normal is perpendicular to the
//! pixel's ray, not to the optical axis).

use crate::base::stats::f_quantile;

/// Standard deviation of the Gaussian that smooths the mask before its gradient gives the
/// silhouette's normal, pixels: wide enough to average a digitised edge's staircase over a few
/// steps, narrow enough to follow a contour whose curvature radius is a few pixels.
const SMOOTHING_SIGMA_PX: f64 = 2.0;

/// The smoothing window's half-width, pixels (3σ).
const WINDOW_RADIUS: isize = 6;

/// Steps inward, pixels, at which the pixels inside an edge pixel are read.
const STEPS_INWARD: [f64; 3] = [1.0, 2.0, 3.0];

/// The one-sided confidence at which the pooled slope of n_z in √d must be positive.
const RISE_CONFIDENCE: f64 = 0.99;

/// The largest n_z of an inner pixel for eq. 1 to hold: √(2d/R) stays within 10% of a circle's
/// profile √(2d/R − (d/R)²) while d/R ≤ 0.38, n_z ≤ 0.78.
const MAX_INNER_NZ: f64 = 0.78;

/// The albedo ratio of edge to inner pixels beyond which (or beyond its inverse) the edge
/// pixels are mixtures: a pixel whose centre lies uniformly within one pixel of a straight
/// edge is on average 1/8 background by the sensor's own pixel area, before any optical blur;
/// a render sampled at pixel centres, 0.
const MIXTURE_RATIO: f64 = 0.9;

/// Half-width of the square of edge pixels whose residuals decide together, pixels.
const POOLING_RADIUS: isize = 3;

/// The cosine of the largest angle between an inner pixel's normal (its image-plane part) and
/// the silhouette's outward normal for the edge to count as a contour (45°).
const MIN_OUTWARD_COSINE: f64 = std::f64::consts::FRAC_1_SQRT_2;

/// The estimate the stage reads and corrects, per mask pixel in the order of
/// [`MaskFrame::pixels`].
pub struct Estimates<'a> {
    /// Unit normals, camera frame (x right, y up, z toward the camera); the edge pixels' are
    /// replaced.
    pub normals: &'a mut [[f32; 3]],
    /// Albedo, `channels` values a pixel.
    pub albedo: &'a [f32],
    pub channels: usize,
}

/// What the contour stage did, for `report.json`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ContourSummary {
    /// Mask pixels with a 4-neighbour inside the frame and outside the mask.
    pub edge_pixels: usize,
    /// Edge pixels whose normal was replaced by the contour's.
    pub replaced: usize,
}

/// The mask's geometry: its frame, flags and the frame index of each mask pixel (ascending).
pub struct MaskFrame<'a> {
    pub width: usize,
    pub height: usize,
    /// `height * width` flags, row-major.
    pub mask: &'a [bool],
    /// Row-major frame index of each mask pixel, ascending (the order of `normals`).
    pub pixels: &'a [u32],
}

impl MaskFrame<'_> {
    fn inside(&self, x: isize, y: isize) -> bool {
        x >= 0
            && y >= 0
            && (x as usize) < self.width
            && (y as usize) < self.height
            && self.mask[y as usize * self.width + x as usize]
    }

    /// Whether (x, y) is a mask pixel with a 4-neighbour in the frame and outside the mask.
    fn is_edge(&self, x: isize, y: isize) -> bool {
        let in_frame = |x: isize, y: isize| {
            x >= 0 && y >= 0 && (x as usize) < self.width && (y as usize) < self.height
        };
        self.inside(x, y)
            && [(1, 0), (-1, 0), (0, 1), (0, -1)]
                .iter()
                .any(|&(dx, dy)| in_frame(x + dx, y + dy) && !self.inside(x + dx, y + dy))
    }

    fn mask_index(&self, x: isize, y: isize) -> Option<usize> {
        if !self.inside(x, y) {
            return None;
        }
        let i = (y as usize * self.width + x as usize) as u32;
        self.pixels.binary_search(&i).ok()
    }

    /// The Gaussian-smoothed mask at (x, y) and its gradient (image axes: x right, y down);
    /// the frame's edge replicated.
    fn smoothed(&self, x: isize, y: isize) -> (f64, [f64; 2]) {
        let (mut sum, mut gx, mut gy, mut weight) = (0.0, 0.0, 0.0, 0.0);
        let s2 = SMOOTHING_SIGMA_PX * SMOOTHING_SIGMA_PX;
        for dy in -WINDOW_RADIUS..=WINDOW_RADIUS {
            for dx in -WINDOW_RADIUS..=WINDOW_RADIUS {
                let w = (-((dx * dx + dy * dy) as f64) / (2.0 * s2)).exp();
                weight += w;
                let xx = (x + dx).clamp(0, self.width as isize - 1);
                let yy = (y + dy).clamp(0, self.height as isize - 1);
                if self.mask[yy as usize * self.width + xx as usize] {
                    sum += w;
                    // d/dx of Σ G(k) m(p + k) = Σ (k_x / σ²) G(k) m(p + k).
                    gx += w * dx as f64 / s2;
                    gy += w * dy as f64 / s2;
                }
            }
        }
        (sum / weight, [gx / weight, gy / weight])
    }
}

/// Replaces the normals of the mask's edge pixels by the occluding contour's where the pixels
/// inside them say the edge is one (module doc). `normals`: one unit normal per mask pixel, in
/// the order of `frame.pixels` (camera frame: x right, y up, z toward the camera).
pub fn apply(frame: &MaskFrame, estimate: Estimates<'_>) -> ContourSummary {
    let Estimates {
        normals,
        albedo,
        channels,
    } = estimate;
    let mut summary = ContourSummary::default();
    if frame.pixels.len() == frame.width * frame.height {
        return summary;
    }
    // Each edge pixel's fit of eq. 1 to the pixels inside it.
    let mut fits = Vec::new();
    for (k, &i) in frame.pixels.iter().enumerate() {
        let (x, y) = (
            (i as usize % frame.width) as isize,
            (i as usize / frame.width) as isize,
        );
        if !frame.is_edge(x, y) {
            continue;
        }
        summary.edge_pixels += 1;
        if let Some(fit) = contour_fit(frame, normals, (albedo, channels), x, y, k) {
            fits.push((k, x, y, fit));
        }
    }
    // The decision pools the residuals of the edge pixels nearby: one pixel's three inner
    // readings are too few to tell a square root from a constant.
    let at: std::collections::HashMap<(isize, isize), usize> = fits
        .iter()
        .enumerate()
        .map(|(j, f)| ((f.1, f.2), j))
        .collect();
    let r = POOLING_RADIUS;
    let mut replacements = Vec::new();
    for &(k, x, y, ref fit) in &fits {
        let mut pooled = Pooled::default();
        for dy in -r..=r {
            for dx in -r..=r {
                if let Some(&j) = at.get(&(x + dx, y + dy)) {
                    pooled.add(&fits[j].3);
                }
            }
        }
        if pooled.rises() && pooled.mixed() {
            replacements.push((k, fit.normal));
        }
    }
    summary.replaced = replacements.len();
    for (k, n) in replacements {
        normals[k] = n;
    }
    summary
}

/// One edge pixel's contour normal and its inner pixels' n_z against √d, centred on their
/// own means (each edge pixel its own intercept).
struct ContourFit {
    normal: [f32; 3],
    /// Σ (√d − mean)², Σ (√d − mean)(n_z − mean), Σ (n_z − mean)².
    sxx: f64,
    sxy: f64,
    syy: f64,
    /// Inner pixels read.
    count: usize,
    /// The grey albedo of the edge pixel and of its innermost pixel read.
    edge_albedo: f64,
    inner_albedo: f64,
}

/// The edge pixels' fits nearby, pooled: one slope of n_z in √d with an intercept per pixel.
#[derive(Default)]
struct Pooled {
    sxx: f64,
    sxy: f64,
    syy: f64,
    count: usize,
    pixels: usize,
    edge_albedo: f64,
    inner_albedo: f64,
}

impl Pooled {
    fn add(&mut self, fit: &ContourFit) {
        self.sxx += fit.sxx;
        self.sxy += fit.sxy;
        self.syy += fit.syy;
        self.count += fit.count;
        self.pixels += 1;
        self.edge_albedo += fit.edge_albedo;
        self.inner_albedo += fit.inner_albedo;
    }

    /// Whether the edge pixels are mixtures of the object and something else: their albedo
    /// differs from the inner pixels' by more than `MIXTURE_RATIO`.
    fn mixed(&self) -> bool {
        let ratio = self.edge_albedo / self.inner_albedo.max(1e-12);
        !(MIXTURE_RATIO..=1.0 / MIXTURE_RATIO).contains(&ratio)
    }

    /// Whether n_z rises inward significantly: the slope positive and its t statistic beyond
    /// Student's one-sided `RISE_CONFIDENCE` quantile (t² against F(1, dof)). Near a contour
    /// it rises (eq. 1); on a face that meets the edge (a coin seen face-on, a plane the mask
    /// cuts) it is flat up to noise.
    fn rises(&self) -> bool {
        let dof = self.count as f64 - self.pixels as f64 - 1.0;
        if dof < 1.0 || self.sxx <= 0.0 || self.sxy <= 0.0 {
            return false;
        }
        let slope = self.sxy / self.sxx;
        let sse = (self.syy - slope * self.sxy).max(0.0);
        let t2 = slope * slope * self.sxx * dof / sse.max(1e-300);
        t2 > f_quantile(2.0 * RISE_CONFIDENCE - 1.0, 1, dof as usize)
    }
}

/// The contour normal of the edge pixel (x, y), or none where the pixels inside it do not
/// say that the edge is a smooth occluding contour.
fn contour_fit(
    frame: &MaskFrame,
    normals: &[[f32; 3]],
    (albedo, channels): (&[f32], usize),
    x: isize,
    y: isize,
    edge: usize,
) -> Option<ContourFit> {
    let grey = |k: usize| -> f64 {
        albedo[k * channels..(k + 1) * channels]
            .iter()
            .map(|&v| v as f64)
            .sum::<f64>()
            / channels as f64
    };
    let mut inner_albedo = 0.0;
    let (level, gradient) = frame.smoothed(x, y);
    let slope = gradient[0].hypot(gradient[1]);
    if slope < 1e-6 {
        return None;
    }
    // The outward normal in image axes, and the pixel centre's distance inside the contour
    // (the smoothed mask's half level), from the linearised level: pixels.
    let outward = [-gradient[0] / slope, -gradient[1] / slope];
    let depth_inside = ((level - 0.5) / slope).clamp(0.05, 1.0);
    // The outward normal in the camera frame (y up).
    let outward_camera = [outward[0], -outward[1]];
    let mut roots = Vec::with_capacity(STEPS_INWARD.len());
    let mut heights = Vec::with_capacity(STEPS_INWARD.len());
    let mut last = (x, y);
    for step in STEPS_INWARD {
        let qx = (x as f64 - step * outward[0]).round() as isize;
        let qy = (y as f64 - step * outward[1]).round() as isize;
        if (qx, qy) == last {
            continue;
        }
        last = (qx, qy);
        let k = frame.mask_index(qx, qy)?;
        let n = unit(normals[k]);
        inner_albedo = grey(k);
        let lateral = n[0].hypot(n[1]);
        if n[0] * outward_camera[0] + n[1] * outward_camera[1] < MIN_OUTWARD_COSINE * lateral {
            return None;
        }
        // The inner pixel's distance from the contour along the outward normal.
        let d = depth_inside - ((qx - x) as f64 * outward[0] + (qy - y) as f64 * outward[1]);
        roots.push(d.max(0.0).sqrt());
        heights.push(n[2].max(0.0));
    }
    if roots.len() < 2 {
        return None;
    }
    // Eq. 1 by least squares through the origin; the centred sums for the pooled test.
    let a = dot(&roots, &heights) / dot(&roots, &roots);
    let nz = (a * depth_inside.sqrt()).clamp(0.0, 1.0);
    let count = roots.len();
    let (mr, mh) = (
        roots.iter().sum::<f64>() / count as f64,
        heights.iter().sum::<f64>() / count as f64,
    );
    let centred = |u: &[f64], mu: f64, v: &[f64], mv: f64| -> f64 {
        u.iter().zip(v).map(|(p, q)| (p - mu) * (q - mv)).sum()
    };
    let (sxx, sxy, syy) = (
        centred(&roots, mr, &roots, mr),
        centred(&roots, mr, &heights, mh),
        centred(&heights, mh, &heights, mh),
    );
    if heights.iter().any(|&h| h > MAX_INNER_NZ) {
        return None;
    }
    if nz >= unit(normals[edge])[2] {
        return None;
    }
    let lateral = (1.0 - nz * nz).sqrt();
    Some(ContourFit {
        normal: [
            (outward_camera[0] * lateral) as f32,
            (outward_camera[1] * lateral) as f32,
            nz as f32,
        ],
        sxx,
        sxy,
        syy,
        count,
        edge_albedo: grey(edge),
        inner_albedo,
    })
}

fn unit(n: [f32; 3]) -> [f64; 3] {
    let n = [n[0] as f64, n[1] as f64, n[2] as f64];
    let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt().max(1e-12);
    [n[0] / len, n[1] / len, n[2] / len]
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}
