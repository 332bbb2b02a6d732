//! Peak memory of integrating a normal map, in bytes per frame pixel: each configuration
//! (`bilateral`/`poisson`, orthographic/perspective, the whole frame or the ellipse inscribed in
//! it, 79% of the frame, where `poisson` iterates) runs in a child process,
//! which makes its normal map, resets the kernel's peak-RSS mark (`/proc/self/clear_refs`),
//! runs [`integrate_normal_map`] and reports the peak resident memory above what it held
//! before (the normal map, 12 bytes a pixel, is not counted). Linux only.
//!
//! ```text
//! cargo run --release -p photostereo --example integrate_memory -- 4000 3000
//! ```

use photostereo::base::progress::Silent;
use photostereo::geometry::integrate::{
    integrate_normal_map, IntegratorKind, NormalMapIntegration,
};
use photostereo::model::lightmodel::Camera;
use std::time::Instant;

/// A field of the kernel's status of this process, in bytes (`VmRSS`, `VmHWM`).
fn status_bytes(field: &str) -> u64 {
    let status = std::fs::read_to_string("/proc/self/status").expect("/proc/self/status");
    status
        .lines()
        .find_map(|l| l.strip_prefix(field))
        .and_then(|v| {
            v.trim_start_matches(':')
                .split_whitespace()
                .next()?
                .parse::<u64>()
                .ok()
        })
        .expect("a VmRSS/VmHWM line")
        * 1024
}

/// Unit normals of a smooth relief (sums of sines, slopes below 1) over the whole frame.
fn relief(w: usize, h: usize) -> Vec<[f32; 3]> {
    let k = std::f64::consts::TAU / w.max(h) as f64;
    let amp = w.max(h) as f64 / 60.0;
    (0..w * h)
        .map(|i| {
            let (x, y) = ((i % w) as f64 * k, (i / w) as f64 * k);
            let p = amp * k * (2.0 * (2.0 * x).cos() * (3.0 * y).cos() - 0.5 * (x + 2.0 * y).sin());
            let q = amp * k * (-3.0 * (2.0 * x).sin() * (3.0 * y).sin() - (x + 2.0 * y).sin());
            let l = (1.0 + p * p + q * q).sqrt();
            [(-p / l) as f32, (q / l) as f32, (1.0 / l) as f32]
        })
        .collect()
}

fn child(w: usize, h: usize, method: IntegratorKind, perspective: bool, ellipse: bool) {
    let mut normals = relief(w, h);
    if ellipse {
        let (a, b) = (w as f64 / 2.0, h as f64 / 2.0);
        for (i, n) in normals.iter_mut().enumerate() {
            let (x, y) = (
                ((i % w) as f64 + 0.5 - a) / a,
                ((i / w) as f64 + 0.5 - b) / b,
            );
            if x * x + y * y > 1.0 {
                *n = [0.0; 3];
            }
        }
    }
    let camera = Camera::new(
        2.0 * w as f64,
        2.0 * w as f64,
        w as f64 / 2.0,
        h as f64 / 2.0,
    )
    .expect("a camera");
    std::fs::write("/proc/self/clear_refs", "5").expect("reset the peak RSS mark");
    let before = status_bytes("VmRSS");
    let t = Instant::now();
    let how = NormalMapIntegration {
        method,
        camera: perspective.then_some((&camera, 1000.0)),
        ..NormalMapIntegration::default()
    };
    let s = integrate_normal_map(w, h, &normals, None, None, &how, &Silent).expect("integration");
    let peak = status_bytes("VmHWM");
    let px = (w * h) as f64;
    println!(
        "{:<9} {:<12} {:<7}: peak {:>6.1} bytes/pixel above the normal map ({:.0} MB), {:.2} s, {} iterations",
        method.name(),
        if perspective { "perspective" } else { "orthographic" },
        if ellipse { "ellipse" } else { "frame" },
        (peak.saturating_sub(before)) as f64 / px,
        (peak.saturating_sub(before)) as f64 / 1e6,
        t.elapsed().as_secs_f64(),
        s.depth.stats.iterations,
    );
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let sizes: Vec<usize> = args.iter().filter_map(|a| a.parse().ok()).collect();
    let (w, h) = match sizes[..] {
        [w, h, ..] => (w, h),
        [n] => (n, n),
        [] => (4000, 3000),
    };
    if let Some(k) = args.iter().position(|a| a == "--child") {
        let method: IntegratorKind = args[k + 1].parse().expect("a method");
        child(
            w,
            h,
            method,
            args[k + 2] == "perspective",
            args[k + 3] == "ellipse",
        );
        return;
    }
    println!("{w} × {h}, threads: {}", rayon::current_num_threads());
    let me = std::env::current_exe().expect("this example's path");
    for method in [IntegratorKind::Bilateral, IntegratorKind::Poisson] {
        for projection in ["orthographic", "perspective"] {
            for mask in ["frame", "ellipse"] {
                let status = std::process::Command::new(&me)
                    .args([w.to_string(), h.to_string()])
                    .args(["--child", method.name(), projection, mask])
                    .status()
                    .expect("a child run");
                assert!(
                    status.success(),
                    "{} {projection} {mask} failed",
                    method.name()
                );
            }
        }
    }
}
