//! Issues 19 and 17 (item 3) on the real captures in `../shared/data` and on renders: what the
//! shadow labels mean, Coleman & Jain's completeness, attached shadows labelled as shadows by
//! every method, the `gray` sphere against its outline, and the recursion's convergence report.
//! The figures behind them: `cargo run --release -p photostereo --example real_figures`.

use photostereo::base::progress::Silent;
use photostereo::io::layouts::CaptureFiles;
use photostereo::method::engine::{reconstruct, Method, Params};
use photostereo::model::capture::Capture;
use photostereo::scene::{
    lambert_capture, ring_lights, sphere_on_plane, synthesize, Brdf, Rig, SceneKind, SynthSpec,
};
use photostereo::solve::lambert::status;
use photostereo::solve::metrics::{circle_from_mask, roughness_deg, sphere_errors};
use std::path::PathBuf;

fn data(rel: &str) -> PathBuf {
    PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../../shared/data")).join(rel)
}

const PSM: [&str; 6] = ["buddha", "cat", "gray", "horse", "owl", "rock"];

fn psm(name: &str) -> Capture {
    CaptureFiles::list_file(
        &data(&format!("psmImages/{name}.txt")),
        &data("psmImages/lights.reference.txt"),
    )
    .unwrap()
    .load(&Silent)
    .unwrap()
}

fn run(capture: &Capture, method: Method) -> photostereo::method::engine::Reconstruction {
    let params = Params {
        method,
        integrate: false,
        ..Params::default()
    };
    reconstruct(capture, &params, &Silent).unwrap()
}

/// Of the pairs the recursive method labels "shadow", fewer than 20% read more than half of the
/// Lambertian prediction (it was 73–94% on psmImages when darker-than-predicted meant shadow);
/// Coleman & Jain gives every mask pixel that least squares solves a normal; the recursion
/// settles within its default limit. With κ measured on the capture (the default) the χ² test
/// flags a third of the pixels on average (0.19–0.51, a minority on five of the six; 0.68–0.98
/// at κ = 1%) and the recursive field is smoother than `l2`'s on every object (roughness 3–23%
/// lower; at κ = 1% it was higher on four of the six); the gray sphere's error is below `l2`'s
/// in mean and 90th percentile.
#[test]
fn psm_shadow_labels_completeness_and_sphere() {
    let mut flagged = Vec::new();
    for name in PSM {
        let capture = psm(name);
        let l2 = run(&capture, Method::L2);
        let rec = run(&capture, Method::Recursive);
        let labels = &rec.report.extra["detection"]["shadow_labels"];
        let lit = labels["lit"].as_f64().unwrap();
        assert!(lit < 0.2, "{name}: {lit} of the shadow pairs read lit");
        let r = &rec.report.extra["recursive"];
        assert!(r["converged"].is_boolean() && r["final_change"].is_f64());
        assert!(!r["stop_reason"].as_str().unwrap().is_empty());
        // With the oscillation rule the usable sets settle within the default limit (they
        // stopped at the limit, 0.4–1% of the pixels still changing, on four of the six).
        assert_eq!(r["converged"], true, "{name}: {}", r["stop_reason"]);
        assert!(r["final_change"].as_f64().unwrap() < 0.002, "{name}");
        let (w, h) = (rec.width, rec.height);
        let rough = |n: &[[f32; 3]]| roughness_deg(n, &rec.mask, w, h);
        let unreliable = rec.report.extra["detection"]["unreliable_share"]
            .as_f64()
            .unwrap();
        let (rough_l2, rough_rec) = (rough(&l2.normals), rough(&rec.normals));
        println!(
            "{name}: roughness l2 {rough_l2:.2} recursive {rough_rec:.2}; shadow pairs lit {lit:.3}; unreliable {unreliable:.3}; {}",
            r["stop_reason"]
        );
        assert!(
            unreliable < 0.6,
            "{name}: the test flags {unreliable} of the pixels"
        );
        flagged.push(unreliable);
        assert!(
            rough_rec < rough_l2,
            "{name}: roughness recursive {rough_rec:.3} against l2 {rough_l2:.3}"
        );
        let cj = run(&capture, Method::ColemanJain);
        let missing = l2
            .normals
            .iter()
            .zip(&cj.normals)
            .zip(&rec.mask)
            .filter(|((a, b), &m)| m && **a != [0.0; 3] && **b == [0.0; 3])
            .count();
        assert_eq!(missing, 0, "{name}: coleman-jain left {missing} pixels");
        if name == "gray" {
            let circle = circle_from_mask(&rec.mask, w, h).unwrap();
            let mean = |n: &[[f32; 3]]| {
                let e = sphere_errors(n, w, circle, 0.9);
                e.iter().sum::<f64>() / e.len() as f64
            };
            let (a, b) = (mean(&l2.normals), mean(&rec.normals));
            let p90 = |n: &[[f32; 3]]| {
                photostereo::solve::metrics::quantile(&mut sphere_errors(n, w, circle, 0.9), 0.9)
            };
            let (pa, pb) = (p90(&l2.normals), p90(&rec.normals));
            println!(
                "gray sphere, inner 90%: mean l2 {a:.3} recursive {b:.3}; p90 l2 {pa:.3} recursive {pb:.3}"
            );
            assert!(b < a, "gray: recursive {b} against l2 {a}");
            assert!(pb < pa, "gray p90: recursive {pb} against l2 {pa}");
        }
    }
    let mean = flagged.iter().sum::<f64>() / flagged.len() as f64;
    assert!(
        mean < 0.4,
        "the test flags {mean} of the pixels on average: {flagged:?}"
    );
}

