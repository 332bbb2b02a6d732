//! The recursive method's reflectance model (`reflectance`, [`photostereo::solve::gloss`]) on
//! renders with known BRDFs: highlights modelled with a lobe lower the normal error where
//! lobes are present, leave a matte render and a four-light capture as they were, and the
//! fitted lobe's strength and roughness agree with the renderer's.

use photostereo::base::progress::Silent;
use photostereo::method::engine::{reconstruct, Params, Reconstruction};
use photostereo::method::recursive::RecursiveParams;
use photostereo::scene::reflectance::{BLINN_PHONG_EXPONENT, BLINN_PHONG_KS};
use photostereo::scene::{synthesize, Brdf, Rendered, Rig, SceneKind, SynthSpec};
use photostereo::solve::gloss::Reflectance;
use photostereo::solve::metrics::evaluate;

fn render(rig: &str, brdf: Brdf) -> Rendered {
    let mut spec = SynthSpec::new(SceneKind::Sphere, Rig::parse(rig).unwrap());
    spec.size = 128;
    spec.render.brdf = brdf;
    spec.render.noise_sigma = 0.005;
    spec.render.seed = 1;
    synthesize(&spec).unwrap()
}

/// The recursive reconstruction with `reflectance` and its mean error against the truth.
fn run(rendered: &Rendered, reflectance: Reflectance) -> (Reconstruction, f64) {
    let capture = rendered.capture().unwrap();
    let params = Params {
        recursive: RecursiveParams {
            reflectance,
            ..RecursiveParams::default()
        },
        ..Params::default()
    };
    let rec = reconstruct(&capture, &params, &Silent).unwrap();
    let truth = &rendered.truth;
    let (_, s) = evaluate(&rec.normals, &truth.normals, Some(&truth.mask)).unwrap();
    (rec, s.mean_deg)
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

#[test]
fn blinn_phong_lobes_lower_the_error_and_are_recovered() {
    let rendered = render("dome-20", Brdf::BlinnPhong);
    let (_, lambert) = run(&rendered, Reflectance::Lambert);
    let (rec, auto) = run(&rendered, Reflectance::Auto);
    assert!(
        auto < 0.8 * lambert,
        "auto {auto:.3}° vs lambert {lambert:.3}°"
    );
    let maps = rec.recursive.as_ref().unwrap().gloss.as_ref().unwrap();
    let fitted: Vec<usize> = (0..maps.strength.len())
        .filter(|&i| maps.strength[i] > 0.0)
        .collect();
    assert!(fitted.len() > 1000, "{} pixels with a lobe", fitted.len());
    // The renderer's lobe k_s (n·h)^e peaks at k_s (unit lights), and (n·h)^e ≈ exp(−e (1 − n·h))
    // near its peak: roughness √(2/e).
    let strength = median(fitted.iter().map(|&i| maps.strength[i] as f64).collect());
    let roughness = median(fitted.iter().map(|&i| maps.roughness[i] as f64).collect());
    let known = (2.0 / BLINN_PHONG_EXPONENT).sqrt();
    eprintln!(
        "error {lambert:.3}° → {auto:.3}°; {} pixels with a lobe: median strength {strength:.3} \
         (k_s {BLINN_PHONG_KS}), roughness {roughness:.4} ({known:.4})",
        fitted.len()
    );
    assert!(
        (strength / BLINN_PHONG_KS - 1.0).abs() < 0.15,
        "strength {strength:.3} against k_s {BLINN_PHONG_KS}"
    );
    assert!(
        (roughness / known - 1.0).abs() < 0.15,
        "roughness {roughness:.4} against {known:.4}"
    );
}

#[test]
fn torrance_sparrow_lobes_lower_the_error() {
    let rendered = render("dome-50", Brdf::TorranceSparrow);
    let (_, lambert) = run(&rendered, Reflectance::Lambert);
    let (_, auto) = run(&rendered, Reflectance::Auto);
    assert!(
        auto < 0.8 * lambert,
        "auto {auto:.3}° vs lambert {lambert:.3}°"
    );
}

#[test]
fn a_matte_render_keeps_its_error() {
    let rendered = render("dome-20", Brdf::Lambert);
    let (_, lambert) = run(&rendered, Reflectance::Lambert);
    let (_, auto) = run(&rendered, Reflectance::Auto);
    assert!(
        (auto - lambert).abs() <= 0.05,
        "auto {auto:.3}° vs lambert {lambert:.3}°"
    );
}

#[test]
fn four_lights_leave_nothing_to_fit() {
    let rendered = render("square4", Brdf::BlinnPhong);
    let (plain, _) = run(&rendered, Reflectance::Lambert);
    let (rec, _) = run(&rendered, Reflectance::Auto);
    assert_eq!(rec.normals, plain.normals);
}
