//! The in-memory engine: `Capture::from_stack` against the file-free `from_images` and against
//! itself under other sample types and strides; `reconstruct` against analytic surfaces (normals,
//! albedo and depth of a Lambertian sphere), its documented full-frame shapes, and parameter
//! errors that name the parameter.

use ndarray::{Array2, Array4, Axis};
use photostereo::base::progress::Silent;
use photostereo::base::rng::Pcg32;
use photostereo::method::engine::{reconstruct, Method, Params};
use photostereo::model::capture::{Capture, Stack};
use photostereo::model::image::Image;
use photostereo::model::lights::Lights;
use photostereo::scene::{lambert_capture, ring_lights, sphere_on_plane, Scene};
use photostereo::solve::lambert::status;
use photostereo::solve::metrics::angular_error_deg;

fn ring(n: usize) -> Lights {
    ring_lights(n, 35.0)
}

/// A random u16 stack (N, H, W, 3).
fn random_stack(n: usize, h: usize, w: usize, seed: u64) -> Array4<u16> {
    let mut rng = Pcg32::new(seed, 1);
    Array4::from_shape_fn((n, h, w, 3), |_| (rng.next_f64() * 65535.0) as u16)
}

#[test]
fn from_stack_equals_from_images_for_every_sample_type_and_stride() {
    let (n, h, w) = (5, 7, 9);
    let lights = ring(n)
        .with_intensities((0..n).map(|k| [1.0 + k as f64, 0.5, 2.0]).collect())
        .unwrap();
    let raw = random_stack(n, h, w, 7);
    let mut mask = Array2::from_elem((h, w), true);
    mask[[0, 0]] = false;
    mask[[3, 4]] = false;
    let as_f32 = raw.mapv(|v| v as f32 / 65535.0);
    // The reference: decoded images through the file path's constructor.
    let images: Vec<Image> = (0..n)
        .map(|k| Image {
            width: w,
            height: h,
            channels: 3,
            bit_depth: 16,
            data: as_f32.index_axis(Axis(0), k).iter().copied().collect(),
        })
        .collect();
    let flat_mask: Vec<bool> = mask.iter().copied().collect();
    let reference = Capture::from_images(&images, lights.clone(), Some(flat_mask)).unwrap();
    assert_eq!(reference.n_pixels(), h * w - 2);

    let u16_capture =
        Capture::from_stack(Stack::U16(raw.view()), lights.clone(), Some(mask.view())).unwrap();
    let f32_capture =
        Capture::from_stack(Stack::F32(as_f32.view()), lights.clone(), Some(mask.view())).unwrap();
    let f64_stack = as_f32.mapv(|v| v as f64);
    let f64_capture = Capture::from_stack(
        Stack::F64(f64_stack.view()),
        lights.clone(),
        Some(mask.view()),
    )
    .unwrap();
    // A non-contiguous view: the same stack stored (H, W, N, C) and viewed as (N, H, W, C).
    let mut transposed = Array4::<u16>::zeros((h, w, n, 3));
    transposed.assign(&raw.view().permuted_axes([1, 2, 0, 3]));
    let strided = transposed.view().permuted_axes([2, 0, 1, 3]);
    assert!(!strided.is_standard_layout());
    let strided_capture =
        Capture::from_stack(Stack::U16(strided), lights.clone(), Some(mask.view())).unwrap();

    for c in [&u16_capture, &f32_capture, &f64_capture, &strided_capture] {
        assert_eq!(c.pixels, reference.pixels);
        assert_eq!((c.width, c.height, c.channels), (w, h, 3));
        assert_eq!(c.samples, reference.samples);
    }
    assert_eq!(u16_capture.bit_depth, 16);

    // 8-bit: full scale 255.
    let raw8 = raw.mapv(|v| (v >> 8) as u8);
    let c8 = Capture::from_stack(Stack::U8(raw8.view()), lights.clone(), None).unwrap();
    let k = 2;
    let (row, col) = (4, 5);
    let expected = raw8[[k, row, col, 1]] as f32 / 255.0 * (1.0 / 0.5);
    let p = row * w + col;
    assert_eq!(c8.pixel_samples(p)[k * 3 + 1], expected);
    assert_eq!(c8.n_pixels(), h * w);
}