/// A zero reading where the surface faces away from the light is an attached shadow for every
/// method that drops lights: never labelled a highlight.
#[test]
fn attached_shadows_are_labelled_shadows() {
    let scene = sphere_on_plane(64);
    let lights = ring_lights(8, 60.0);
    let (capture, _) = lambert_capture(&scene, &lights).unwrap();
    let n = capture.n_lights();
    for method in [Method::ColemanJain, Method::BarskyPetrou, Method::Recursive] {
        let rec = run(&capture, method);
        let (mut zeros, mut wrong) = (0, 0);
        for (p, &i) in capture.pixels.iter().enumerate() {
            let nrm = scene.normals[i as usize];
            for k in 0..n {
                let l = capture.lights.directions[k];
                let facing = l[0] * nrm[0] as f64 + l[1] * nrm[1] as f64 + l[2] * nrm[2] as f64;
                let reading = capture.pixel_samples(p)[k * capture.channels];
                let s = rec.light_status.get(k, i as usize);
                if facing < 0.0 && reading == 0.0 && s != status::USED {
                    zeros += 1;
                    wrong += usize::from(s != status::SHADOW);
                }
            }
        }
        // Coleman & Jain may drop none of them (it looks for highlights only).
        assert!(
            zeros > 100 || method == Method::ColemanJain,
            "{}: {zeros}",
            method.name()
        );
        assert_eq!(wrong, 0, "{}: {wrong}/{zeros} not shadows", method.name());
    }
}

/// A 64² sphere under the eight-light ring used to cycle between the same usable-light sets
/// (period 2, "not converged"); with the attribution's hysteresis (a set that passed the test
/// and agrees with the new surface's shadows stays) it settles within the default limit and
/// says so. (The stop rule's cycle, stall and limit verdicts are unit-tested in
/// `recursive::stop_tests`.)
#[test]
fn the_recursion_settles_where_it_used_to_cycle() {
    let mut spec = SynthSpec::new(SceneKind::Sphere, Rig::Ring(8));
    spec.size = 64;
    spec.render.brdf = Brdf::BlinnPhong;
    let capture = synthesize(&spec).unwrap().capture().unwrap();
    let params = Params {
        integrate: false,
        ..Params::default()
    };
    let rec = reconstruct(&capture, &params, &Silent).unwrap();
    let r = &rec.report.extra["recursive"];
    let iterations = r["iterations"].as_array().unwrap().len();
    assert_eq!(r["converged"], true, "{r}");
    assert!(iterations < params.recursive.max_iterations, "{iterations}");
    let reason = r["stop_reason"].as_str().unwrap();
    assert!(reason.starts_with("converged after"), "{reason}");
    assert!(r["final_change"].as_f64().unwrap() < params.recursive.change_tolerance);
    assert!(!rec.report.notes.iter().any(|n| n.contains("not converged")));
}
