//! The sphere's outline: circle fits to boundary points (algebraic least squares refined
//! geometrically), the outline of a binary mask, and the automatic detection of a sphere from
//! the brightest values of its images.
//!
//! Image coordinates: `x` = column, `y` = row (row 0 at the top), in pixels, with the centre of
//! pixel (col, row) at (col, row).

use crate::base::error::{Error, Result};
use crate::model::image::Image;
use nalgebra::{Matrix3, Vector3};

/// A circle in image coordinates (pixels; `cx` = column, `cy` = row of the centre).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Circle {
    /// Column of the centre, pixels.
    pub cx: f64,
    /// Row of the centre, pixels (row 0 at the top).
    pub cy: f64,
    /// Radius, pixels.
    pub r: f64,
}

impl Circle {
    /// The sphere's unit normal (camera frame: x right, y up, z toward the camera) seen at image
    /// point (x = column, y = row), for an orthographic view; `None` outside the outline.
    pub fn normal_at(&self, x: f64, y: f64) -> Option<[f64; 3]> {
        let nx = (x - self.cx) / self.r;
        let ny = (self.cy - y) / self.r;
        let s = nx * nx + ny * ny;
        if s > 1.0 {
            None
        } else {
            Some([nx, ny, (1.0 - s).sqrt()])
        }
    }
}

/// A circle fitted to boundary points, with the quality figures of the fit.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct CircleFit {
    /// The fitted circle.
    pub circle: Circle,
    /// Root-mean-square distance of the boundary points to the circle, pixels.
    pub rms_residual_px: f64,
    /// Largest distance of a boundary point to the circle, pixels.
    pub max_residual_px: f64,
    /// Number of boundary points used.
    pub points: usize,
    /// Share of the circumference (in 10° sectors) that carries boundary points, 0..1.
    pub coverage: f64,
    /// Whether the region touches the image border (its outline is cut there).
    pub touches_frame: bool,
}

/// Fits a circle to points (x, y): Kåsa's algebraic least squares, then Gauss–Newton on the
/// geometric distances. Needs at least three non-collinear points.
pub fn fit_circle(points: &[[f64; 2]]) -> Result<CircleFit> {
    if points.len() < 3 {
        return Err(Error::invalid(format!(
            "{} boundary point(s): a circle fit needs at least three",
            points.len()
        )));
    }
    let n = points.len() as f64;
    let (mx, my) = points
        .iter()
        .fold((0.0, 0.0), |(a, b), p| (a + p[0], b + p[1]));
    let (mx, my) = (mx / n, my / n);
    // Algebraic fit on centred coordinates: u² + v² + D u + E v + F = 0.
    let mut ata = Matrix3::<f64>::zeros();
    let mut atb = Vector3::<f64>::zeros();
    for p in points {
        let (u, v) = (p[0] - mx, p[1] - my);
        let row = Vector3::new(u, v, 1.0);
        ata += row * row.transpose();
        atb -= row * (u * u + v * v);
    }
    let sol = ata
        .lu()
        .solve(&atb)
        .ok_or_else(|| Error::invalid("boundary points are collinear: no circle fits them"))?;
    let (mut cx, mut cy) = (-sol.x / 2.0, -sol.y / 2.0);
    let r2 = cx * cx + cy * cy - sol.z;
    if r2.is_nan() || r2 <= 0.0 {
        return Err(Error::invalid("boundary points do not describe a circle"));
    }
    let mut r = r2.sqrt();
    // Geometric refinement: minimise Σ (|p − c| − r)².
    for _ in 0..50 {
        let mut jtj = Matrix3::<f64>::zeros();
        let mut jtr = Vector3::<f64>::zeros();
        for p in points {
            let (dx, dy) = (p[0] - mx - cx, p[1] - my - cy);
            let d = (dx * dx + dy * dy).sqrt().max(1e-12);
            let res = d - r;
            let j = Vector3::new(-dx / d, -dy / d, -1.0);
            jtj += j * j.transpose();
            jtr += j * res;
        }
        let Some(step) = jtj.lu().solve(&(-jtr)) else {
            break;
        };
        cx += step.x;
        cy += step.y;
        r += step.z;
        if step.norm() < 1e-9 {
            break;
        }
    }
    if r.is_nan() || r <= 0.0 || !cx.is_finite() || !cy.is_finite() {
        return Err(Error::invalid("the circle fit did not converge"));
    }
    let circle = Circle {
        cx: cx + mx,
        cy: cy + my,
        r,
    };
    let mut sum2 = 0.0;
    let mut max = 0.0f64;
    let mut sectors = [false; 36];
    for p in points {
        let (dx, dy) = (p[0] - circle.cx, p[1] - circle.cy);
        let e = (dx * dx + dy * dy).sqrt() - circle.r;
        sum2 += e * e;
        max = max.max(e.abs());
        let a = dy.atan2(dx).to_degrees().rem_euclid(360.0);
        sectors[((a / 10.0) as usize).min(35)] = true;
    }
    Ok(CircleFit {
        circle,
        rms_residual_px: (sum2 / n).sqrt(),
        max_residual_px: max,
        points: points.len(),
        coverage: sectors.iter().filter(|&&s| s).count() as f64 / 36.0,
        touches_frame: false,
    })
}

