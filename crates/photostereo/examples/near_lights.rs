//! Near-light figures: on near-light scenes rendered by `synth`, the mean angular
//! error of `l2` under the distant approximation, of every method in the near model, and of
//! the oracle (least squares on the truly lit lights with the true per-pixel light vectors).
//!
//! `cargo run --release -p photostereo --example near_lights [SIZE] [SCENE...]` (env `PS_KAPPA=0.01`
//! fixes κ instead of measuring it)

use photostereo::base::progress::Silent;
use photostereo::method::engine::{reconstruct_with_truth, Method, Params};
use photostereo::scene::near::{oracle_error, synthesize_near, NearRig, NearSpec};
use photostereo::scene::SceneKind;

fn main() -> photostereo::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let size: usize = args.first().and_then(|s| s.parse().ok()).unwrap_or(256);
    let scenes: Vec<SceneKind> = if args.len() > 1 {
        args[1..]
            .iter()
            .map(|s| s.parse())
            .collect::<Result<_, _>>()?
    } else {
        vec![SceneKind::Sphere, SceneKind::Bumps, SceneKind::Face]
    };
    println!("scene rig | l2 distant | l2 near | recursive near | oracle | recursive/distant | recursive/oracle | rounds");
    for &scene in &scenes {
        for &rig in NearRig::ALL {
            let spec = NearSpec {
                size,
                ..NearSpec::new(scene, rig)
            };
            let r = synthesize_near(&spec)?;
            let truth = &r.rendered.truth.normals;
            let err = |capture: &photostereo::Capture,
                       method: Method|
             -> photostereo::Result<(f64, usize)> {
                let mut params = Params {
                    method,
                    ..Params::default()
                };
                // PS_KAPPA=0.01 fixes κ (default: measured on the capture).
                if let Ok(k) = std::env::var("PS_KAPPA") {
                    params.detection.relative_noise = k.parse().ok();
                }
                let mut rec = reconstruct_with_truth(capture, &params, None, &Silent)?;
                let e = rec.evaluate(truth)?;
                let rounds = rec
                    .report
                    .extra
                    .get("near")
                    .and_then(|v| v.get("rounds"))
                    .and_then(|v| v.as_array())
                    .map_or(0, |a| a.len());
                if let Some(l) = rec
                    .report
                    .extra
                    .get("near")
                    .and_then(|v| v.get("highlight_lobe"))
                {
                    if !l.is_null() {
                        eprintln!(
                            "  {} {} {}: lobe {l}",
                            scene.name(),
                            rig.name(),
                            method.name()
                        );
                    }
                }
                Ok((e.mean_deg, rounds))
            };
            let distant = err(&r.distant_capture()?, Method::L2)?.0;
            let near_l2 = err(&r.capture()?, Method::L2)?.0;
            let (near_rec, rounds) = err(&r.capture()?, Method::Recursive)?;
            let oracle = oracle_error(&r)?;
            println!(
                "{} {} | {distant:.2} | {near_l2:.2} | {near_rec:.2} | {oracle:.2} | {:.0}% | {:.2}× | {rounds}",
                scene.name(),
                rig.name(),
                100.0 * near_rec / distant,
                near_rec / oracle
            );
        }
    }
    Ok(())
}
