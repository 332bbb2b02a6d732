use photostereo::progress::Silent;
fn main() {
    for o in ["ball", "cat", "bear"] {
        let dir = std::path::PathBuf::from(format!("../shared/data/diligent/{o}PNG"));
        let cap = photostereo::CaptureFiles::diligent(&dir)
            .unwrap()
            .load(&Silent)
            .unwrap();
        let (w, h) = (cap.width, cap.height);
        let mut index = vec![usize::MAX; w * h];
        for (p, &i) in cap.pixels.iter().enumerate() {
            index[i as usize] = p;
        }
        let n = cap.n_lights();
        let c = cap.channels;
        let grey = |p: usize, k: usize| {
            cap.pixel_samples(p)[k * c..(k + 1) * c].iter().sum::<f32>() / c as f32
        };
        let mut sig = Vec::new();
        let mut levels = Vec::new();
        for k in 0..n {
            let mut vals = Vec::new();
            let mut lv = Vec::new();
            for (p, &i) in cap.pixels.iter().enumerate() {
                let (r, cc) = (i as usize / w, i as usize % w);
                if r == 0 || cc == 0 || r + 1 >= h || cc + 1 >= w {
                    continue;
                }
                let mut acc = 0.0f32;
                let mut ok = true;
                for (dr, dc, m) in [
                    (-1i32, -1i32, 1.0f32),
                    (-1, 0, -2.0),
                    (-1, 1, 1.0),
                    (0, -1, -2.0),
                    (0, 0, 4.0),
                    (0, 1, -2.0),
                    (1, -1, 1.0),
                    (1, 0, -2.0),
                    (1, 1, 1.0),
                ] {
                    let q = index[((r as i32 + dr) as usize) * w + (cc as i32 + dc) as usize];
                    if q == usize::MAX {
                        ok = false;
                        break;
                    }
                    acc += m * grey(q, k);
                }
                if ok {
                    vals.push(acc.abs() as f64);
                    lv.push(grey(p, k) as f64);
                }
            }
            let med = photostereo::metrics::median(&mut vals);
            sig.push(1.4826 * med / 6.0);
            levels.push(photostereo::metrics::median(&mut lv));
        }
        let s = photostereo::metrics::median(&mut sig.clone());
        println!("{o}: image noise (grey, normalised) median over lights {:.5}; min {:.5} max {:.5}; median level {:.4}", s, sig.iter().cloned().fold(1.0, f64::min), sig.iter().cloned().fold(0.0, f64::max), photostereo::metrics::median(&mut levels));
    }
}
