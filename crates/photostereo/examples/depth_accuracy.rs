//! Depth from DiLiGenT's true normals against the true depth (`../shared/data/diligent-depth`):
//! per object and integrator, perspective integration through the object's K at 1500 mm, then
//! the literature's measure — s = median(Z_gt / Z) over the mask, mean |s·Z − Z_gt| in mm — the
//! NaN count inside the mask and the integration time.
//!
//! `cargo run --release -p photostereo --example depth_accuracy [-- OBJECT... [--method M]...
//! [--max-slope S] [--figure PNG]]`; objects default to every folder there, methods to
//! `poisson` and `bilateral`. `--figure` draws the error maps |s·Z − Z_gt| of each method on the
//! first object side by side (docs/img/depth-error-cat.png).

use photostereo::base::progress::Silent;
use photostereo::geometry::integrate::perspective::perspective_surface;
use photostereo::geometry::integrate::IntegratorKind;
use photostereo::io::figure::{colormap, Canvas};
use photostereo::io::groundtruth::read_depth_map;
use photostereo::io::imageio::read_mask;
use photostereo::io::layouts::near::read_camera;
use std::path::{Path, PathBuf};
use std::time::Instant;

fn data() -> PathBuf {
    PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../../shared/data/diligent-depth"
    ))
}

/// One object's inputs.
struct Object {
    width: usize,
    height: usize,
    normals: Vec<[f32; 3]>,
    mask: Vec<bool>,
    truth: Vec<f32>,
    camera: photostereo::model::lightmodel::Camera,
}

fn load(dir: &Path) -> Object {
    let map = photostereo::io::groundtruth::read_normal_map(&dir.join("normal_map.png")).unwrap();
    let (h, w, mask) = read_mask(&dir.join("mask.png")).unwrap();
    assert_eq!((w, h), (map.width, map.height));
    let truth = read_depth_map(&dir.join("depth_gt.npz")).unwrap();
    assert_eq!((truth.width, truth.height), (w, h));
    let truth = truth.values;
    Object {
        width: w,
        height: h,
        normals: map.normals,
        mask,
        truth,
        camera: read_camera(&dir.join("K.txt")).unwrap(),
    }
}

/// `(mean |s·Z − Z_gt| mm, NaN pixels inside the mask, the error map)`.
fn measure(o: &Object, z: &[f32]) -> (f64, usize, Vec<f32>) {
    let mut ratios = Vec::new();
    let mut nan = 0;
    for ((&zi, &inside), &t) in z.iter().zip(&o.mask).zip(&o.truth) {
        if inside && t.is_finite() {
            if zi.is_finite() {
                ratios.push(t as f64 / zi as f64);
            } else {
                nan += 1;
            }
        }
    }
    ratios.sort_by(f64::total_cmp);
    let s = ratios[ratios.len() / 2];
    let mut map = vec![f32::NAN; z.len()];
    let (mut sum, mut count) = (0f64, 0usize);
    for (i, m) in map.iter_mut().enumerate() {
        if o.mask[i] && o.truth[i].is_finite() && z[i].is_finite() {
            let e = (s * z[i] as f64 - o.truth[i] as f64).abs();
            *m = e as f32;
            sum += e;
            count += 1;
        }
    }
    (sum / count.max(1) as f64, nan, map)
}

/// The error maps side by side on one colour scale (0..`max` mm), titled, with a scale bar.
fn figure(maps: &[(String, Vec<f32>)], o: &Object, max: f32, path: &Path) {
    // Crop to the mask's bounding box plus a margin.
    let (mut r0, mut r1, mut c0, mut c1) = (o.height, 0, o.width, 0);
    for i in 0..o.mask.len() {
        if o.mask[i] {
            let (r, c) = (i / o.width, i % o.width);
            (r0, r1, c0, c1) = (r0.min(r), r1.max(r), c0.min(c), c1.max(c));
        }
    }
    let m = 6;
    let (r0, c0) = (r0.saturating_sub(m), c0.saturating_sub(m));
    let (r1, c1) = ((r1 + m).min(o.height - 1), (c1 + m).min(o.width - 1));
    let (pw, ph) = (c1 - c0 + 1, r1 - r0 + 1);
    let (title_h, gap, bar_w) = (24, 12, 90);
    let width = maps.len() * pw + (maps.len() - 1) * gap + bar_w;
    let mut canvas = Canvas::new(width, ph + title_h, [255, 255, 255]);
    for (k, (title, map)) in maps.iter().enumerate() {
        let x0 = k * (pw + gap);
        canvas.text(x0 + 4, 4, title, 2, [0, 0, 0]);
        for r in 0..ph {
            for c in 0..pw {
                let i = (r0 + r) * o.width + c0 + c;
                let v = map[i];
                let rgb = if v.is_finite() {
                    colormap(v / max)
                } else if o.mask[i] {
                    [255, 0, 0]
                } else {
                    [40, 40, 40]
                };
                canvas.put(x0 + c, title_h + r, rgb);
            }
        }
    }
    let bx = width - bar_w + 10;
    let (top, bottom) = (title_h + 4, title_h + ph - 4);
    for y in top..bottom {
        let t = 1.0 - (y - top) as f32 / (bottom - top - 1) as f32;
        canvas.fill_rect(bx, y, 14, 1, colormap(t));
    }
    canvas.text(bx + 20, top, &format!("{max} mm"), 2, [0, 0, 0]);
    canvas.text(bx + 20, bottom - 14, "0", 2, [0, 0, 0]);
    canvas.save(path).unwrap();
}

