//! Ground-truth scenes: geometry, shadows, reflectance, noise, files and determinism, each
//! checked against an independent truth (analytic formulas, brute force, least squares).

use photostereo::base::progress::Silent;
use photostereo::base::rng::Pcg32;
use photostereo::io::groundtruth::read_normal_map;
use photostereo::io::layouts::CaptureFiles;
use photostereo::io::synth::synth_to_folder;
use photostereo::model::lights::Lights;
use photostereo::scene::rigs::slant_tilt_lights;
use photostereo::scene::{
    cast_shadows, ray_march_shadows, render, synthesize, Brdf, Frame, LightIntensities, MaskShape,
    RenderOptions, Rig, Scene, SceneKind, SynthSpec,
};
use photostereo::solve::estimate::{Estimator, LeastSquares};
use photostereo::solve::metrics::evaluate;
use std::path::Path;

fn noise_free(brdf: Brdf) -> RenderOptions {
    RenderOptions {
        brdf,
        noise_sigma: 0.0,
        shot_full_well: 0.0,
        seed: 1,
    }
}

#[test]
fn analytic_gradients_match_finite_differences() {
    // Central differences of the height function itself (not of the sampled grid) at
    // pseudo-random points; a wrong sign or factor in any primitive shows up here.
    let size = 256;
    let frame = Frame::new(size);
    let mut rng = Pcg32::new(99, 0);
    let eps = 1e-4;
    for &kind in SceneKind::ALL {
        let mut worst = 0f64;
        for _ in 0..4000 {
            let col = rng.next_f64() * (size - 1) as f64;
            let row = rng.next_f64() * (size - 1) as f64;
            let [_, gc, gr] = frame.height_and_gradient(kind, col, row);
            let h = |c: f64, r: f64| frame.height_and_gradient(kind, c, r)[0];
            let fc = (h(col + eps, row) - h(col - eps, row)) / (2.0 * eps);
            let fr = (h(col, row + eps) - h(col, row - eps)) / (2.0 * eps);
            let scale = 1.0 + gc.abs().max(gr.abs());
            worst = worst
                .max((fc - gc).abs() / scale)
                .max((fr - gr).abs() / scale);
        }
        assert!(worst < 1e-4, "{kind}: gradient mismatch {worst}");
    }
}

#[test]
fn normals_are_unit_face_the_camera_and_match_the_height_field() {
    for &kind in SceneKind::ALL {
        let scene = Scene::builtin(kind, 96, None, true).unwrap();
        assert!(scene.mask.iter().any(|&m| m));
        let frame = Frame::new(96);
        for (i, n) in scene.normals.iter().enumerate() {
            let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
            assert!((len - 1.0).abs() < 1e-5, "{kind}: |n| = {len}");
            assert!(n[2] > 0.0, "{kind}: n_z = {}", n[2]);
            // CONVENTIONS.md: ∂f/∂col = −n_x/n_z and ∂f/∂row = +n_y/n_z.
            let (col, row) = ((i % 96) as f64, (i / 96) as f64);
            let [h, gc, gr] = frame.height_and_gradient(kind, col, row);
            assert!((scene.depth[i] as f64 - h).abs() < 1e-3);
            let tol = 1e-3 * (1.0 + gc.abs().max(gr.abs()));
            assert!((gc + (n[0] / n[2]) as f64).abs() < tol, "{kind} x-slope");
            assert!((gr - (n[1] / n[2]) as f64).abs() < tol, "{kind} y-slope");
            assert!(scene.albedo[i].iter().all(|&a| a > 0.2 && a <= 0.95));
        }
    }
}

#[test]
fn the_sphere_points_up_at_its_top_and_right_at_its_right() {
    // Independent of the formulas: the top of the dome has n_y > 0, its right side n_x > 0.
    let scene = Scene::builtin(SceneKind::Sphere, 65, None, false).unwrap();
    let at = |row: usize, col: usize| scene.normals[row * 65 + col];
    let top = at(32 - 12, 32);
    let right = at(32, 32 + 12);
    assert!(top[1] > 0.3 && top[0].abs() < 1e-6, "{top:?}");
    assert!(right[0] > 0.3 && right[1].abs() < 1e-6, "{right:?}");
    assert!(scene.depth[32 * 65 + 32] > scene.depth[20 * 65 + 32]);
}

