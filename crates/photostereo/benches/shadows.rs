//! Shadow maps of a 612×512 height field (DiLiGenT size) under the 96 DiLiGenT lights, against
//! the per-pixel ray march of one light. Run:
//! `cargo bench -p photostereo --bench shadows -- --warm-up-time 1 --measurement-time 3`

use criterion::{criterion_group, criterion_main, Criterion};
use photostereo::geometry::shadows::{
    cast_shadows, cast_shadows_ray_march, shadow_maps, ShadowParams,
};
use std::hint::black_box;
use std::path::Path;

const WIDTH: usize = 612;
const HEIGHT: usize = 512;

/// An elliptical object of smooth bumps (heights up to ~60 px) with its normals.
fn field() -> (Vec<f32>, Vec<[f32; 3]>, Vec<bool>) {
    let mut seed = 0x5eed_u64;
    let mut next = || {
        seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (seed >> 11) as f64 / (1u64 << 53) as f64
    };
    let bumps: Vec<[f64; 4]> = (0..40)
        .map(|_| {
            [
                next() * WIDTH as f64,
                next() * HEIGHT as f64,
                -15.0 + 60.0 * next(),
                10.0 + 40.0 * next(),
            ]
        })
        .collect();
    let f = |x: f64, y: f64| -> f64 {
        bumps
            .iter()
            .map(|b| {
                b[2] * (-((x - b[0]).powi(2) + (y - b[1]).powi(2)) / (2.0 * b[3] * b[3])).exp()
            })
            .sum()
    };
    let (cx, cy) = (WIDTH as f64 / 2.0, HEIGHT as f64 / 2.0);
    let mut depth = vec![f32::NAN; WIDTH * HEIGHT];
    let mut normals = vec![[0f32; 3]; WIDTH * HEIGHT];
    let mut mask = vec![false; WIDTH * HEIGHT];
    for row in 0..HEIGHT {
        for col in 0..WIDTH {
            let (x, y) = (col as f64, row as f64);
            if ((x - cx) / (0.45 * WIDTH as f64)).powi(2)
                + ((y - cy) / (0.45 * HEIGHT as f64)).powi(2)
                < 1.0
            {
                let i = row * WIDTH + col;
                mask[i] = true;
                depth[i] = f(x, y) as f32;
                let p = (f(x + 0.5, y) - f(x - 0.5, y)) as f32; // ∂f/∂col
                let q = (f(x, y + 0.5) - f(x, y - 0.5)) as f32; // ∂f/∂row
                let n = (p * p + q * q + 1.0).sqrt();
                normals[i] = [-p / n, q / n, 1.0 / n];
            }
        }
    }
    (depth, normals, mask)
}

fn lights() -> Vec<[f64; 3]> {
    let path = Path::new(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../../shared/data/diligent/ballPNG/light_directions.txt"
    ));
    photostereo::io::light_files::read_directions(path)
        .map(|l| l.directions)
        .unwrap_or_else(|_| {
            // Without the shared data: 96 lights on 4 rings.
            (0..96)
                .map(|k| {
                    let (s, t) = ((15.0 + 15.0 * (k % 4) as f64).to_radians(), k as f64 * 0.41);
                    [s.sin() * t.cos(), s.sin() * t.sin(), s.cos()]
                })
                .collect()
        })
}

fn bench(c: &mut Criterion) {
    let (depth, normals, mask) = field();
    let lights = lights();
    let params = ShadowParams::default();
    let mut g = c.benchmark_group("shadows_612x512");
    g.sample_size(10);
    g.bench_function("shadow_maps_96_lights", |b| {
        b.iter(|| {
            shadow_maps(
                black_box(&depth),
                &normals,
                &mask,
                WIDTH,
                HEIGHT,
                &lights,
                &params,
            )
            .unwrap()
        })
    });
    // The steepest DiLiGenT light (largest slant) gives the longest sweeps and marches.
    let steep = *lights
        .iter()
        .min_by(|a, b| a[2].total_cmp(&b[2]))
        .expect("lights");
    g.bench_function("cast_shadows_1_light", |b| {
        b.iter(|| cast_shadows(black_box(&depth), &mask, WIDTH, HEIGHT, steep, &params).unwrap())
    });
    g.bench_function("ray_march_1_light_step_0.25", |b| {
        b.iter(|| {
            cast_shadows_ray_march(
                black_box(&depth),
                &mask,
                WIDTH,
                HEIGHT,
                steep,
                0.25,
                params.cast_tolerance_px,
            )
            .unwrap()
        })
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