/// The largest 8-connected region of `mask` (`height * width`, row-major) with its holes filled.
/// Returns the region and how many other regions were dropped.
pub fn largest_region(mask: &[bool], width: usize, height: usize) -> (Vec<bool>, usize) {
    let labels = label_regions(mask, width, height, true);
    let mut sizes = vec![0usize; labels.count + 1];
    for &l in &labels.labels {
        if l > 0 {
            sizes[l as usize] += 1;
        }
    }
    let best = (1..sizes.len()).max_by_key(|&l| sizes[l]).unwrap_or(0);
    let mut region: Vec<bool> = labels
        .labels
        .iter()
        .map(|&l| best > 0 && l as usize == best)
        .collect();
    fill_holes(&mut region, width, height);
    (region, labels.count.saturating_sub(1))
}

/// Connected-component labels (0 = background, 1..=count).
pub(crate) struct Labels {
    pub labels: Vec<u32>,
    pub count: usize,
}

/// Labels the connected regions of `mask` (8-connected when `eight`, else 4-connected).
pub(crate) fn label_regions(mask: &[bool], width: usize, height: usize, eight: bool) -> Labels {
    let mut labels = vec![0u32; width * height];
    let mut count = 0usize;
    let mut stack: Vec<usize> = Vec::new();
    for start in 0..width * height {
        if !mask[start] || labels[start] != 0 {
            continue;
        }
        count += 1;
        labels[start] = count as u32;
        stack.push(start);
        while let Some(i) = stack.pop() {
            let (r, c) = ((i / width) as isize, (i % width) as isize);
            for dr in -1isize..=1 {
                for dc in -1isize..=1 {
                    if (dr == 0 && dc == 0) || (!eight && dr != 0 && dc != 0) {
                        continue;
                    }
                    let (rr, cc) = (r + dr, c + dc);
                    if rr < 0 || cc < 0 || rr >= height as isize || cc >= width as isize {
                        continue;
                    }
                    let j = rr as usize * width + cc as usize;
                    if mask[j] && labels[j] == 0 {
                        labels[j] = count as u32;
                        stack.push(j);
                    }
                }
            }
        }
    }
    Labels { labels, count }
}

/// Sets every background pixel not 4-connected to the image border.
fn fill_holes(mask: &mut [bool], width: usize, height: usize) {
    let mut outside = vec![false; width * height];
    let mut stack: Vec<usize> = Vec::new();
    for i in 0..width * height {
        let (r, c) = (i / width, i % width);
        let border = r == 0 || c == 0 || r + 1 == height || c + 1 == width;
        if border && !mask[i] {
            outside[i] = true;
            stack.push(i);
        }
    }
    while let Some(i) = stack.pop() {
        let (r, c) = (i / width, i % width);
        let mut visit = |j: usize| {
            if !mask[j] && !outside[j] {
                outside[j] = true;
                stack.push(j);
            }
        };
        if r > 0 {
            visit(i - width);
        }
        if r + 1 < height {
            visit(i + width);
        }
        if c > 0 {
            visit(i - 1);
        }
        if c + 1 < width {
            visit(i + 1);
        }
    }
    for (m, o) in mask.iter_mut().zip(&outside) {
        if !o {
            *m = true;
        }
    }
}

