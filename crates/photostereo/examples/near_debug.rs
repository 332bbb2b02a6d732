use photostereo::progress::Silent;
use photostereo::scene::near::{synthesize_near, NearRig, NearSpec};
use photostereo::scene::SceneKind;
fn main() -> photostereo::Result<()> {
    for scene in [SceneKind::Sphere, SceneKind::Bumps] {
        let r = synthesize_near(&NearSpec {
            size: 128,
            ..NearSpec::new(scene, NearRig::Ring)
        })?;
        let cap = r.capture()?;
        let t = &r.rendered.truth;
        cap.lights.near.as_deref().unwrap().set_surface(&t.depth);
        let n = cap.n_lights();
        let mut usable = vec![false; cap.n_pixels() * n];
        let mut few = 0;
        for (p, &i) in cap.pixels.iter().enumerate() {
            let mut c = 0;
            for k in 0..n {
                let ok = !t.shadow[k][i as usize] && !t.highlight[k][i as usize];
                usable[p * n + k] = ok;
                c += ok as usize;
            }
            if c < 3 {
                few += 1;
            }
        }
        let est = photostereo::lambert::solve_subsets(&cap, Some(&usable), &Silent);
        let nm = cap.scatter(&est.normals, 1, [0.0; 3]);
        let (_, s) = photostereo::metrics::evaluate(&nm, &t.normals, Some(&t.mask))?;
        println!(
            "{}: oracle without highlights {:.2}°, pixels with <3 clean lights {:.1}%",
            scene.name(),
            s.mean_deg,
            100.0 * few as f64 / cap.n_pixels() as f64
        );
    }
    Ok(())
}
