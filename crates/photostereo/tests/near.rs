//! Near point lights and a perspective camera: the near model against the distant
//! approximation and against the oracle, on small near-light scenes; the near-light layout
//! read back from disk.

use photostereo::base::progress::Silent;
use photostereo::io::synth::write_near_capture;
use photostereo::method::engine::{reconstruct_with_truth, Method, Params};
use photostereo::scene::near::{oracle_error, synthesize_near, NearRendered, NearRig, NearSpec};
use photostereo::scene::{Brdf, SceneKind};
use photostereo::{Capture, CaptureFiles};

fn error(r: &NearRendered, capture: &Capture, method: Method) -> (f64, serde_json::Value) {
    let params = Params {
        method,
        ..Params::default()
    };
    let mut rec = reconstruct_with_truth(capture, &params, None, &Silent).unwrap();
    let e = rec.evaluate(&r.rendered.truth.normals).unwrap();
    (
        e.mean_deg,
        rec.report.extra.get("near").cloned().unwrap_or_default(),
    )
}

fn scene(rig: NearRig, size: usize) -> NearRendered {
    synthesize_near(&NearSpec {
        size,
        ..NearSpec::new(SceneKind::Sphere, rig)
    })
    .unwrap()
}

#[test]
fn the_near_model_is_exact_on_noise_free_lambertian_images() {
    // The oracle (true per-pixel light vectors, lit lights only) recovers the normals: the
    // renderer and the light model agree on the image formation.
    let r = synthesize_near(&NearSpec {
        size: 48,
        brdf: Brdf::Lambert,
        noise_sigma: 0.0,
        ..NearSpec::new(SceneKind::Sphere, NearRig::Ring)
    })
    .unwrap();
    let e = oracle_error(&r).unwrap();
    assert!(e < 0.05, "oracle {e}°");
}

#[test]
fn recursive_in_the_near_model_beats_the_distant_approximation() {
    for rig in [NearRig::Square, NearRig::Dome] {
        let r = scene(rig, 64);
        let (distant, _) = error(&r, &r.distant_capture().unwrap(), Method::L2);
        let (near, record) = error(&r, &r.capture().unwrap(), Method::Recursive);
        let oracle = oracle_error(&r).unwrap();
        assert!(
            near <= 0.25 * distant && near <= 2.0 * oracle,
            "{}: recursive near {near:.2}°, l2 distant {distant:.2}°, oracle {oracle:.2}°",
            rig.name()
        );
        let rounds = record["rounds"].as_array().unwrap();
        assert!(!rounds.is_empty() && rounds.len() <= 5);
        assert!(rounds[0]["mean_abs_depth_change_mm"].as_f64().unwrap() > 0.0);
    }
}

#[test]
fn the_ring_highlights_are_modelled_where_every_led_is_highlighted() {
    // With the LEDs beside the lens the glossy lobe covers every LED at once on the surfaces
    // facing the camera; the recursive method's estimate is refitted there with a lobe about
    // each half vector (near_lobe.rs) and reaches the acceptance: a quarter of the distant
    // error, within 2× of the oracle.
    for kind in [SceneKind::Sphere, SceneKind::Bumps] {
        let r = synthesize_near(&NearSpec {
            size: 64,
            ..NearSpec::new(kind, NearRig::Ring)
        })
        .unwrap();
        let (distant, _) = error(&r, &r.distant_capture().unwrap(), Method::L2);
        let (near, record) = error(&r, &r.capture().unwrap(), Method::Recursive);
        let oracle = oracle_error(&r).unwrap();
        assert!(
            near <= 0.25 * distant && near <= 2.0 * oracle,
            "{} ring: recursive near {near:.2}°, l2 distant {distant:.2}°, oracle {oracle:.2}°",
            kind.name()
        );
        let lobe = &record["highlight_lobe"];
        let m = lobe["exponent"].as_f64().unwrap();
        // The renderer's Blinn–Phong cos^100 is a Gaussian lobe of sharpness about 100.
        assert!((35.0..=280.0).contains(&m), "lobe sharpness {m}");
        assert!(lobe["refined_share"].as_f64().unwrap() > 0.05, "{lobe}");
    }
}

