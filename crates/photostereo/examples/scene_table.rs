//! Prints the mean angular error of every method on the six built-in scenes under a rig, and
//! the IoU of the recursive method's final shadow maps with the ground truth.
//! `cargo run --release -p photostereo --example scene_table -- square4 ring8 dome-20`
//! (`FALLBACK=brightest` or `UW=0.0` vary the recursive method's fallback and unreliable weight).
use photostereo::pipeline::{reconstruct, Method, RunOptions};
use photostereo::progress::Silent;
use photostereo::report::Report;
use photostereo::scene::{synthesize, Brdf, Rig, SceneKind, SynthSpec};

fn main() -> photostereo::Result<()> {
    let rigs: Vec<String> = std::env::args().skip(1).collect();
    for rig in rigs {
        println!("rig {rig}");
        let mut means = vec![0.0; Method::ALL.len()];
        let (mut iou_sum, mut iou_n) = (0.0, 0);
        for &kind in SceneKind::ALL {
            let mut spec = SynthSpec::new(kind, Rig::parse(&rig)?);
            spec.size = 128;
            spec.render.brdf = Brdf::BlinnPhong;
            spec.render.noise_sigma = 0.005;
            spec.render.seed = 1;
            let rendered = synthesize(&spec)?;
            let capture = rendered.capture()?;
            let truth = &rendered.truth;
            let mut line = format!("{:<10}", kind.name());
            for (i, &method) in Method::ALL.iter().enumerate() {
                let mut options = RunOptions {
                    method,
                    ..RunOptions::default()
                };
                if let Ok(f) = std::env::var("FALLBACK") {
                    options.recursive.fallback = f.parse()?;
                }
                if let Ok(f) = std::env::var("UW") {
                    options.recursive.unreliable_weight = f.parse().map_err(|_| {
                        photostereo::Error::invalid(format!("UW={f}: not a number"))
                    })?;
                }
                let mut report = Report::new(method.name());
                let rec = reconstruct(
                    &capture,
                    &options,
                    Some(&truth.normals),
                    &Silent,
                    &mut report,
                )?;
                let (_, s) = photostereo::metrics::evaluate(
                    &rec.normals,
                    &truth.normals,
                    Some(&truth.mask),
                )?;
                means[i] += s.mean_deg / SceneKind::ALL.len() as f64;
                line += &format!(" {}={:.2}", method.name(), s.mean_deg);
                if let Some(r) = &rec.recursive {
                    let (mut inter, mut uni) = (0usize, 0usize);
                    for k in 0..capture.n_lights() {
                        let est = r.shadows.union(k);
                        for i in 0..est.len() {
                            if truth.mask[i] {
                                let (a, b) = (est[i], truth.shadow[k][i]);
                                inter += usize::from(a && b);
                                uni += usize::from(a || b);
                            }
                        }
                    }
                    let iou = inter as f64 / uni.max(1) as f64;
                    iou_sum += iou;
                    iou_n += 1;
                    line += &format!(" iou={iou:.3} it={}", r.iterations.len());
                }
            }
            println!("{line}");
        }
        let l2 = means[0];
        println!(
            "mean: {}  recursive/l2 = {:.2}  shadow IoU {:.3}",
            Method::ALL
                .iter()
                .zip(&means)
                .map(|(m, v)| format!("{}={v:.2}", m.name()))
                .collect::<Vec<_>>()
                .join(" "),
            means[Method::ALL.len() - 1] / l2,
            iou_sum / iou_n as f64
        );
    }
    Ok(())
}