/// The outline of a region as sub-pixel points: the midpoint between every pair of 4-adjacent
/// pixels of which one is inside and one outside. Also says whether the region touches the
/// image border (where its outline is not seen).
pub fn region_outline(mask: &[bool], width: usize, height: usize) -> (Vec<[f64; 2]>, bool) {
    let mut points = Vec::new();
    let mut touches = false;
    for r in 0..height {
        for c in 0..width {
            let i = r * width + c;
            if mask[i] && (r == 0 || c == 0 || r + 1 == height || c + 1 == width) {
                touches = true;
            }
            if c + 1 < width && mask[i] != mask[i + 1] {
                points.push([c as f64 + 0.5, r as f64]);
            }
            if r + 1 < height && mask[i] != mask[i + width] {
                points.push([c as f64, r as f64 + 0.5]);
            }
        }
    }
    (points, touches)
}

/// Largest RMS distance of the outline to the fitted circle accepted as "circular", as a share
/// of the radius (with a floor of [`MAX_RMS_RESIDUAL_FLOOR_PX`]).
pub const MAX_RMS_RESIDUAL_SHARE: f64 = 0.02;
/// Floor of the accepted RMS residual, pixels (a digitised circle has about 0.3 px).
pub const MAX_RMS_RESIDUAL_FLOOR_PX: f64 = 1.0;
/// Smallest sphere radius accepted, pixels.
pub const MIN_RADIUS_PX: f64 = 8.0;

/// Fits the sphere's circle to the outline of the largest region of `mask`. `what` names the
/// mask in errors (a file name or "the detected sphere"). Errors when the region is empty, too
/// small, not circular, or cut by the image border over more than half its circumference.
pub fn fit_mask_circle(
    mask: &[bool],
    width: usize,
    height: usize,
    what: &str,
) -> Result<CircleFit> {
    if mask.len() != width * height {
        return Err(Error::invalid(format!(
            "{what}: {} mask pixels for a {width}×{height} image",
            mask.len()
        )));
    }
    let (region, _dropped) = largest_region(mask, width, height);
    let area = region.iter().filter(|&&m| m).count();
    if area == 0 {
        return Err(Error::invalid(format!("{what}: the mask is empty")));
    }
    let (points, touches) = region_outline(&region, width, height);
    let mut fit = fit_circle(&points).map_err(|e| Error::invalid(format!("{what}: {e}")))?;
    fit.touches_frame = touches;
    let c = fit.circle;
    if c.r < MIN_RADIUS_PX {
        return Err(Error::invalid(format!(
            "{what}: the sphere's radius is {:.1} px; at least {MIN_RADIUS_PX} px is needed",
            c.r
        )));
    }
    if fit.coverage < 0.5 {
        return Err(Error::invalid(format!(
            "{what}: only {:.0}% of the sphere's outline is inside the image (it touches the frame); \
             at least half is needed to fit its circle — reframe so the whole sphere is visible",
            100.0 * fit.coverage
        )));
    }
    let limit = (MAX_RMS_RESIDUAL_SHARE * c.r).max(MAX_RMS_RESIDUAL_FLOOR_PX);
    if fit.rms_residual_px > limit {
        return Err(Error::invalid(format!(
            "{what}: the mask is not circular: its outline is {:.2} px RMS (up to {:.1} px) away \
             from the best circle (centre ({:.1}, {:.1}), radius {:.1} px); at most {:.2} px expected",
            fit.rms_residual_px, fit.max_residual_px, c.cx, c.cy, c.r, limit
        )));
    }
    // Compare the area inside the frame with the circle's: a ring or a crescent fits a circle
    // by its outline but not by its area.
    let mut inside_circle = 0usize;
    for r in 0..height {
        let dy = r as f64 - c.cy;
        for col in 0..width {
            let dx = col as f64 - c.cx;
            if dx * dx + dy * dy <= c.r * c.r {
                inside_circle += 1;
            }
        }
    }
    let ratio = area as f64 / inside_circle.max(1) as f64;
    if (ratio - 1.0).abs() > 0.05 {
        return Err(Error::invalid(format!(
            "{what}: the mask is not a filled disc: it covers {:.0}% of its fitted circle's area",
            100.0 * ratio
        )));
    }
    Ok(fit)
}

