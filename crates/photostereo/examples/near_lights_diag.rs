//! Where the near model's error lies: the recursive method in the near model on one
//! `synth` near scene, its mean angular error split by what the ground truth says of each pixel
//! (how many lights are truly lit, whether one is highlighted) and by whether the method's
//! usable lights are the truly lit, unhighlighted ones.
//!
//! `cargo run --release -p photostereo --example near_lights_diag [SIZE] [SCENE] [RIG]`

use photostereo::base::progress::Silent;
use photostereo::method::engine::{reconstruct_with_truth, Method, Params, Reconstruction};
use photostereo::scene::near::{synthesize_near, NearRig, NearSpec};
use photostereo::scene::render::GroundTruth;
use photostereo::scene::SceneKind;
use photostereo::solve::lambert::status;
use photostereo::solve::metrics::angular_error_deg;
use std::collections::BTreeMap;

/// (lit lights, highlighted, usable lights, usable in true shadow, highlighted usable).
type DetailKey = (usize, bool, usize, usize, usize);

/// The error split by the truth's classes of each mask pixel.
#[derive(Default)]
struct Tally {
    /// (lit lights, highlighted) -> (pixels, error sum, pixels with the right set, their error
    /// sum).
    table: BTreeMap<(usize, bool), (usize, f64, usize, f64)>,
    /// Per class: the integrated surface's own normals' error sum and pixels.
    surface: BTreeMap<(usize, bool), (f64, usize)>,
    /// Per class: the integration trust's sum and the pixels per count of usable lights.
    trust: BTreeMap<(usize, bool), (f64, [usize; 5])>,
    /// Per detailed class: pixels, error sum, surface error sum, trust sum.
    detail: BTreeMap<DetailKey, (usize, f64, f64, f64)>,
    total: f64,
    count: usize,
}

impl Tally {
    /// Every mask pixel of the truth, classed and counted.
    fn collect(truth: &GroundTruth, rec: &Reconstruction, surface_normals: &[[f32; 3]]) -> Self {
        let mut t = Tally::default();
        let n = rec.n_lights;
        for i in (0..rec.width * rec.height).filter(|&i| truth.mask[i]) {
            let used_where = |f: &dyn Fn(usize) -> bool| {
                (0..n)
                    .filter(|&k| rec.light_status.get(k, i) == status::USED && f(k))
                    .count()
            };
            let e = angular_error_deg(rec.normals[i], truth.normals[i]);
            let lit = (0..n).filter(|&k| !truth.shadow[k][i]).count();
            let hl = (0..n).any(|k| truth.highlight[k][i]);
            let right = (0..n).all(|k| {
                let good = !truth.shadow[k][i] && !truth.highlight[k][i];
                (rec.light_status.get(k, i) == status::USED) == good
            });
            // The surface's normal where it has one (not at its NaN pixels).
            let se = angular_error_deg(surface_normals[i], truth.normals[i]);
            let sf = t.surface.entry((lit, hl)).or_default();
            if se.is_finite() {
                sf.0 += se;
                sf.1 += 1;
            }
            let used = used_where(&|_| true);
            let in_shadow = used_where(&|k| truth.shadow[k][i]);
            let hl_used = used_where(&|k| truth.highlight[k][i]);
            let d = t
                .detail
                .entry((lit, hl, used, in_shadow, hl_used))
                .or_default();
            d.0 += 1;
            d.1 += e;
            d.2 += if se.is_finite() { se } else { 0.0 };
            d.3 += rec.trust[i] as f64;
            let tr = t.trust.entry((lit, hl)).or_default();
            tr.0 += rec.trust[i] as f64;
            tr.1[used.min(4)] += 1;
            let row = t.table.entry((lit, hl)).or_default();
            row.0 += 1;
            row.1 += e;
            if right {
                row.2 += 1;
                row.3 += e;
            }
            t.total += e;
            t.count += 1;
        }
        t
    }