#[test]
fn accelerated_cast_shadows_equal_the_plain_ray_march() {
    let mut lights = Rig::Square4.lights().unwrap().directions;
    lights.extend(Rig::Dome(12).lights().unwrap().directions);
    lights.push([0.9, 0.1, 0.2]); // grazing
                                  // Along the axes (no travel on one of them) and low, in every quadrant.
    let r = 0.5f64.sqrt();
    lights.extend([
        [r, 0.0, r],
        [0.0, -r, r],
        [-0.9, 0.0, 0.436],
        [0.0, 0.9, 0.436],
    ]);
    lights.extend([[-0.6, -0.6, 0.53], [0.6, -0.6, 0.53], [-0.6, 0.6, 0.53]]);
    for &kind in SceneKind::ALL {
        for mask in [None, Some(MaskShape::Irregular)] {
            let scene = Scene::builtin(kind, 80, mask, false).unwrap();
            for l in &lights {
                let fast = cast_shadows(&scene, *l);
                let slow = ray_march_shadows(&scene, *l, 0.25);
                assert_eq!(fast, slow, "{kind}, light {l:?}");
            }
        }
    }
}

/// A vertical step: height `h` for col < c0, 0 beyond, joined by a tanh ramp 0.1 px wide (so
/// the sampled heights are h up to col ⌊c0⌋ and 0 from ⌈c0⌉ on, to 0.01%).
fn wall_scene(h: f64, c0: f64, w: usize, rows: usize) -> Scene {
    const RAMP: f64 = 0.1;
    Scene::from_height_fn(
        "wall",
        w,
        rows,
        |col, _row| {
            let t = ((c0 - col) / RAMP).tanh();
            [h * 0.5 * (1.0 + t), -h * 0.5 * (1.0 - t * t) / RAMP, 0.0]
        },
        |_, _| [0.7; 3],
        |_, _| true,
    )
    .unwrap()
}

#[test]
fn a_vertical_step_casts_a_shadow_of_length_h_tan_slant() {
    let (w, rows, c0) = (160, 9, 30.5);
    for (h, slant) in [(10.0, 35.0f64), (20.0, 47.0), (12.0, 60.0), (30.0, 20.0)] {
        let scene = wall_scene(h, c0, w, rows);
        let s = slant.to_radians();
        // The light comes from the left (−x): the shadow falls to the right of the wall.
        let lights = Lights::new(&[[-s.sin(), 0.0, s.cos()]]).unwrap();
        let r = render(&scene, &lights, &noise_free(Brdf::Lambert)).unwrap();
        let shadow = &r.truth.shadow[0];
        let row = rows / 2;
        let last = (0..w).rev().find(|&c| shadow[row * w + c]).unwrap() as f64;
        let expected = h * s.tan();
        // Measured from the step's top edge: the last pixel at full height (col 30); the sampled
        // step is a one-pixel bilinear ramp from col 30 to 31.
        let len = last - c0.floor();
        assert!(
            (len - expected).abs() <= 1.0,
            "h {h}, slant {slant}°: shadow length {len}, expected {expected:.2}"
        );
        // Everything left of the wall is lit; the shadow is contiguous up to its end.
        assert!((0..25).all(|c| !shadow[row * w + c]));
        assert!((31..=last as usize).all(|c| shadow[row * w + c]));
        // Shadowed pixels are black in the noise-free image.
        let img = &r.images[0];
        assert_eq!(img.at(row, last as usize, 0), 0.0);
        let lit = img.at(row, last as usize + 2, 0) as f64;
        assert!((lit - 0.7 * s.cos()).abs() < 1e-4, "lit ground {lit}");
    }
}

#[test]
fn shadows_follow_the_y_up_frame() {
    // A wall across the columns: high for row < r0 (the top of the image, +y). A light from the
    // top (+y) casts the wall's shadow downward (growing row index) onto the low part; lit from
    // below (−y), the wall faces the light and nothing is shadowed.
    let (w, rows, r0, h) = (8, 120, 30.5, 16.0);
    let scene = Scene::from_height_fn(
        "wall-y",
        w,
        rows,
        |_col, row| {
            let t = ((r0 - row) / 0.1).tanh();
            [h * 0.5 * (1.0 + t), 0.0, -h * 0.5 * (1.0 - t * t) / 0.1]
        },
        |_, _| [0.7; 3],
        |_, _| true,
    )
    .unwrap();
    let s = 40f64.to_radians();
    let from_top = Lights::new(&[[0.0, s.sin(), s.cos()]]).unwrap();
    let r = render(&scene, &from_top, &noise_free(Brdf::Lambert)).unwrap();
    let col = w / 2;
    let last = (0..rows)
        .rev()
        .find(|&rr| r.truth.shadow[0][rr * w + col])
        .unwrap() as f64;
    let expected = r0.floor() + h * s.tan();
    assert!(
        (last - expected).abs() <= 1.0,
        "shadow ends at row {last}, expected {expected:.2}"
    );
    let from_bottom = Lights::new(&[[0.0, -s.sin(), s.cos()]]).unwrap();
    let r = render(&scene, &from_bottom, &noise_free(Brdf::Lambert)).unwrap();
    // The wall faces down (−y): lit from below, nothing is shadowed.
    assert!(r.truth.shadow[0].iter().all(|&b| !b));
}