/// Detects the sphere when no mask is given: the per-pixel maximum over the images (grey),
/// clipped at its 95th percentile so that highlights do not set the scale, an Otsu threshold,
/// the largest region, holes filled, and a circle fit to its outline. Returns the region (as a
/// mask) and its fit. Works when the sphere is brighter than its surroundings in some image
/// (a matte sphere, or a mirror sphere reflecting a lit room); otherwise pass a mask.
pub fn detect_sphere(images: &[Image]) -> Result<(Vec<bool>, CircleFit)> {
    let first = images
        .first()
        .ok_or_else(|| Error::invalid("no image to detect the sphere in"))?;
    let (w, h) = (first.width, first.height);
    let mut max = vec![0f32; w * h];
    for img in images {
        for (i, m) in max.iter_mut().enumerate() {
            let v = grey_at(img, i);
            if v > *m {
                *m = v;
            }
        }
    }
    let mut sorted = max.clone();
    let at = ((sorted.len() as f64 * 0.95) as usize).min(sorted.len() - 1);
    let (_, p95, _) = sorted.select_nth_unstable_by(at, |a, b| a.total_cmp(b));
    let scale = p95.max(1e-6);
    let scaled: Vec<f32> = max.iter().map(|v| (v / scale).min(1.0)).collect();
    let t = otsu_threshold(&scaled);
    let mask: Vec<bool> = scaled.iter().map(|&v| v > t).collect();
    let (region, _) = largest_region(&mask, w, h);
    let fail = |m: String| {
        Error::invalid(format!(
            "could not detect the sphere automatically ({m}); pass --mask with the sphere's mask"
        ))
    };
    let (points, touches) = region_outline(&region, w, h);
    if points.len() < 3 {
        return Err(fail(
            "the brightest region has no outline inside the image: it is the background, not \
             the sphere"
                .into(),
        ));
    }
    // Robust fit: the bright region may include a stand or clutter touching the sphere.
    let (mut fit, inliers) = fit_circle_trimmed(&points).map_err(|e| fail(e.to_string()))?;
    fit.touches_frame = touches;
    let c = fit.circle;
    if c.r < MIN_RADIUS_PX {
        return Err(fail(format!(
            "the brightest region's radius is {:.1} px",
            c.r
        )));
    }
    if inliers < 0.6 {
        return Err(fail(format!(
            "only {:.0}% of the brightest region's outline lies on a circle",
            100.0 * inliers
        )));
    }
    if fit.coverage < 0.5 {
        return Err(fail(format!(
            "the brightest region fits a circle (centre ({:.0}, {:.0}), radius {:.0} px) only {:.0}% \
             of whose outline is inside the image: either the sphere is cut by the frame, or the \
             brightest region is not the sphere (a lit background)",
            c.cx,
            c.cy,
            c.r,
            100.0 * fit.coverage
        )));
    }
    let (mut inside, mut covered) = (0usize, 0usize);
    for r in 0..h {
        for col in 0..w {
            if (col as f64 - c.cx).powi(2) + (r as f64 - c.cy).powi(2) <= c.r * c.r {
                inside += 1;
                covered += region[r * w + col] as usize;
            }
        }
    }
    if (covered as f64) < 0.9 * inside as f64 {
        return Err(fail(format!(
            "the brightest region covers only {:.0}% of its circle",
            100.0 * covered as f64 / inside.max(1) as f64
        )));
    }
    let fit = refine_on_edges(&max, w, h, &fit).unwrap_or(fit);
    Ok((region, fit))
}

