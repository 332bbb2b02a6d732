//! Integration benchmarks: `poisson` on a full 4096² grid and on a 1024² irregular mask, `dct`
//! on a full 1024² grid; `poisson` on a full rectangle solves directly by the DCT unless
//! `direct_on_rectangle` is off (`poisson_multigrid_full_1024`). Keep runs short:
//! `RAYON_NUM_THREADS=2 cargo bench -p photostereo --bench integrate -- --warm-up-time 1 --measurement-time 3`
//! (the 4096² case alone takes several seconds per sample; filter it with `poisson_full_4096`).

use criterion::{criterion_group, criterion_main, Criterion};
use photostereo::base::progress::Silent;
use photostereo::geometry::integrate::{Dct, IntegrationProblem, Integrator, Poisson};
use std::hint::black_box;

#[path = "support/grids.rs"]
mod grids;
use grids::irregular_mask;

/// Gradients of a smooth bumpy surface on an n × n grid (sums of sines; depth range ≈ n / 10).
fn gradients(n: usize) -> (Vec<f32>, Vec<f32>) {
    let k = std::f64::consts::TAU / n as f64;
    let amp = n as f64 / 40.0;
    let mut p = vec![0f32; n * n];
    let mut q = vec![0f32; n * n];
    for r in 0..n {
        for c in 0..n {
            let (x, y) = (c as f64 * k, r as f64 * k);
            // f = amp (sin 2x cos 3y + 0.5 cos(x + 2y))
            p[r * n + c] =
                (amp * k * (2.0 * (2.0 * x).cos() * (3.0 * y).cos() - 0.5 * (x + 2.0 * y).sin()))
                    as f32;
            q[r * n + c] =
                (amp * k * (-3.0 * (2.0 * x).sin() * (3.0 * y).sin() - (x + 2.0 * y).sin())) as f32;
        }
    }
    (p, q)
}

fn bench(c: &mut Criterion) {
    let mut g = c.benchmark_group("integrate");
    g.sample_size(10);
    {
        let n = 1024;
        let (p, q) = gradients(n);
        let mask = irregular_mask(n);
        let problem = IntegrationProblem::new(n, n, &p, &q, &mask);
        g.bench_function("poisson_irregular_1024", |b| {
            b.iter(|| black_box(Poisson::default().integrate(&problem, &Silent).unwrap()))
        });
        let full = vec![true; n * n];
        let problem = IntegrationProblem::new(n, n, &p, &q, &full);
        g.bench_function("dct_full_1024", |b| {
            b.iter(|| black_box(Dct::default().integrate(&problem, &Silent).unwrap()))
        });
        g.bench_function("poisson_full_1024", |b| {
            b.iter(|| black_box(Poisson::default().integrate(&problem, &Silent).unwrap()))
        });
        // The same problem by multigrid CG (what any mask or weight gets).
        let multigrid = Poisson {
            direct_on_rectangle: false,
            ..Poisson::default()
        };
        g.bench_function("poisson_multigrid_full_1024", |b| {
            b.iter(|| black_box(multigrid.integrate(&problem, &Silent).unwrap()))
        });
    }
    {
        let n = 4096;
        let (p, q) = gradients(n);
        let full = vec![true; n * n];
        let problem = IntegrationProblem::new(n, n, &p, &q, &full);
        g.bench_function("poisson_full_4096", |b| {
            b.iter(|| black_box(Poisson::default().integrate(&problem, &Silent).unwrap()))
        });
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
