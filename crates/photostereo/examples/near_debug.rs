use photostereo::estimate::{ColemanJain, Estimator, LeastSquares};
use photostereo::progress::Silent;
use photostereo::scene::near::{synthesize_near, NearRig, NearSpec};
use photostereo::scene::{Brdf, SceneKind};
fn main() -> photostereo::Result<()> {
    for brdf in [Brdf::Lambert, Brdf::BlinnPhong] {
        let spec = NearSpec {
            size: 64,
            brdf,
            ..NearSpec::new(SceneKind::Sphere, NearRig::Dome)
        };
        let r = synthesize_near(&spec)?;
        let truth = &r.rendered.truth;
        for (name, cap) in [("near", r.capture()?), ("distant", r.distant_capture()?)] {
            if let Some(m) = cap.lights.near.as_deref() {
                m.set_surface(&truth.depth);
            }
            for (en, est) in [
                ("l2", LeastSquares.estimate(&cap, &Silent)?),
                ("cj", ColemanJain::default().estimate(&cap, &Silent)?),
            ] {
                let n = cap.scatter(&est.normals, 1, [0.0; 3]);
                if let Some(st) = &est.light_status {
                    println!(
                        "removed share {:.3}",
                        st.iter().filter(|&&x| x != 0).count() as f64 / st.len() as f64
                    );
                }
                let (_, s) = photostereo::metrics::evaluate(&n, &truth.normals, Some(&truth.mask))?;
                println!("{} {name} {en}: {:.2}", brdf.name(), s.mean_deg);
            }
        }
    }
    Ok(())
}