/// Fits a circle, then refits twice without the points farther than three robust standard
/// deviations (+1 px) from it. Returns the fit (its figures over the kept points) and the share
/// of points kept.
pub fn fit_circle_trimmed(points: &[[f64; 2]]) -> Result<(CircleFit, f64)> {
    let mut fit = fit_circle(points)?;
    let mut kept: Vec<[f64; 2]> = points.to_vec();
    for _ in 0..3 {
        let c = fit.circle;
        let res: Vec<f64> = points
            .iter()
            .map(|p| ((p[0] - c.cx).hypot(p[1] - c.cy) - c.r).abs())
            .collect();
        let mut sorted = res.clone();
        let mid = sorted.len() / 2;
        let (_, mad, _) = sorted.select_nth_unstable_by(mid, |a, b| a.total_cmp(b));
        let limit = 3.0 * 1.4826 * *mad + 1.0;
        kept = points
            .iter()
            .zip(&res)
            .filter(|(_, r)| **r <= limit)
            .map(|(p, _)| *p)
            .collect();
        fit = fit_circle(&kept)?;
    }
    Ok((fit, kept.len() as f64 / points.len().max(1) as f64))
}

/// Refines a circle on the image's edge: along 720 radial profiles within ±6 px of the circle,
/// the steepest descent (inside brighter than outside) located to a quarter pixel with a
/// parabola; a circle fitted to those points, then refitted without the points farther than
/// three robust standard deviations (highlights near the rim, clutter). `None` when fewer than
/// half the profiles give an edge or the refined circle moved by more than 3 px.
fn refine_on_edges(values: &[f32], w: usize, h: usize, fit: &CircleFit) -> Option<CircleFit> {
    let c = fit.circle;
    let sample = |x: f64, y: f64| -> Option<f64> {
        if x < 0.0 || y < 0.0 || x > (w - 1) as f64 || y > (h - 1) as f64 {
            return None;
        }
        let (x0, y0) = (x.floor() as usize, y.floor() as usize);
        let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
        let (fx, fy) = (x - x0 as f64, y - y0 as f64);
        let v = |xx: usize, yy: usize| values[yy * w + xx] as f64;
        Some(
            (1.0 - fy) * ((1.0 - fx) * v(x0, y0) + fx * v(x1, y0))
                + fy * ((1.0 - fx) * v(x0, y1) + fx * v(x1, y1)),
        )
    };
    const STEPS: usize = 49; // −6..=6 px in quarter pixels
    let mut points = Vec::new();
    let mut profile = [0f64; STEPS];
    'angles: for k in 0..720 {
        let a = k as f64 * std::f64::consts::TAU / 720.0;
        let (ca, sa) = (a.cos(), a.sin());
        for (i, p) in profile.iter_mut().enumerate() {
            let s = c.r - 6.0 + 0.25 * i as f64;
            match sample(c.cx + s * ca, c.cy + s * sa) {
                Some(v) => *p = v,
                None => continue 'angles,
            }
        }
        // Descent over one pixel (4 quarter steps): d[i] = p[i − 2] − p[i + 2].
        let mut best = (0usize, 0f64);
        for i in 2..STEPS - 2 {
            let d = profile[i - 2] - profile[i + 2];
            if d > best.1 {
                best = (i, d);
            }
        }
        let i = best.0;
        if best.1 <= 0.0 || !(3..=STEPS - 4).contains(&i) {
            continue;
        }
        let (dm, d0, dp) = (
            profile[i - 3] - profile[i + 1],
            best.1,
            profile[i - 1] - profile[i + 3],
        );
        let denom = dm - 2.0 * d0 + dp;
        let off = if denom < 0.0 {
            (0.5 * (dm - dp) / denom).clamp(-0.5, 0.5)
        } else {
            0.0
        };
        let s = c.r - 6.0 + 0.25 * (i as f64 + off);
        points.push([c.cx + s * ca, c.cy + s * sa]);
    }
    if points.len() < 360 {
        return None;
    }
    let first = fit_circle(&points).ok()?;
    let mut res: Vec<f64> = points
        .iter()
        .map(|p| ((p[0] - first.circle.cx).hypot(p[1] - first.circle.cy) - first.circle.r).abs())
        .collect();
    let mut sorted = res.clone();
    let mid = sorted.len() / 2;
    let (_, mad, _) = sorted.select_nth_unstable_by(mid, |a, b| a.total_cmp(b));
    let limit = 3.0 * 1.4826 * *mad + 0.25;
    let kept: Vec<[f64; 2]> = points
        .iter()
        .zip(res.iter_mut())
        .filter(|(_, r)| **r <= limit)
        .map(|(p, _)| *p)
        .collect();
    let mut refined = fit_circle(&kept).ok()?;
    let moved =
        (refined.circle.cx - c.cx).hypot(refined.circle.cy - c.cy) + (refined.circle.r - c.r).abs();
    if moved > 3.0 {
        return None;
    }
    refined.touches_frame = fit.touches_frame;
    refined.coverage = refined.coverage.min(fit.coverage);
    Some(refined)
}

