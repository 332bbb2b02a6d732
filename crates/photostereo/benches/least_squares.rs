//! The least-squares solve for 96 lights on a full 612×512 RGB frame (DiLiGenT's size), and the
//! same on a DiLiGenT-like mask of about 45k pixels.

use criterion::{criterion_group, criterion_main, Criterion};
use photostereo::base::progress::Silent;
use photostereo::model::image::Image;
use photostereo::scene::ring_lights;
use photostereo::solve::estimate::{Estimator, LeastSquares};
use photostereo::Capture;

fn capture(width: usize, height: usize, mask_radius: Option<f64>) -> Capture {
    // 96 lights on three rings; a smooth random-looking albedo pattern keeps the solve honest.
    let mut dirs = Vec::new();
    for (n, slant) in [(32, 20.0), (32, 40.0), (32, 60.0)] {
        dirs.extend(ring_lights(n, slant).directions);
    }
    let lights = photostereo::Lights::new(&dirs).unwrap();
    let images: Vec<Image> = (0..dirs.len())
        .map(|k| {
            let data = (0..width * height * 3)
                .map(|i| ((i * 2654435761usize + k * 97) % 65521) as f32 / 65521.0)
                .collect();
            Image {
                width,
                height,
                channels: 3,
                bit_depth: 16,
                data,
            }
        })
        .collect();
    let mask = mask_radius.map(|r| {
        (0..width * height)
            .map(|i| {
                let (y, x) = (
                    (i / width) as f64 - height as f64 / 2.0,
                    (i % width) as f64 - width as f64 / 2.0,
                );
                x * x + y * y < r * r
            })
            .collect()
    });
    Capture::from_images(&images, lights, mask).unwrap()
}

fn bench(c: &mut Criterion) {
    let mut g = c.benchmark_group("least_squares_96_lights");
    g.sample_size(10);
    let full = capture(612, 512, None);
    g.bench_function("612x512_full_frame", |b| {
        b.iter(|| LeastSquares.estimate(&full, &Silent).unwrap())
    });
    drop(full);
    let masked = capture(612, 512, Some(120.0));
    g.bench_function("612x512_mask_45k", |b| {
        b.iter(|| LeastSquares.estimate(&masked, &Silent).unwrap())
    });
    g.finish();
}

/// On a real DiLiGenT object (when ../shared/data is present): least squares alone, the
/// detector (noise estimate, χ² test and attribution), and the recursive method.
fn bench_diligent(c: &mut Criterion) {
    let dir = std::path::PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../../shared/data/diligent/catPNG"
    ));
    let Ok(files) = photostereo::CaptureFiles::diligent(&dir) else {
        return;
    };
    let capture = files.load(&Silent).unwrap();
    let mut g = c.benchmark_group("diligent_cat");
    g.sample_size(10);
    g.bench_function("load", |b| b.iter(|| files.load(&Silent).unwrap()));
    g.bench_function("l2", |b| {
        b.iter(|| LeastSquares.estimate(&capture, &Silent).unwrap())
    });
    let params = photostereo::solve::detect::DetectionParams::default();
    let test_only = photostereo::solve::detect::DetectionParams {
        attribute: false,
        ..params.clone()
    };
    g.bench_function("detect_test_only", |b| {
        b.iter(|| photostereo::solve::detect::detect(&capture, &test_only, &Silent).unwrap())
    });
    g.bench_function("detect_and_attribute", |b| {
        b.iter(|| photostereo::solve::detect::detect(&capture, &params, &Silent).unwrap())
    });
    g.bench_function("recursive", |b| {
        b.iter(|| {
            photostereo::method::recursive::Recursive::default()
                .estimate(&capture, &Silent)
                .unwrap()
        })
    });
    g.finish();
}

criterion_group!(benches, bench, bench_diligent);
criterion_main!(benches);
