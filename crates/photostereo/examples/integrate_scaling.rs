//! Prints `poisson`'s CG iteration counts (to 1e-6 relative residual) and wall times on full
//! grids and on an irregular mask, from 256² to 4096² (`--method bilateral` for that
//! integrator: its CG iterations over all reweightings; `--full` for the full grids only). For peak memory run one size under
//! `/usr/bin/time -v`:
//!
//! ```text
//! cargo run --release -p photostereo --example integrate_scaling -- 256 512 1024 2048 4096
//! /usr/bin/time -v target/release/examples/integrate_scaling 4096
//! ```

use photostereo::base::progress::Silent;
use photostereo::geometry::integrate::{IntegrationProblem, IntegratorKind, Poisson};
use std::time::Instant;

#[path = "../benches/support/grids.rs"]
mod grids;
use grids::irregular_mask;

/// Gradients of a peaks-like surface scaled to an n × n grid (depth range ≈ n / 8 pixels).
pub fn peaks_gradients(n: usize) -> (Vec<f32>, Vec<f32>) {
    let s = n as f64 / 6.0;
    let amp = n as f64 / 64.0;
    let mut p = vec![0f32; n * n];
    let mut q = vec![0f32; n * n];
    for r in 0..n {
        for c in 0..n {
            let (u, v) = (
                (c as f64 - n as f64 / 2.0) / s,
                (r as f64 - n as f64 / 2.0) / s,
            );
            let e1 = (-u * u - (v + 1.0).powi(2)).exp();
            let e2 = (-u * u - v * v).exp();
            let e3 = (-(u + 1.0).powi(2) - v * v).exp();
            let a = 3.0 * (1.0 - u).powi(2);
            let b = 10.0 * (u / 5.0 - u.powi(3) - v.powi(5));
            let du = -6.0 * (1.0 - u) * e1 - 2.0 * u * a * e1 - 10.0 * (0.2 - 3.0 * u * u) * e2
                + 2.0 * u * b * e2
                + 2.0 * (u + 1.0) * e3 / 3.0;
            let dv = -2.0 * (v + 1.0) * a * e1
                + 50.0 * v.powi(4) * e2
                + 2.0 * v * b * e2
                + 2.0 * v * e3 / 3.0;
            p[r * n + c] = (amp * du / s) as f32;
            q[r * n + c] = (amp * dv / s) as f32;
        }
    }
    (p, q)
}

/// CPU seconds (user + system) used by this process so far, from `/proc/self/stat` (Linux; 0
/// elsewhere). On a loaded machine wall time overstates the cost; CPU time does not.
fn cpu_seconds() -> f64 {
    let Ok(stat) = std::fs::read_to_string("/proc/self/stat") else {
        return 0.0;
    };
    // Fields after the parenthesised command name; utime and stime are fields 14 and 15.
    let rest = stat.rsplit(')').next().unwrap_or("");
    let fields: Vec<&str> = rest.split_whitespace().collect();
    let ticks = |k: usize| {
        fields
            .get(k)
            .and_then(|v| v.parse::<f64>().ok())
            .unwrap_or(0.0)
    };
    (ticks(11) + ticks(12)) / 100.0
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let method = args
        .iter()
        .position(|a| a == "--method")
        .map(|k| args[k + 1].parse::<IntegratorKind>().expect("a method"))
        .unwrap_or(IntegratorKind::Poisson);
    let full_only = args.iter().any(|a| a == "--full");
    let sizes: Vec<usize> = args.iter().filter_map(|a| a.parse().ok()).collect();
    let sizes = if sizes.is_empty() {
        vec![256, 512, 1024, 2048, 4096]
    } else {
        sizes
    };
    println!(
        "{}, threads: {}",
        method.name(),
        rayon::current_num_threads()
    );
    for &n in &sizes {
        let (p, q) = peaks_gradients(n);
        for (label, mask) in [
            ("full", vec![true; n * n]),
            ("irregular", irregular_mask(n)),
        ] {
            if label == "irregular" && (n > 2048 || full_only) {
                continue;
            }
            let problem = IntegrationProblem::new(n, n, &p, &q, &mask);
            let t = Instant::now();
            let cpu = cpu_seconds();
            let integrator = match method {
                IntegratorKind::Poisson => Box::new(Poisson::default()),
                other => other.integrator(),
            };
            let d = integrator
                .integrate(&problem, &Silent)
                .expect("integration");
            println!(
                "{n:>5}² {label:<9}: {:>2} iterations ({} reweightings), relative residual {:.2e}, {} levels, {} components, {:.3} s wall, {:.2} s CPU",
                d.stats.iterations,
                d.stats.reweightings,
                d.stats.relative_residual,
                d.stats.levels,
                d.stats.components,
                t.elapsed().as_secs_f64(),
                cpu_seconds() - cpu
            );
        }
    }
}