#[test]
fn from_stack_refuses_what_cannot_work() {
    let lights = ring(4);
    let stack = random_stack(4, 6, 6, 1);
    let err = |r: photostereo::Result<Capture>| r.unwrap_err().to_string();
    // Count mismatch.
    let e = err(Capture::from_stack(Stack::U16(stack.view()), ring(5), None));
    assert!(e.contains("4 images") && e.contains("5 lights"), "{e}");
    // Two images.
    let two = random_stack(2, 6, 6, 2);
    let two_lights = Lights::new(&[[0.0, 0.0, 1.0], [0.5, 0.0, 0.866]]).unwrap();
    let e = err(Capture::from_stack(
        Stack::U16(two.view()),
        two_lights,
        None,
    ));
    assert!(e.contains("at least three"), "{e}");
    // Two channels.
    let c2 = Array4::<f32>::zeros((4, 6, 6, 2));
    let e = err(Capture::from_stack(
        Stack::F32(c2.view()),
        lights.clone(),
        None,
    ));
    assert!(e.contains("2 channels"), "{e}");
    // Mask of another shape, and an empty mask.
    let m = Array2::from_elem((5, 6), true);
    let e = err(Capture::from_stack(
        Stack::U16(stack.view()),
        lights.clone(),
        Some(m.view()),
    ));
    assert!(e.contains("mask is 5×6"), "{e}");
    let m = Array2::from_elem((6, 6), false);
    let e = err(Capture::from_stack(
        Stack::U16(stack.view()),
        lights.clone(),
        Some(m.view()),
    ));
    assert!(e.contains("mask is empty"), "{e}");
    // A NaN sample is read as a shadow and named in a note; an image of NaN is refused.
    let mut f = stack.mapv(|v| v as f32 / 65535.0);
    f[[2, 3, 1, 0]] = f32::NAN;
    let c = Capture::from_stack(Stack::F32(f.view()), lights.clone(), None).unwrap();
    assert!(
        c.notes
            .iter()
            .any(|n| n.contains("image 3 of the stack (1 of 108 readings")),
        "{:?}",
        c.notes
    );
    assert_eq!(c.pixel_samples(3 * 6 + 1)[2 * 3], 0.0);
    f.index_axis_mut(ndarray::Axis(0), 2).fill(f32::NAN);
    let e = err(Capture::from_stack(
        Stack::F32(f.view()),
        lights.clone(),
        None,
    ));
    assert!(e.contains("image 3") && e.contains("no reading"), "{e}");
    // Coplanar lights.
    let flat = Lights::new(&[
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [-1.0, 0.0, 0.0],
        [0.0, -1.0, 0.0],
    ])
    .unwrap();
    assert!(Capture::from_stack(Stack::U16(stack.view()), flat, None).is_err());
}

/// A Lambertian sphere cap (radius 40 px in a 96² frame) lit by every light of an 8-light ring:
/// (H, W, 4) stack, lights, mask and the analytic scene.
fn sphere_stack() -> (Array4<f32>, Lights, Array2<bool>, Scene) {
    let mut scene = sphere_on_plane(96);
    let lights = ring(8);
    // Keep the sphere's pixels lit by every light and away from its rim.
    let c = 47.5;
    for row in 0..96 {
        for col in 0..96 {
            let (x, y) = (col as f64 - c, c - row as f64);
            let i = row * 96 + col;
            let n = scene.normals[i];
            let lit = lights
                .directions
                .iter()
                .all(|l| l[0] * n[0] as f64 + l[1] * n[1] as f64 + l[2] * n[2] as f64 > 0.05);
            scene.mask[i] = (x * x + y * y).sqrt() < 0.9 * 28.8 && lit;
        }
    }
    let (capture, _) = lambert_capture(&scene, &lights).unwrap();
    let mut stack = Array4::<f32>::zeros((8, 96, 96, 3));
    for (p, &i) in capture.pixels.iter().enumerate() {
        let (row, col) = (i as usize / 96, i as usize % 96);
        for k in 0..8 {
            for ch in 0..3 {
                stack[[k, row, col, ch]] = capture.pixel_samples(p)[k * 3 + ch];
            }
        }
    }
    let mask = Array2::from_shape_vec((96, 96), scene.mask.clone()).unwrap();
    (stack, lights, mask, scene)
}