#[test]
fn four_lights_take_the_capture_lobe_out_where_no_light_is_spare() {
    // Under the four-LED square the blocks cast shadows across the highlights of the flat
    // ground: pixels left with three (or two) lit lights, one of them highlighted, where the χ²
    // test has nothing to compare. The capture's lobe, fitted where four lights are lit, is
    // the renderer's (Blinn–Phong cos^100 ≈ a Gaussian lobe of sharpness 100), and taken out
    // of those readings it brings the error within the acceptance.
    let r = synthesize_near(&NearSpec {
        size: 64,
        ..NearSpec::new(SceneKind::Blocks, NearRig::Square)
    })
    .unwrap();
    let (distant, _) = error(&r, &r.distant_capture().unwrap(), Method::L2);
    let (near, record) = error(&r, &r.capture().unwrap(), Method::Recursive);
    let lobe = &record["capture_lobe"];
    let m = lobe["lobe"]["exponent"].as_f64().unwrap();
    assert!((70.0..=140.0).contains(&m), "{lobe}");
    assert!(lobe["corrected_pixels"].as_u64().unwrap() > 50, "{lobe}");
    assert!(
        near <= 0.25 * distant,
        "blocks square: recursive near {near:.2}°, l2 distant {distant:.2}°"
    );
}

#[test]
fn lambertian_pixels_keep_the_recursive_estimate() {
    // Without highlights the lobe lowers no pixel's residual beyond the χ² quantile: (almost)
    // no pixel is refitted.
    let r = synthesize_near(&NearSpec {
        size: 48,
        brdf: Brdf::Lambert,
        ..NearSpec::new(SceneKind::Sphere, NearRig::Ring)
    })
    .unwrap();
    let (near, record) = error(&r, &r.capture().unwrap(), Method::Recursive);
    let share = record["highlight_lobe"]["refined_share"].as_f64().unwrap();
    assert!(share < 0.02, "refitted share {share}");
    // Their diffuse fits pass the χ² test (at its 95% confidence): only the test's false alarms
    // are fitted at all.
    let pixels = r.rendered.truth.mask.iter().filter(|&&m| m).count() as f64;
    let fitted = record["highlight_lobe"]["fitted_pixels"].as_f64().unwrap() / pixels;
    assert!(fitted < 0.1, "fitted share {fitted}");
    assert!(near < 1.0, "{near}°");
}

#[test]
fn every_method_uses_the_per_pixel_lights() {
    let r = scene(NearRig::Dome, 48);
    for method in [Method::L2, Method::BarskyPetrou] {
        let (distant, _) = error(&r, &r.distant_capture().unwrap(), method);
        let (near, _) = error(&r, &r.capture().unwrap(), method);
        assert!(
            near < 0.75 * distant,
            "{}: near {near} distant {distant}",
            method.name()
        );
    }
}

#[test]
fn the_near_layout_reads_back_from_disk_with_depth_in_mm() {
    let r = scene(NearRig::Square, 48);
    let dir = tempfile::tempdir().unwrap();
    write_near_capture(dir.path(), &r).unwrap();
    let files = CaptureFiles::from_inputs(&[dir.path().to_path_buf()], None, None, None).unwrap();
    assert!(files.lights.near.is_some());
    let capture = files.load(&Silent).unwrap();
    let params = Params {
        method: Method::L2,
        ..Params::default()
    };
    let mut from_disk = reconstruct_with_truth(&capture, &params, None, &Silent).unwrap();
    let e_disk = from_disk
        .evaluate(&r.rendered.truth.normals)
        .unwrap()
        .mean_deg;
    let (e_mem, _) = error(&r, &r.capture().unwrap(), Method::L2);
    assert!((e_disk - e_mem).abs() < 0.05, "{e_disk} vs {e_mem}");
    // Depth in mm along the optical axis: within a few mm of the truth (mean fixed by D).
    let depth = from_disk.depth().unwrap();
    let truth = &r.rendered.truth.depth;
    let (mut sum, mut count) = (0.0, 0);
    for (d, t) in depth.iter().zip(truth) {
        if d.is_finite() && t.is_finite() {
            sum += (d - t).abs() as f64;
            count += 1;
        }
    }
    assert!(
        sum / (count as f64) < 2.0,
        "mean |ΔZ| {} mm",
        sum / count as f64
    );
    // A missing distance is refused with the file named.
    std::fs::remove_file(dir.path().join("mean_distance.txt")).unwrap();
    let e = CaptureFiles::from_inputs(&[dir.path().to_path_buf()], None, None, None)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("mean_distance.txt") && e.contains("distance="),
        "{e}"
    );
}