/// Grey value (mean over channels) of flat pixel `i`.
#[inline]
pub(crate) fn grey_at(img: &Image, i: usize) -> f32 {
    let c = img.channels;
    let px = &img.data[i * c..(i + 1) * c];
    px.iter().sum::<f32>() / c as f32
}

/// Otsu's threshold of values in [0, 1] (256 bins); values above it are foreground.
fn otsu_threshold(values: &[f32]) -> f32 {
    let mut hist = [0u64; 256];
    for &v in values {
        let b = (v.clamp(0.0, 1.0) * 255.0).round() as usize;
        hist[b] += 1;
    }
    let total = values.len() as f64;
    let sum_all: f64 = hist
        .iter()
        .enumerate()
        .map(|(i, &n)| i as f64 * n as f64)
        .sum();
    let (mut w0, mut sum0) = (0.0, 0.0);
    let (mut best, mut best_t) = (-1.0, 0usize);
    for (t, &n) in hist.iter().enumerate() {
        w0 += n as f64;
        sum0 += t as f64 * n as f64;
        let w1 = total - w0;
        if w0 == 0.0 || w1 == 0.0 {
            continue;
        }
        let m0 = sum0 / w0;
        let m1 = (sum_all - sum0) / w1;
        let between = w0 * w1 * (m0 - m1) * (m0 - m1);
        if between > best {
            best = between;
            best_t = t;
        }
    }
    (best_t as f32 + 0.5) / 255.0
}

#[cfg(test)]
mod tests {
    use super::*;

    fn disc(w: usize, h: usize, c: Circle) -> Vec<bool> {
        (0..w * h)
            .map(|i| {
                let (r, col) = ((i / w) as f64, (i % w) as f64);
                (col - c.cx).powi(2) + (r - c.cy).powi(2) <= c.r * c.r
            })
            .collect()
    }

    #[test]
    fn fits_exact_points() {
        let pts: Vec<[f64; 2]> = (0..40)
            .map(|k| {
                let a = k as f64 * 0.3;
                [10.0 + 7.0 * a.cos(), -3.0 + 7.0 * a.sin()]
            })
            .collect();
        let f = fit_circle(&pts).unwrap();
        assert!((f.circle.cx - 10.0).abs() < 1e-9);
        assert!((f.circle.cy + 3.0).abs() < 1e-9);
        assert!((f.circle.r - 7.0).abs() < 1e-9);
    }

    #[test]
    fn digitised_disc_fits_to_a_tenth_of_a_pixel() {
        let truth = Circle {
            cx: 71.3,
            cy: 48.7,
            r: 33.4,
        };
        let m = disc(150, 110, truth);
        let f = fit_mask_circle(&m, 150, 110, "test").unwrap();
        assert!((f.circle.cx - truth.cx).abs() < 0.1, "{:?}", f);
        assert!((f.circle.cy - truth.cy).abs() < 0.1, "{:?}", f);
        assert!((f.circle.r - truth.r).abs() < 0.1, "{:?}", f);
        assert!(!f.touches_frame);
    }

    #[test]
    fn collinear_points_are_an_error() {
        let pts: Vec<[f64; 2]> = (0..10).map(|k| [k as f64, 2.0 * k as f64]).collect();
        assert!(fit_circle(&pts).is_err());
    }
}
