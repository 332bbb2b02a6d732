use photostereo::scene::near::{oracle_error, synthesize_near, NearRig, NearSpec};
use photostereo::scene::{Brdf, SceneKind};
fn main() -> photostereo::Result<()> {
    for rig in [NearRig::Ring, NearRig::Square] {
        for brdf in [Brdf::Lambert, Brdf::BlinnPhong] {
            for noise in [0.0, 0.005] {
                let spec = NearSpec {
                    size: 128,
                    brdf,
                    noise_sigma: noise,
                    ..NearSpec::new(SceneKind::Sphere, rig)
                };
                let r = synthesize_near(&spec)?;
                println!(
                    "{} {} {noise}: oracle {:.2} shadow {:.3} hl {:.3} clip {:.3}",
                    rig.name(),
                    brdf.name(),
                    oracle_error(&r)?,
                    r.rendered.stats.shadow_fraction,
                    r.rendered.stats.highlight_fraction,
                    r.rendered.stats.clipped_fraction
                );
            }
        }
    }
    Ok(())
}