/// DiLiGenT's camera (its calibration: fx 3772.08, fy 3759.01, cx 305.875, cy 255.125 pixels;
/// objects about 1.5 m away): its ground-truth normals integrated through the camera and
/// differentiated back are closer to the truth than with orthographic integration.
#[test]
fn perspective_integration_fits_diligent_ground_truth_better_than_orthographic() {
    use photostereo::geometry::integrate::perspective::{normals_from_z, perspective_surface};
    use photostereo::geometry::integrate::{normals_from_depth, surface_from_normals, Poisson};
    use photostereo::model::lightmodel::Camera;
    let root = std::path::PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../../shared/data/diligent"
    ));
    let camera = Camera::new(3772.08, 3759.01, 305.875, 255.125).unwrap();
    for object in ["ballPNG", "bearPNG", "catPNG"] {
        let map =
            photostereo::io::groundtruth::read_normal_map(&root.join(object).join("Normal_gt.mat"))
                .unwrap();
        let (w, h) = (map.width, map.height);
        // Both integrations see the same pixels: those facing the camera by n_z > 0 (the
        // perspective one would also keep grazing pixels that face the camera along their own
        // ray; their capped slopes are not what this test compares).
        let mask: Vec<bool> = map.normals.iter().map(|n| n[2] > 0.0).collect();
        // Scored away from the outline (pixels whose 5×5 neighbourhood is inside the mask),
        // where one-sided differences of either integration dominate.
        let inner: Vec<bool> = (0..w * h)
            .map(|i| {
                let (r, c) = ((i / w) as i64, (i % w) as i64);
                (-2..=2).all(|dr| {
                    (-2..=2).all(|dc| {
                        let (rr, cc) = (r + dr, c + dc);
                        rr >= 0
                            && cc >= 0
                            && rr < h as i64
                            && cc < w as i64
                            && mask[rr as usize * w + cc as usize]
                    })
                })
            })
            .collect();
        let mean_error = |normals: &[[f32; 3]]| {
            let (_, s) =
                photostereo::solve::metrics::evaluate(normals, &map.normals, Some(&inner)).unwrap();
            s.mean_deg
        };
        let ortho = surface_from_normals(
            w,
            h,
            &map.normals,
            Some(&mask),
            None,
            &Poisson::default(),
            photostereo::geometry::integrate::DEFAULT_MAX_SLOPE,
            &Silent,
        )
        .unwrap();
        let e_ortho = mean_error(&normals_from_depth(w, h, &ortho.depth.values, &mask));
        let persp = perspective_surface(
            w,
            h,
            &map.normals,
            Some(&mask),
            None,
            &camera,
            1500.0,
            &Poisson::default(),
            photostereo::geometry::integrate::DEFAULT_MAX_SLOPE,
            &Silent,
        )
        .unwrap();
        let e_persp = mean_error(&normals_from_z(w, h, &persp.depth.values, &mask, &camera));
        println!("{object}: orthographic {e_ortho:.3}°, perspective {e_persp:.3}°");
        assert!(
            e_persp < e_ortho,
            "{object}: perspective {e_persp}° vs orthographic {e_ortho}°"
        );
    }
}

/// The point-light shadow maps of the recursive method, from the true depth and normals, agree
/// with the renderer's shadows (an independent ray march against the analytic height field).
#[test]
fn point_light_shadow_maps_match_the_rendered_shadows() {
    let r = synthesize_near(&NearSpec {
        size: 64,
        ..NearSpec::new(SceneKind::Blocks, NearRig::Dome)
    })
    .unwrap();
    let t = &r.rendered.truth;
    let capture = r.capture().unwrap();
    let near = capture.lights.near.as_deref().unwrap();
    let maps = photostereo::geometry::shadows::near::near_shadow_maps(
        near,
        &t.depth,
        &t.normals,
        &t.mask,
        64,
        64,
        &photostereo::geometry::shadows::ShadowParams::default(),
    )
    .unwrap();
    let (mut agree, mut total, mut cast_truth, mut cast_found) = (0usize, 0usize, 0usize, 0usize);
    for k in 0..near.len() {
        for i in 0..64 * 64 {
            if !t.mask[i] {
                continue;
            }
            total += 1;
            let ours = maps.is_shadowed(k, i);
            agree += (ours == t.shadow[k][i]) as usize;
            if t.cast_shadow[k][i] {
                cast_truth += 1;
                cast_found += ours as usize;
            }
        }
    }
    let share = agree as f64 / total as f64;
    assert!(
        cast_truth > 100,
        "the scene must have cast shadows ({cast_truth})"
    );
    assert!(share > 0.97, "agreement {share}");
    assert!(
        cast_found as f64 > 0.8 * cast_truth as f64,
        "cast shadows found {cast_found} of {cast_truth}"
    );
}