#[test]
fn least_squares_through_the_written_files_recovers_the_normals() {
    // Lambert, no noise: on the pixels lit by every light the images are exactly Lambertian
    // (up to 16-bit quantisation), so least squares must return the shading normals.
    let dir = tempfile::tempdir().unwrap();
    // A light file: six lights at slant 25°.
    let light_file = dir.path().join("six.txt");
    let six = slant_tilt_lights(25.0, &[10.0, 70.0, 130.0, 190.0, 250.0, 310.0]);
    photostereo::io::light_files::write_directions(&six, &light_file).unwrap();
    for (kind, rig) in [
        (SceneKind::Sphere, Rig::Square4),
        (SceneKind::Face, Rig::Ring(8)),
        (
            SceneKind::Cavities,
            photostereo::io::light_files::parse_rig(light_file.to_str().unwrap()).unwrap(),
        ),
    ] {
        let mut spec = SynthSpec::new(kind, rig);
        spec.render = noise_free(Brdf::Lambert);
        spec.intensities = LightIntensities::Coloured;
        let out = dir.path().join(kind.name());
        synth_to_folder(&spec, &out, false).unwrap();
        let capture = CaptureFiles::diligent(&out).unwrap().load(&Silent).unwrap();
        let est = LeastSquares.estimate(&capture, &Silent).unwrap();
        let normals = capture.scatter(&est.normals, 1, [0.0; 3]);
        let truth = read_normal_map(&out.join("gt/normal.npy")).unwrap();
        let shadow: ndarray::Array3<bool> =
            ndarray_npy::read_npy(out.join("gt/shadow.npy")).unwrap();
        let (n, h, w) = shadow.dim();
        assert_eq!((h, w, n), (128, 128, capture.n_lights()));
        let lit: Vec<bool> = (0..h * w)
            .map(|i| capture.mask[i] && (0..n).all(|k| !shadow[[k, i / w, i % w]]))
            .collect();
        let pixels = lit.iter().filter(|&&b| b).count();
        assert!(
            pixels > 5000,
            "{kind}: only {pixels} pixels lit by all lights"
        );
        let (_, stats) = evaluate(&normals, &truth.normals, Some(&lit)).unwrap();
        eprintln!(
            "{kind}: least squares through the files, {pixels} pixels lit by all lights: mean {:.5}°, median {:.5}°",
            stats.mean_deg, stats.median_deg
        );
        assert!(
            stats.mean_deg < 0.05,
            "{kind}: mean error {} through the files",
            stats.mean_deg
        );
    }
}

#[test]
fn specular_lobes_peak_where_the_normal_is_the_half_vector() {
    // The rendered (not the formula's) specular excess over Lambert, per light, is largest at
    // the sphere pixel whose normal is the half vector of the light and the viewer (0, 0, 1).
    // Intensity 0.5 keeps every value below white, so nothing clips.
    let scene = Scene::builtin(SceneKind::Sphere, 160, None, false).unwrap();
    let lights = Rig::Ring(8)
        .lights()
        .unwrap()
        .with_intensities(vec![[0.5; 3]; 8])
        .unwrap();
    let matte = render(&scene, &lights, &noise_free(Brdf::Lambert)).unwrap();
    for brdf in [Brdf::BlinnPhong, Brdf::TorranceSparrow] {
        let shiny = render(&scene, &lights, &noise_free(brdf)).unwrap();
        assert_eq!(shiny.stats.clipped_fraction, 0.0);
        for (k, l) in lights.directions.iter().enumerate() {
            let (best, excess) = (0..scene.mask.len())
                .map(|i| {
                    let d: f32 = (0..3)
                        .map(|c| shiny.images[k].data[i * 3 + c] - matte.images[k].data[i * 3 + c])
                        .sum();
                    (i, d)
                })
                .max_by(|a, b| a.1.total_cmp(&b.1))
                .unwrap();
            assert!(excess / 3.0 > 0.2, "{brdf}: peak excess {excess}");
            let hv = [l[0], l[1], l[2] + 1.0];
            let hn = (hv[0] * hv[0] + hv[1] * hv[1] + hv[2] * hv[2]).sqrt();
            let n = scene.normals[best];
            let cos: f64 = (0..3).map(|c| n[c] as f64 * hv[c] / hn).sum();
            let angle = cos.min(1.0).acos().to_degrees();
            assert!(
                angle < 2.0,
                "{brdf} light {k}: peak {angle:.2}° from the half vector"
            );
        }
    }
}