    /// The two tables: by class, and by detailed class (classes of 50 pixels or more).
    fn print(&self, title: &str) {
        let total = self.total;
        println!(
            "{title}: mean {:.3} deg over {} pixels",
            total / self.count as f64,
            self.count
        );
        println!("lit highlighted | pixels | share of error sum | mean | right set | mean (right) | mean (wrong) | surface mean | mean trust | pixels by usable lights 0..4+");
        for ((lit, hl), (p, s, rp, rs)) in &self.table {
            let surface = self.surface[&(*lit, *hl)];
            let trust = self.trust[&(*lit, *hl)];
            println!(
                "{lit} {hl} | {p} | {:.1}% | {:.2} | {rp} | {:.2} | {:.2} | {:.2} | {:.2} | {:?}",
                100.0 * s / total,
                s / *p as f64,
                rs / (*rp).max(1) as f64,
                (s - rs) / (p - rp).max(1) as f64,
                surface.0 / surface.1.max(1) as f64,
                trust.0 / *p as f64,
                trust.1
            );
        }
        println!("lit highlighted usable shadowed-usable highlighted-usable | pixels | mean | surface mean | mean trust");
        for ((lit, hl, u, su, hu), (p, e, se, t)) in &self.detail {
            if *p >= 50 {
                let p = *p as f64;
                println!(
                    "{lit} {hl} {u} {su} {hu} | {p} | {:.2} | {:.2} | {:.2}",
                    e / p,
                    se / p,
                    t / p
                );
            }
        }
    }
}

/// The picture of `DIAG_PNG`: the error (white = 30° or more) beside the truth's classes (red:
/// highlighted lights, green: lit lights, blue: the method's usable lights), three times
/// larger.
fn write_picture(path: &str, truth: &GroundTruth, rec: &Reconstruction) -> photostereo::Result<()> {
    let (w, n) = (rec.width, rec.n_lights);
    let hw = w * rec.height;
    let mut img = vec![0u8; 2 * hw * 3];
    for i in (0..hw).filter(|&i| truth.mask[i]) {
        let (row, col) = (i / w, i % w);
        let a = (row * 2 * w + col) * 3;
        let b = a + w * 3;
        let e = (angular_error_deg(rec.normals[i], truth.normals[i]) / 30.0).min(1.0);
        img[a..a + 3].fill((255.0 * e) as u8);
        let lit = (0..n).filter(|&k| !truth.shadow[k][i]).count();
        let hl = (0..n).filter(|&k| truth.highlight[k][i]).count();
        let used = (0..n)
            .filter(|&k| rec.light_status.get(k, i) == status::USED)
            .count();
        img[b] = (hl * 120).min(255) as u8;
        img[b + 1] = (lit * 60).min(255) as u8;
        img[b + 2] = (used * 60).min(255) as u8;
    }
    let (sw, sh) = (6 * w, 3 * rec.height);
    let big: Vec<u8> = (0..sw * sh * 3)
        .map(|j| {
            let (px, ch) = (j / 3, j % 3);
            let (r, c) = (px / sw / 3, px % sw / 3);
            img[(r * 2 * w + c) * 3 + ch]
        })
        .collect();
    photostereo::io::imageio::write_png8(std::path::Path::new(path), sw, sh, 3, &big)
}

fn main() -> photostereo::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let size: usize = args.first().and_then(|s| s.parse().ok()).unwrap_or(128);
    let scene: SceneKind = args.get(1).map_or("blocks", |s| s).parse()?;
    let rig = args
        .get(2)
        .and_then(|s| NearRig::parse(s))
        .unwrap_or(NearRig::Square);
    let spec = NearSpec {
        size,
        ..NearSpec::new(scene, rig)
    };
    let r = synthesize_near(&spec)?;
    let truth = &r.rendered.truth;
    let params = Params {
        method: Method::Recursive,
        ..Params::default()
    };
    let t = std::time::Instant::now();
    let rec = reconstruct_with_truth(&r.capture()?, &params, None, &Silent)?;
    println!("seconds {:.2}", t.elapsed().as_secs_f64());
    println!("timings {:?}", rec.report.timings_s);
    if let Some(near) = rec.report.extra.get("near") {
        println!("lobe {}", near["highlight_lobe"]);
        println!("capture lobe {}", near["capture_lobe"]);
        for r in near["rounds"].as_array().into_iter().flatten() {
            println!("round {r}");
        }
    }
    let surface_normals = photostereo::geometry::integrate::perspective::normals_from_z(
        rec.width,
        rec.height,
        rec.depth().unwrap(),
        &rec.mask,
        &rec.camera.unwrap(),
    );
    let tally = Tally::collect(truth, &rec, &surface_normals);
    if let Ok(path) = std::env::var("DIAG_PNG") {
        write_picture(&path, truth, &rec)?;
    }
    tally.print(&format!("{} {}", scene.name(), rig.name()));
    Ok(())
}