#[test]
#[allow(clippy::needless_range_loop)]
fn reconstruct_recovers_an_analytic_sphere_in_full_frame() {
    let (stack, lights, mask, scene) = sphere_stack();
    let capture = Capture::from_stack(Stack::F32(stack.view()), lights, Some(mask.view())).unwrap();
    let (w, h) = (96, 96);
    for method in Method::ALL.iter().copied() {
        let params = Params {
            method,
            ..Params::default()
        };
        let rec = reconstruct(&capture, &params, &Silent).unwrap();
        assert_eq!(rec.normals.len(), h * w);
        assert_eq!(rec.albedo.len(), h * w * 3);
        assert_eq!(rec.light_status.to_full().len(), 8 * h * w);
        assert_eq!(rec.trust.len(), h * w);
        let depth = rec.depth().expect("integrated by default");
        assert_eq!(depth.len(), h * w);
        assert_eq!(rec.curl().unwrap().len(), h * w);
        assert_eq!(rec.residual.as_ref().unwrap().len(), h * w);
        let mut worst: f64 = 0.0;
        for i in 0..h * w {
            if scene.mask[i] {
                worst = worst.max(angular_error_deg(rec.normals[i], scene.normals[i]));
                for ch in 0..3 {
                    let a = rec.albedo[i * 3 + ch];
                    assert!(
                        (a - scene.albedo[i][ch]).abs() < 1e-3,
                        "{method:?} albedo {a}"
                    );
                }
                assert!(depth[i].is_finite());
                for k in 0..8 {
                    assert_eq!(rec.light_status.get(k, i), status::USED, "{method:?}");
                }
            } else {
                assert_eq!(rec.normals[i], [0.0; 3]);
                assert!(depth[i].is_nan());
                assert_eq!(rec.light_status.get(0, i), status::OUTSIDE);
            }
        }
        assert!(worst < 0.01, "{method:?}: worst error {worst}°");
        // Depth up to a constant: the sphere's height field.
        let inside: Vec<usize> = (0..h * w).filter(|&i| scene.mask[i]).collect();
        let offset = inside
            .iter()
            .map(|&i| (depth[i] - scene.depth[i]) as f64)
            .sum::<f64>()
            / inside.len() as f64;
        let rms = (inside
            .iter()
            .map(|&i| (depth[i] as f64 - offset - scene.depth[i] as f64).powi(2))
            .sum::<f64>()
            / inside.len() as f64)
            .sqrt();
        assert!(rms < 0.05, "{method:?}: depth rms {rms} px");
        assert_eq!(rec.report.method, method.name());
        assert_eq!(rec.report.input.mask_pixels, inside.len());
    }
}

#[test]
fn the_exported_depth_follows_the_recursion_weighting_rule() {
    // A sphere on a plane under a ring: cast shadows leave some pixels with few lights; every
    // mask pixel must still get a finite depth (weight 0 fills, never a hole), and the trust
    // map takes only the rule's three values.
    let scene = sphere_on_plane(64);
    let lights = ring_lights(8, 60.0);
    let (capture, _) = lambert_capture(&scene, &lights).unwrap();
    let params = Params::default();
    let rec = reconstruct(&capture, &params, &Silent).unwrap();
    let low = params.integration.unreliable_weight;
    assert!(rec.trust.iter().all(|&t| t == 0.0 || t == 1.0 || t == low));
    let depth = rec.depth().unwrap();
    assert!(depth.iter().all(|d| d.is_finite()));
    let maps = rec.recursive.as_ref().unwrap();
    assert!(!maps.iterations.is_empty());
    assert_eq!(maps.highlight.len(), 64 * 64);
}

#[test]
fn parameter_errors_name_the_parameter() {
    let (stack, lights, mask, _) = sphere_stack();
    let capture = Capture::from_stack(Stack::F32(stack.view()), lights, Some(mask.view())).unwrap();
    let cases: Vec<(Params, &str)> = vec![
        (
            Params {
                detection: photostereo::solve::detect::DetectionParams {
                    relative_noise: Some(-0.5),
                    ..Default::default()
                },
                ..Params::default()
            },
            "relative_noise",
        ),
        (
            Params {
                recursive: photostereo::method::recursive::RecursiveParams {
                    max_iterations: 0,
                    ..Default::default()
                },
                ..Params::default()
            },
            "max_iterations",
        ),
        (
            Params {
                integration: photostereo::geometry::integrate::IntegrationParams {
                    unreliable_weight: 1.5,
                    ..Default::default()
                },
                ..Params::default()
            },
            "unreliable_weight",
        ),
    ];
    for (params, name) in cases {
        match reconstruct(&capture, &params, &Silent) {
            Err(photostereo::Error::Parameter { name: n, .. }) => assert_eq!(n, name),
            other => panic!("{name}: expected a parameter error, got {other:?}"),
        }
    }
}