#[test]
fn highlight_masks_follow_the_documented_rule() {
    // Compare a Blinn–Phong rendering with the Lambert one (both noise-free): the difference is
    // the specular term (where nothing clips), which must exceed 2% of full scale exactly on the
    // highlight mask.
    let mut spec = SynthSpec::new(SceneKind::Bumps, Rig::Square4);
    spec.render = noise_free(Brdf::BlinnPhong);
    let shiny = synthesize(&spec).unwrap();
    spec.render.brdf = Brdf::Lambert;
    let matte = synthesize(&spec).unwrap();
    assert!(matte.truth.highlight.iter().flatten().all(|&b| !b));
    let mut checked = 0;
    for k in 0..4 {
        for i in 0..shiny.truth.mask.len() {
            let s = &shiny.images[k].data[i * 3..i * 3 + 3];
            let m = &matte.images[k].data[i * 3..i * 3 + 3];
            if s.iter().any(|&v| v >= 1.0) || !shiny.truth.mask[i] {
                continue;
            }
            let diff: f64 = (0..3).map(|c| (s[c] - m[c]) as f64).sum::<f64>() / 3.0;
            if (diff - 0.02).abs() < 1e-4 {
                continue; // on the threshold within quantisation
            }
            assert_eq!(
                shiny.truth.highlight[k][i],
                diff > 0.02,
                "light {k} pixel {i}"
            );
            assert_eq!(shiny.truth.shadow[k][i], matte.truth.shadow[k][i]);
            checked += 1;
        }
    }
    assert!(checked > 10_000);
    assert!(shiny.stats.highlight_fraction > 0.01);
    assert!(
        shiny.stats.clipped_fraction > 0.0,
        "strong highlights clip at white"
    );
}

#[test]
fn every_scene_under_square4_has_cast_shadows_and_highlights() {
    for brdf in [Brdf::BlinnPhong, Brdf::TorranceSparrow] {
        for &kind in SceneKind::ALL {
            let mut spec = SynthSpec::new(kind, Rig::Square4);
            spec.render.brdf = brdf;
            let r = synthesize(&spec).unwrap();
            let s = &r.stats;
            assert!(s.cast_shadow_fraction > 0.005, "{kind} {brdf}: {s:?}");
            assert!(s.highlight_fraction > 0.005, "{kind} {brdf}: {s:?}");
            // Every light has some of each.
            for k in 0..4 {
                assert!(
                    r.truth.highlight[k].iter().any(|&b| b),
                    "{kind} {brdf} light {k}"
                );
                assert!(
                    r.truth.cast_shadow[k].iter().any(|&b| b),
                    "{kind} {brdf} light {k}"
                );
            }
        }
    }
}

#[test]
fn noise_has_the_requested_sigma() {
    let mut spec = SynthSpec::new(SceneKind::Face, Rig::Square4);
    spec.render = noise_free(Brdf::Lambert);
    let clean = synthesize(&spec).unwrap();
    spec.render.noise_sigma = 0.01;
    spec.render.seed = 5;
    let noisy = synthesize(&spec).unwrap();
    let (mut s, mut s2, mut n) = (0.0, 0.0, 0.0);
    for k in 0..4 {
        for (a, b) in noisy.images[k].data.iter().zip(&clean.images[k].data) {
            // Away from 0 and 1, where clipping would bias the statistics.
            if *b > 0.1 && *b < 0.85 {
                let d = (a - b) as f64;
                s += d;
                s2 += d * d;
                n += 1.0;
            }
        }
    }
    let sd = (s2 / n - (s / n) * (s / n)).sqrt();
    assert!((sd - 0.01).abs() < 0.0005, "measured σ {sd}");
    assert!((s / n).abs() < 0.0005);
    // Shot noise scales with the signal: variance = value / full_well.
    spec.render.noise_sigma = 0.0;
    spec.render.shot_full_well = 1000.0;
    let shot = synthesize(&spec).unwrap();
    let (mut lo, mut hi) = ((0.0, 0.0), (0.0, 0.0));
    for k in 0..4 {
        for (a, b) in shot.images[k].data.iter().zip(&clean.images[k].data) {
            let d2 = ((a - b) as f64).powi(2);
            if *b > 0.1 && *b < 0.2 {
                lo = (lo.0 + d2 / *b as f64, lo.1 + 1.0);
            } else if *b > 0.5 && *b < 0.8 {
                hi = (hi.0 + d2 / *b as f64, hi.1 + 1.0);
            }
        }
    }
    for (sum, count) in [lo, hi] {
        let ratio = sum / count * 1000.0;
        assert!(
            (ratio - 1.0).abs() < 0.1,
            "variance/value·full_well = {ratio}"
        );
    }
}

