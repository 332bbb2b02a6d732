use photostereo::pipeline::{reconstruct, Method, RunOptions};
use photostereo::progress::Silent;
use photostereo::report::Report;
use photostereo::scene::{synthesize, Brdf, Rig, SceneKind, SynthSpec};
fn main() -> photostereo::Result<()> {
    let kind = SceneKind::ALL
        .iter()
        .copied()
        .find(|k| k.name() == std::env::args().nth(1).unwrap())
        .unwrap();
    let mut spec = SynthSpec::new(kind, Rig::parse("square4")?);
    spec.size = 128;
    spec.render.brdf = Brdf::BlinnPhong;
    spec.render.noise_sigma = 0.005;
    spec.render.seed = 1;
    let rendered = synthesize(&spec)?;
    let capture = rendered.capture()?;
    let t = &rendered.truth;
    for &method in &[Method::BarskyPetrou, Method::Recursive] {
        let options = RunOptions {
            method,
            ..RunOptions::default()
        };
        let rec = reconstruct(
            &capture,
            &options,
            Some(&t.normals),
            &Silent,
            &mut Report::new("x"),
        )?;
        let mut sum = [0.0f64; 8];
        let mut cnt = [0usize; 8];
        for i in 0..t.mask.len() {
            if !t.mask[i] {
                continue;
            }
            let ns = (0..4).filter(|&k| t.shadow[k][i]).count();
            let nh = (0..4).filter(|&k| t.highlight[k][i]).count();
            let cls = ns.min(3) + 4 * usize::from(nh > 0);
            let e = photostereo::metrics::angular_error_deg(rec.normals[i], t.normals[i]);
            sum[cls] += e;
            cnt[cls] += 1;
        }
        let total: f64 = sum.iter().sum::<f64>() / cnt.iter().sum::<usize>() as f64;
        println!("{} total {:.2}", method.name(), total);
        for c in 0..8 {
            if cnt[c] > 0 {
                println!(
                    "  shadows {} highlight {}: n={} mean={:.2} contrib={:.2}",
                    c % 4,
                    c / 4,
                    cnt[c],
                    sum[c] / cnt[c] as f64,
                    sum[c] / cnt.iter().sum::<usize>() as f64
                );
            }
        }
    }
    Ok(())
}
