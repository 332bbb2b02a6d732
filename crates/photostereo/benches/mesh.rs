//! Mesh and depth writers on a 2048² (4 MP) surface: binary PLY, OBJ, and the depth files
//! (`depth.npy`, `depth.exr`, `depth.png`) plus `curl.npy` as `integrate --no-mesh` writes them.
//! Files go to a temporary folder, each sample a new file (the page cache: no fsync).
//! `cargo bench -p photostereo --bench mesh -- --warm-up-time 1 --measurement-time 5`

use criterion::{criterion_group, criterion_main, BatchSize, Criterion};
use photostereo::io::surface::{write_depth, write_mesh_obj, write_mesh_ply};
use std::hint::black_box;

/// A smooth 2048² depth map (pixels) with its unit normals.
fn surface(n: usize) -> (Vec<f32>, Vec<[f32; 3]>) {
    let k = std::f64::consts::TAU / n as f64;
    let amp = n as f64 / 40.0;
    let mut depth = vec![0f32; n * n];
    let mut normals = vec![[0f32; 3]; n * n];
    for r in 0..n {
        for c in 0..n {
            let (x, y) = (c as f64 * k, r as f64 * k);
            let i = r * n + c;
            depth[i] = (amp * (2.0 * x).sin() * (3.0 * y).cos()) as f32;
            let p = amp * k * 2.0 * (2.0 * x).cos() * (3.0 * y).cos();
            let q = -amp * k * 3.0 * (2.0 * x).sin() * (3.0 * y).sin();
            let norm = (p * p + q * q + 1.0).sqrt();
            normals[i] = [(-p / norm) as f32, (q / norm) as f32, (1.0 / norm) as f32];
        }
    }
    (depth, normals)
}

fn bench(c: &mut Criterion) {
    let n = 2048;
    let (depth, normals) = surface(n);
    let dir = tempfile::tempdir().unwrap();
    let mut g = c.benchmark_group("mesh_4mp");
    g.sample_size(10);
    // Each sample writes a new file: the previous one is removed outside the timing.
    let fresh = |name: &str| {
        let path = dir.path().join(name);
        let _ = std::fs::remove_file(&path);
        path
    };
    g.bench_function("ply", |b| {
        b.iter_batched(
            || fresh("m.ply"),
            |path| write_mesh_ply(&path, n, n, black_box(&depth), &normals),
            BatchSize::PerIteration,
        )
    });
    g.bench_function("obj", |b| {
        b.iter_batched(
            || fresh("m.obj"),
            |path| write_mesh_obj(&path, n, n, black_box(&depth), &normals),
            BatchSize::PerIteration,
        )
    });
    g.bench_function("depth_files", |b| {
        b.iter(|| write_depth(dir.path(), n, n, black_box(&depth)))
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