fn files_of(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                let rel = p.strip_prefix(dir).unwrap().display().to_string();
                out.push((rel, std::fs::read(&p).unwrap()));
            }
        }
    }
    out.sort();
    out
}

#[test]
fn the_same_seed_gives_byte_identical_files() {
    let dir = tempfile::tempdir().unwrap();
    let mut spec = SynthSpec::new(SceneKind::Terrain, Rig::Ring(8));
    spec.size = 72;
    spec.render.shot_full_well = 5000.0;
    spec.intensities = LightIntensities::Varied;
    let a = dir.path().join("a");
    let b = dir.path().join("b");
    synth_to_folder(&spec, &a, false).unwrap();
    // Render b on a single thread: the split of the work must not matter.
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    pool.install(|| synth_to_folder(&spec, &b, false)).unwrap();
    let fa = files_of(&a);
    let fb = files_of(&b);
    assert!(fa.len() >= 8 + 5 + 5, "{} files", fa.len());
    assert_eq!(fa.len(), fb.len());
    for ((na, da), (nb, db)) in fa.iter().zip(&fb) {
        assert_eq!(na, nb);
        assert!(da == db, "{na} differs between runs with the same seed");
    }
    spec.render.seed += 1;
    let c = dir.path().join("c");
    synth_to_folder(&spec, &c, false).unwrap();
    let fc = files_of(&c);
    let img = |f: &[(String, Vec<u8>)]| f.iter().find(|(n, _)| n == "001.png").unwrap().1.clone();
    assert_ne!(img(&fa), img(&fc), "another seed must give other noise");
}

#[test]
fn written_ground_truth_has_the_documented_shapes() {
    let dir = tempfile::tempdir().unwrap();
    let mut spec = SynthSpec::new(SceneKind::Bumps, Rig::Dome(6));
    spec.size = 40;
    let out = dir.path().join("x");
    let (r, _) = synth_to_folder(&spec, &out, false).unwrap();
    let depth: ndarray::Array2<f32> = ndarray_npy::read_npy(out.join("gt/depth.npy")).unwrap();
    let albedo: ndarray::Array3<f32> = ndarray_npy::read_npy(out.join("gt/albedo.npy")).unwrap();
    let hl: ndarray::Array3<bool> = ndarray_npy::read_npy(out.join("gt/highlight.npy")).unwrap();
    assert_eq!(depth.dim(), (40, 40));
    assert_eq!(albedo.dim(), (40, 40, 3));
    assert_eq!(hl.dim(), (6, 40, 40));
    for i in 0..1600 {
        let (row, col) = (i / 40, i % 40);
        assert_eq!(depth[[row, col]].is_nan(), !r.truth.mask[i]);
        for k in 0..6 {
            assert_eq!(hl[[k, row, col]], r.truth.highlight[k][i]);
        }
    }
    let (h, w, mask) = photostereo::io::imageio::read_mask(&out.join("mask.png")).unwrap();
    assert_eq!((h, w), (40, 40));
    assert_eq!(mask, r.truth.mask);
    assert!(mask.iter().any(|&m| !m), "bumps use the irregular mask");
    // Existing output is refused without force.
    assert!(synth_to_folder(&spec, &out, false).is_err());
    assert!(synth_to_folder(&spec, &out, true).is_ok());
}

#[test]
fn rigs_shadow_more_as_slant_grows() {
    // Sanity of the light geometry: a steeper rig (slant 60°) shadows more than slant 20°.
    let scene = Scene::builtin(SceneKind::Blocks, 96, None, false).unwrap();
    let tilts = [45.0, 135.0, 225.0, 315.0];
    let frac = |slant: f64| {
        let lights = slant_tilt_lights(slant, &tilts);
        render(&scene, &lights, &noise_free(Brdf::Lambert))
            .unwrap()
            .stats
            .shadow_fraction
    };
    let (low, mid, high) = (frac(20.0), frac(35.0), frac(60.0));
    assert!(low < mid && mid < high, "{low} {mid} {high}");
}
