use photostereo::detect::DetectionParams;
use photostereo::estimate::Estimator;
use photostereo::progress::Silent;
use photostereo::recursive::{Recursive, RecursiveParams};
fn main() {
    let configs: Vec<(f64, f64)> = std::env::args()
        .skip(1)
        .map(|a| {
            let v: Vec<f64> = a.split(',').map(|x| x.parse().unwrap()).collect();
            (v[0], v[1])
        })
        .collect();
    for o in ["ball", "cat", "bear"] {
        let dir = std::path::PathBuf::from(format!("../shared/data/diligent/{o}PNG"));
        let cap = photostereo::CaptureFiles::diligent(&dir)
            .unwrap()
            .load(&Silent)
            .unwrap();
        let gt = photostereo::groundtruth::read_normal_map(&dir.join("Normal_gt.mat")).unwrap();
        let gtm: Vec<[f32; 3]> = cap.pixels.iter().map(|&i| gt.normals[i as usize]).collect();
        let mut line = format!("{o}:");
        for &(s0, k) in &configs {
            let det = DetectionParams {
                sigma: Some(s0 * 3f64.sqrt()),
                relative_noise: Some(k),
                ..Default::default()
            };
            let t = std::time::Instant::now();
            let est = Recursive {
                params: RecursiveParams {
                    detection: det,
                    ..Default::default()
                },
                truth: None,
            }
            .estimate(&cap, &Silent)
            .unwrap();
            let (_, s) = photostereo::metrics::evaluate(&est.normals, &gtm, None).unwrap();
            line += &format!(
                " ({s0},{k})={:.2}/{:.1}s",
                s.mean_deg,
                t.elapsed().as_secs_f64()
            );
        }
        println!("{line}");
    }
}
