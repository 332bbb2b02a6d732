//! Issue 19, item "a zero reading where the fit predicts a negative value is an attached shadow
//! in every method", with image noise: readings at the shadow level (the renderer's Gaussian
//! noise around 0, clipped at 0) on surface that faces away from the light are never labelled
//! highlights by the methods that drop lights. Measured: of 900 such readings, coleman-jain drops
//! 21, barsky-petrou 676, recursive 862, all labelled shadows.

use photostereo::base::progress::Silent;
use photostereo::method::engine::{reconstruct, Method, Params};
use photostereo::scene::{synthesize, Brdf, Rig, SceneKind, SynthSpec};
use photostereo::solve::lambert::status;

#[test]
fn noisy_attached_shadows_are_labelled_shadows() {
    let mut spec = SynthSpec::new(SceneKind::Sphere, Rig::Ring(8));
    spec.size = 64;
    spec.textured_albedo = false;
    spec.render.brdf = Brdf::Lambert;
    spec.render.noise_sigma = 0.005;
    let rendered = synthesize(&spec).unwrap();
    let capture = rendered.capture().unwrap();
    let n = capture.n_lights();
    let c = capture.channels;
    // The shadow level of the renderer's noise: 4σ above 0 (a reading of 0 plus noise).
    let level = 4.0 * spec.render.noise_sigma;
    for method in [Method::ColemanJain, Method::BarskyPetrou, Method::Recursive] {
        let params = Params {
            method,
            integrate: false,
            ..Params::default()
        };
        let rec = reconstruct(&capture, &params, &Silent).unwrap();
        let (mut dark, mut dropped, mut wrong) = (0usize, 0usize, 0usize);
        for (p, &i) in capture.pixels.iter().enumerate() {
            let nrm = rendered.truth.normals[i as usize];
            let samples = capture.pixel_samples(p);
            for k in 0..n {
                let l = capture.lights.directions[k];
                let facing = l[0] * nrm[0] as f64 + l[1] * nrm[1] as f64 + l[2] * nrm[2] as f64;
                let reading = samples[k * c..(k + 1) * c].iter().sum::<f32>() as f64 / c as f64;
                if facing >= 0.0 || reading > level {
                    continue;
                }
                dark += 1;
                let s = rec.light_status.get(k, i as usize);
                if s != status::USED {
                    dropped += 1;
                    wrong += usize::from(s != status::SHADOW);
                }
            }
        }
        let name = method.name();
        assert!(dark > 500, "{name}: only {dark} attached-shadow readings");
        assert_eq!(
            wrong, 0,
            "{name}: {wrong}/{dropped} dropped dark readings not shadows"
        );
        // Coleman & Jain looks for highlights only and may keep them; the others drop enough
        // of them for the labels to be checked (near the terminator, where the fit predicts
        // about 0, a dark reading is no fault and stays).
        if method != Method::ColemanJain {
            assert!(dropped > 300, "{name}: dropped {dropped} of {dark}");
        }
        println!("{name}: {dark} attached-shadow readings, {dropped} dropped, {wrong} not shadows");
    }
}