fn env<T: std::str::FromStr>(name: &str, default: T) -> T {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

struct Reference(photostereo::geometry::integrate::Bilateral);
impl photostereo::geometry::integrate::Integrator for Reference {
    fn name(&self) -> &'static str {
        "reference"
    }
    fn integrate(
        &self,
        problem: &photostereo::geometry::integrate::IntegrationProblem,
        _: &dyn photostereo::base::progress::Progress,
    ) -> photostereo::base::error::Result<photostereo::geometry::integrate::Depth> {
        photostereo::geometry::integrate::bilateral_reference(&self.0, problem)
    }
}

fn integrator(kind: IntegratorKind) -> Box<dyn photostereo::geometry::integrate::Integrator> {
    use photostereo::geometry::integrate::Bilateral;
    if kind != IntegratorKind::Bilateral {
        return kind.integrator();
    }
    let d = Bilateral::default();
    let b = Bilateral {
        k: env("BIL_K", d.k),
        max_iterations: env("BIL_ITER", d.max_iterations),
        tolerance: env("BIL_TOL", d.tolerance),
        inner_reduction: env("BIL_INNER_RED", d.inner_reduction),
        inner_iterations: env("BIL_INNER_IT", d.inner_iterations),
        min_edge_weight: env("BIL_FLOOR", d.min_edge_weight),
        slope_weighting: env("BIL_SLOPEW", d.slope_weighting),
        debias: env("BIL_DEBIAS", d.debias),
        ..d
    };
    if std::env::var("BIL_REF").is_ok() {
        Box::new(Reference(b))
    } else {
        Box::new(b)
    }
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (mut objects, mut methods, mut max_slope, mut fig) = (Vec::new(), Vec::new(), None, None);
    let mut it = args.iter();
    while let Some(a) = it.next() {
        match a.as_str() {
            "--method" => methods.push(it.next().unwrap().parse::<IntegratorKind>().unwrap()),
            "--max-slope" => max_slope = Some(it.next().unwrap().parse::<f32>().unwrap()),
            "--figure" => fig = Some(PathBuf::from(it.next().unwrap())),
            _ => objects.push(a.clone()),
        }
    }
    if objects.is_empty() {
        let mut names: Vec<String> = std::fs::read_dir(data())
            .unwrap()
            .filter_map(|e| e.ok())
            .filter(|e| e.path().join("depth_gt.npz").is_file())
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        objects = names;
    }
    if methods.is_empty() {
        methods = vec![IntegratorKind::Poisson, IntegratorKind::Bilateral];
    }
    let max_slope = max_slope
        .unwrap_or(photostereo::geometry::integrate::IntegrationParams::default().max_slope);
    println!("max slope {max_slope}; mean |s·Z − Z_gt| (mm), NaN inside the mask, time");
    let mut maps = Vec::new();
    for (n, name) in objects.iter().enumerate() {
        let o = load(&data().join(name));
        for &kind in &methods {
            let t = Instant::now();
            let s = perspective_surface(
                o.width,
                o.height,
                &o.normals,
                Some(&o.mask),
                None,
                &o.camera,
                1500.0,
                integrator(kind).as_ref(),
                max_slope,
                &Silent,
            )
            .unwrap();
            let secs = t.elapsed().as_secs_f64();
            let (err, nan, map) = measure(&o, &s.depth.values);
            println!(
                "{name:>8} {:>10}: {err:.4} mm, {nan} NaN, {:.3} s ({} CG iterations, {} reweightings, {} discontinuity pixels)",
                kind.name(),
                secs,
                s.depth.stats.iterations,
                s.depth.stats.reweightings,
                s.discontinuity_pixels()
            );
            if n == 0 && fig.is_some() {
                maps.push((format!("{} {err:.3} mm", kind.name()), map));
                if std::env::var("SHOW_DISC").is_ok() {
                    if let Some(d) = &s.depth.discontinuities {
                        maps.push(("jumps".into(), d.iter().map(|v| v * 2.0).collect()));
                    }
                }
            }
        }
        if n == 0 && std::env::var("SHOW_TRUE_JUMPS").is_ok() {
            use photostereo::geometry::integrate::perspective::{
                log_depth_gradients, log_depth_scale,
            };
            let g = log_depth_gradients(
                o.width,
                o.height,
                &o.normals,
                Some(&o.mask),
                &o.camera,
                1000.0,
            )
            .unwrap();
            let fs = log_depth_scale(&o.camera);
            let f: Vec<f64> = o.truth.iter().map(|&z| fs * (z as f64).ln()).collect();
            let mut jm = vec![f32::NAN; o.truth.len()];
            let w = o.width;
            for i in 0..f.len() {
                if !g.mask[i] || !f[i].is_finite() {
                    continue;
                }
                let mut m = 0f64;
                for (j, t) in [
                    (
                        i + 1,
                        0.5 * (g.p[i] + g.p.get(i + 1).copied().unwrap_or(0.0)),
                    ),
                    (
                        i + w,
                        0.5 * (g.q[i] + g.q.get(i + w).copied().unwrap_or(0.0)),
                    ),
                ] {
                    if j < f.len() && g.mask[j] && f[j].is_finite() {
                        m = m.max((f[j] - f[i] - t as f64).abs());
                    }
                }
                jm[i] = m as f32;
            }
            maps.push(("true jumps px".into(), jm));
        }
        if n == 0 {
            if let Some(path) = &fig {
                figure(&maps, &o, env("FIG_MAX", 2.0), path);
                println!("wrote {}", path.display());
            }
        }
    }
}
