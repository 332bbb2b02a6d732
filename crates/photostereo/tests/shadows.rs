//! The horizon sweep of `photostereo::geometry::shadows` against independent truths: the per-pixel ray
//! march, `scene::ray_march_shadows`, analytic shadow lengths and terminator areas.
//! Run with `--nocapture` to see the measured agreement per case.

mod shadows_scenes;

use photostereo::geometry::shadows::*;
use photostereo::io::shadow_figure::{
    shadow_maps_montage, shadow_montage, shadow_montage_outlined,
};
use photostereo::scene;
use shadows_scenes::*;

/// Ray-march step (pixels) of the reference in these tests.
const MARCH_STEP: f64 = 0.1;

/// One tilt in each of the 8 octants, plus the axes and diagonals (octant borders).
const TILTS: [f64; 16] = [
    0.0, 10.0, 45.0, 55.0, 90.0, 100.0, 135.0, 145.0, 180.0, 190.0, 225.0, 235.0, 270.0, 280.0,
    315.0, 325.0,
];
const SLANTS: [f64; 4] = [20.0, 35.0, 50.0, 70.0];

fn check_field(f: &Field, min_agreement: f64, min_total_iou: f64) {
    let params = ShadowParams::default();
    let (mut worst, mut worst_light) = (1.0f64, [0.0; 3]);
    let (mut inter, mut uni, mut min_iou_big) = (0usize, 0usize, 1.0f64);
    for l in lights(&TILTS, &SLANTS) {
        let sweep = cast_shadows(&f.depth, &f.mask, f.width, f.height, l, &params).unwrap();
        let truth = cast_shadows_ray_march(
            &f.depth,
            &f.mask,
            f.width,
            f.height,
            l,
            MARCH_STEP,
            params.cast_tolerance_px,
        )
        .unwrap();
        let (agree, iou) = agreement(&sweep, &truth, &f.mask);
        if agree < worst {
            worst = agree;
            worst_light = l;
        }
        let shadowed = truth.iter().filter(|&&s| s).count();
        if shadowed >= 200 {
            min_iou_big = min_iou_big.min(iou);
        }
        for i in 0..truth.len() {
            inter += (sweep[i] && truth[i]) as usize;
            uni += (sweep[i] || truth[i]) as usize;
        }
        // Outside the object nothing is ever marked.
        assert!(sweep.iter().zip(&f.mask).all(|(s, m)| *m || !s));
    }
    let total_iou = inter as f64 / uni as f64;
    println!(
        "{:17} {} lights: min agreement {:.4} (light {:.3?}), IoU over all lights {:.4}, \
         min IoU (shadows >= 200 px) {:.4}",
        f.name,
        TILTS.len() * SLANTS.len(),
        worst,
        worst_light,
        total_iou,
        min_iou_big
    );
    assert!(worst >= min_agreement, "{}: agreement {worst}", f.name);
    assert!(total_iou >= min_total_iou, "{}: IoU {total_iou}", f.name);
}

#[test]
fn sweep_agrees_with_ray_march_on_block() {
    check_field(&block(96, 12.0), 0.99, 0.95);
}

#[test]
fn sweep_agrees_with_ray_march_on_sphere_cap() {
    check_field(&sphere_cap(96), 0.99, 0.95);
}

#[test]
fn sweep_agrees_with_ray_march_on_bowl() {
    check_field(&bowl(96), 0.99, 0.95);
}

#[test]
fn sweep_agrees_with_ray_march_on_random_bumps() {
    check_field(&bumps(96, 1), 0.99, 0.95);
    check_field(&bumps(96, 7), 0.99, 0.95);
}

#[test]
fn sweep_agrees_with_ray_march_with_mask_holes() {
    check_field(&bumps_with_holes(96, 3), 0.99, 0.95);
}

/// A wall of height `h` filling the light's side of a `size`² image (its face `wall` pixels from
/// that border), lit along an image axis at slant `slant` (degrees): returns the number of
/// shadowed ground pixels in front of the face along the middle line, by sweep and ray march.
fn wall_shadow_length(tilt: f64, h: f64, slant: f64) -> (usize, usize) {
    let (size, wall) = (100usize, 20usize);
    let mut depth = vec![0f32; size * size];
    // Distance of (row, col) from the light's border, and the ground walk away from it.
    let from_light = |row: usize, col: usize| match tilt as i64 {
        0 => size - 1 - col,
        90 => row,
        180 => col,
        270 => size - 1 - row,
        _ => unreachable!(),
    };
    for row in 0..size {
        for col in 0..size {
            if from_light(row, col) < wall {
                depth[row * size + col] = h as f32;
            }
        }
    }
    let mask = vec![true; size * size];
    let (s, t) = (slant.to_radians(), tilt.to_radians());
    let l = [s.sin() * t.cos(), s.sin() * t.sin(), s.cos()];
    let sweep = cast_shadows(&depth, &mask, size, size, l, &ShadowParams::default()).unwrap();
    let march = cast_shadows_ray_march(&depth, &mask, size, size, l, 0.02, 0.0).unwrap();
    let mid = size / 2;
    let pixel = |d: usize| match tilt as i64 {
        0 => mid * size + (size - 1 - d),
        90 => d * size + mid,
        180 => mid * size + d,
        270 => (size - 1 - d) * size + mid,
        _ => unreachable!(),
    };
    let count = |map: &[bool]| (wall..size).take_while(|&d| map[pixel(d)]).count();
    (count(&sweep), count(&march))
}

#[test]
fn step_shadow_length_is_h_tan_slant() {
    let mut worst = 0.0f64;
    for tilt in [0.0, 90.0, 180.0, 270.0] {
        for h in [5.0, 10.0, 20.0] {
            for slant in [20.0f64, 30.0, 45.0, 60.0, 70.0] {
                let expected = h * slant.to_radians().tan();
                if expected > 75.0 {
                    continue; // would leave the 100 px image
                }
                let (sweep, march) = wall_shadow_length(tilt, h, slant);
                worst = worst.max((sweep as f64 - expected).abs());
                assert!(
                    (sweep as f64 - expected).abs() <= 1.0,
                    "tilt {tilt} h {h} slant {slant}: sweep {sweep} px, expected {expected:.2}"
                );
                assert!(
                    (march as f64 - expected).abs() <= 1.0,
                    "tilt {tilt} h {h} slant {slant}: ray march {march} px, expected {expected:.2}"
                );
            }
        }
    }
    println!("wall shadow length: worst |sweep − h·tan θ| = {worst:.2} px");
}

#[test]
fn sphere_on_plane_ring_of_8_at_40_degrees() {
    let sc = scene::sphere_on_plane(128);
    let rig = scene::ring_lights(8, 40.0);
    let params = ShadowParams::default();
    let maps = shadow_maps(
        &sc.depth,
        &sc.normals,
        &sc.mask,
        sc.width,
        sc.height,
        &rig.directions,
        &params,
    )
    .unwrap();
    for (k, l) in rig.directions.iter().enumerate() {
        let sweep = maps.cast(k);
        let ours = cast_shadows_ray_march(
            &sc.depth,
            &sc.mask,
            sc.width,
            sc.height,
            *l,
            MARCH_STEP,
            params.cast_tolerance_px,
        )
        .unwrap();
        let (agree, iou) = agreement(&sweep, &ours, &sc.mask);
        // The renderer's march has no tolerance: compare it with a sweep without one too.
        let renderer = scene::ray_march_shadows(&sc, *l, 0.05);
        let exact = ShadowParams {
            cast_tolerance_px: 0.0,
            ..params
        };
        let sweep0 = cast_shadows(&sc.depth, &sc.mask, sc.width, sc.height, *l, &exact).unwrap();
        let (agree_r, iou_r) = agreement(&sweep0, &renderer, &sc.mask);
        let (_, iou_r_default) = agreement(&sweep, &renderer, &sc.mask);
        println!(
            "sphere-on-plane light {k}: vs ray march agreement {agree:.4} IoU {iou:.4}; \
             tolerance 0 vs scene::ray_march_shadows agreement {agree_r:.4} IoU {iou_r:.4} \
             (default tolerance: IoU {iou_r_default:.4})"
        );
        assert!(
            iou >= 0.95 && iou_r >= 0.95,
            "light {k}: IoU {iou} / {iou_r}"
        );
        assert!(agree >= 0.99 && agree_r >= 0.99);
    }
}

#[test]
fn attached_shadow_covers_the_dark_side_of_the_hemisphere() {
    // Viewed from above, the part of a hemisphere facing away from a light at slant θ has the
    // projected area (π r² / 2)(1 − cos θ).
    let size = 201;
    let sc = scene::sphere_on_plane(size);
    let r = 0.3 * size as f64;
    for slant in [20.0f64, 45.0, 70.0] {
        let s = slant.to_radians();
        let l = [s.sin() * 0.6, s.sin() * 0.8, s.cos()];
        let params = ShadowParams {
            attached_tolerance: 0.0,
            ..ShadowParams::default()
        };
        let maps = shadow_maps(
            &sc.depth,
            &sc.normals,
            &sc.mask,
            sc.width,
            sc.height,
            &[l],
            &params,
        )
        .unwrap();
        let attached = maps.attached(0).iter().filter(|&&a| a).count() as f64;
        let expected = std::f64::consts::PI * r * r / 2.0 * (1.0 - s.cos());
        println!("slant {slant}: attached {attached} px, analytic {expected:.0} px");
        assert!((attached - expected).abs() <= 0.03 * expected + 2.0 * r);
        // The union is attached ∪ cast, per pixel.
        let (a, c, u) = (maps.attached(0), maps.cast(0), maps.union(0));
        assert!((0..u.len()).all(|i| u[i] == (a[i] || c[i])));
        assert!((0..u.len()).all(|i| maps.is_shadowed(0, i) == u[i]));
    }
}

#[test]
fn shadow_maps_match_single_light_sweeps_and_respect_the_mask() {
    let f = bumps_with_holes(80, 11);
    let normals = numeric_normals(&f);
    let ls = lights(&[30.0, 200.0, 300.0], &[25.0, 60.0]);
    let params = ShadowParams::default();
    let maps = shadow_maps(&f.depth, &normals, &f.mask, f.width, f.height, &ls, &params).unwrap();
    assert_eq!((maps.lights, maps.width, maps.height), (6, 80, 80));
    for (k, l) in ls.iter().enumerate() {
        let single = cast_shadows(&f.depth, &f.mask, f.width, f.height, *l, &params).unwrap();
        assert_eq!(maps.cast(k), single);
        let attached_map = maps.attached(k);
        for (i, n) in normals.iter().enumerate() {
            let nl: f64 = (0..3).map(|c| l[c] * n[c] as f64).sum();
            let attached = f.mask[i] && nl <= params.attached_tolerance;
            assert_eq!(attached_map[i], attached);
            if !f.mask[i] {
                assert_eq!(maps.flags_of(k)[i], 0);
            }
        }
    }
    let all: Vec<u8> = (0..maps.lights).flat_map(|k| maps.flags_of(k)).collect();
    assert!(all.contains(&ShadowMaps::CAST));
    assert!(all.contains(&(ShadowMaps::ATTACHED | ShadowMaps::CAST)));
    // The bit planes count and answer per pixel as the flags do.
    let count = |bits: u8| all.iter().filter(|&&x| x & bits != 0).count();
    for bits in [
        ShadowMaps::ATTACHED,
        ShadowMaps::CAST,
        ShadowMaps::ATTACHED | ShadowMaps::CAST,
    ] {
        assert_eq!(maps.count(bits), count(bits));
    }
    // The montage read from the bit planes is the one drawn from per-light union maps.
    let unions: Vec<Vec<bool>> = (0..maps.lights).map(|k| maps.union(k)).collect();
    let drawn = shadow_montage_outlined(&unions, Some(&f.mask), f.width, f.height);
    let from_bits = shadow_maps_montage(&maps, Some(&f.mask));
    assert_eq!(
        (drawn.width, drawn.height),
        (from_bits.width, from_bits.height)
    );
    assert!(drawn.data == from_bits.data);
    let pixels: Vec<u32> = (0..(f.width * f.height) as u32).step_by(7).collect();
    let bits = maps.pixel_bits(&pixels);
    for (j, &i) in pixels.iter().enumerate() {
        for k in 0..maps.lights {
            let set = bits[j] >> k & 1 != 0;
            assert_eq!(set, maps.flag(k, i as usize) != 0, "pixel {i} light {k}");
        }
    }
}

/// Normals of the field by central differences (∂f/∂col = −n_x/n_z, ∂f/∂row = +n_y/n_z).
fn numeric_normals(f: &Field) -> Vec<[f32; 3]> {
    let (w, h) = (f.width, f.height);
    let at = |r: usize, c: usize| {
        let v = f.depth[r * w + c];
        if v.is_finite() {
            v as f64
        } else {
            0.0
        }
    };
    (0..w * h)
        .map(|i| {
            let (r, c) = (i / w, i % w);
            let p = (at(r, (c + 1).min(w - 1)) - at(r, c.saturating_sub(1))) / 2.0;
            let q = (at((r + 1).min(h - 1), c) - at(r.saturating_sub(1), c)) / 2.0;
            let n = (p * p + q * q + 1.0).sqrt();
            [(-p / n) as f32, (q / n) as f32, (1.0 / n) as f32]
        })
        .collect()
}

#[test]
fn mirrored_and_transposed_scenes_give_mirrored_maps() {
    // The 8 octants are one sweep walked in different directions: mirroring the field and the
    // light must mirror the map.
    let f = bumps(64, 5);
    let n = f.width;
    let params = ShadowParams::default();
    let flip =
        |v: &[f32]| -> Vec<f32> { (0..n * n).map(|i| v[(i / n) * n + n - 1 - i % n]).collect() };
    let transpose =
        |v: &[f32]| -> Vec<f32> { (0..n * n).map(|i| v[(i % n) * n + i / n]).collect() };
    for l in lights(
        &[10.0, 55.0, 100.0, 145.0, 190.0, 235.0, 280.0, 325.0],
        &[30.0, 65.0],
    ) {
        let base = cast_shadows(&f.depth, &f.mask, n, n, l, &params).unwrap();
        let as_f32 = |b: &[bool]| b.iter().map(|&s| s as u8 as f32).collect::<Vec<_>>();
        let flipped =
            cast_shadows(&flip(&f.depth), &f.mask, n, n, [-l[0], l[1], l[2]], &params).unwrap();
        assert_eq!(
            as_f32(&flipped),
            flip(&as_f32(&base)),
            "mirror, light {l:?}"
        );
        let transposed = cast_shadows(
            &transpose(&f.depth),
            &f.mask,
            n,
            n,
            [-l[1], -l[0], l[2]],
            &params,
        )
        .unwrap();
        assert_eq!(
            as_f32(&transposed),
            transpose(&as_f32(&base)),
            "transpose, light {l:?}"
        );
    }
}

#[test]
fn zenith_light_casts_nothing_and_grazing_light_shadows_a_dent() {
    let f = bowl(64);
    let none = cast_shadows(
        &f.depth,
        &f.mask,
        64,
        64,
        [0.0, 0.0, 1.0],
        &ShadowParams::default(),
    )
    .unwrap();
    assert!(none.iter().all(|&s| !s));
    let grazing = cast_shadows(
        &f.depth,
        &f.mask,
        64,
        64,
        [0.99, 0.0, 0.141],
        &ShadowParams::default(),
    )
    .unwrap();
    // The bowl's lit-side half (toward the light, +x) lies in the rim's shadow.
    let inside_right = (0..64 * 64)
        .filter(|&i| f.depth[i] < -1.0 && (i % 64) > 34 && grazing[i])
        .count();
    assert!(inside_right > 100, "{inside_right}");
}

#[test]
fn a_hole_stops_the_horizon() {
    // A wall at columns < 10 (height 10) lit from −x at 45°: the ground is shadowed over 9 px.
    // A one-column hole at column 12 stops the horizon: ground beyond it is lit.
    let (w, h) = (40usize, 6usize);
    let mut depth = vec![0f32; w * h];
    for r in 0..h {
        for c in 0..10 {
            depth[r * w + c] = 10.0;
        }
    }
    let l = [-(0.5f64.sqrt()), 0.0, 0.5f64.sqrt()];
    let params = ShadowParams::default();
    let full = vec![true; w * h];
    let open = cast_shadows(&depth, &full, w, h, l, &params).unwrap();
    assert_eq!((10..w).filter(|&c| open[3 * w + c]).count(), 9);
    let mut holed = full.clone();
    let mut nan_depth = depth.clone();
    for r in 0..h {
        holed[r * w + 12] = false;
        nan_depth[r * w + 12] = f32::NAN; // NaN inside the mask counts as a hole too
    }
    for (d, m) in [(&depth, &holed), (&nan_depth, &full)] {
        let s = cast_shadows(d, m, w, h, l, &params).unwrap();
        let march = cast_shadows_ray_march(d, m, w, h, l, 0.05, 0.0).unwrap();
        let shadowed: Vec<usize> = (0..w).filter(|&c| s[3 * w + c]).collect();
        assert_eq!(shadowed, vec![10, 11]);
        assert_eq!(s, march);
    }
}

#[test]
fn bad_inputs_are_errors() {
    let depth = vec![0f32; 12];
    let mask = vec![true; 12];
    let p = ShadowParams::default();
    assert!(cast_shadows(&depth, &mask, 4, 4, [0.5, 0.0, 0.8], &p).is_err());
    assert!(cast_shadows(&depth, &mask, 4, 3, [0.0, 0.0, 0.0], &p).is_err());
    assert!(cast_shadows(&depth, &mask, 4, 3, [f64::NAN, 0.0, 1.0], &p).is_err());
    let bad = ShadowParams {
        cast_tolerance_px: -1.0,
        ..p
    };
    assert!(cast_shadows(&depth, &mask, 4, 3, [0.5, 0.0, 0.8], &bad).is_err());
    assert!(cast_shadows_ray_march(&depth, &mask, 4, 3, [0.5, 0.0, 0.8], 0.0, 0.0).is_err());
    let normals = vec![[0f32, 0.0, 1.0]; 11];
    let e = shadow_maps(&depth, &normals, &mask, 4, 3, &[[0.0, 0.0, 1.0]], &p).unwrap_err();
    assert!(e.to_string().contains("normals"), "{e}");
    let e = shadow_maps(
        &depth,
        &[[0.0, 0.0, 1.0]; 12],
        &mask,
        4,
        3,
        &[[0.0, 0.0, 1.0], [0.0; 3]],
        &p,
    )
    .unwrap_err();
    assert!(e.to_string().contains("light 2"), "{e}");
}

#[test]
fn montage_shows_each_light_as_a_labelled_tile() {
    let (w, h) = (300usize, 200usize);
    let lit = vec![false; w * h];
    let dark = vec![true; w * h];
    let mut half = vec![false; w * h];
    for (i, v) in half.iter_mut().enumerate() {
        *v = i % w < w / 2;
    }
    let maps = vec![lit, dark, half, vec![false; w * h], vec![true; w * h]];
    let c = shadow_montage(&maps, w, h);
    // 5 tiles in a 3×2 grid; 300×200 reduced by 3 to 100×67.
    let px = |x: usize, y: usize| c.data[(y * c.width + x) * 3];
    assert!(c.width >= 3 * 100 && c.height >= 2 * 67);
    let (gap, label) = (6, 11);
    let cell_w = 100 + gap;
    let tile = |k: usize, x: usize, y: usize| {
        px(
            gap + (k % 3) * cell_w + x,
            gap + (k / 3) * (67 + label + gap) + label + y,
        )
    };
    assert_eq!(tile(0, 50, 30), 255);
    assert_eq!(tile(1, 50, 30), 0);
    assert_eq!(tile(2, 10, 30), 0);
    assert_eq!(tile(2, 90, 30), 255);
    assert_eq!(tile(4, 99, 66), 0);
    // Labels: some black pixels above the first tile.
    let label_dark = (0..label)
        .flat_map(|y| (0..30).map(move |x| (x, y)))
        .filter(|&(x, y)| px(gap + x, gap + y) == 0)
        .count();
    assert!(label_dark > 5);
}

#[test]
fn union_matches_the_renderers_shadow_flags() {
    // `scene::render_lambert` marks n·l ≤ 0 or its own ray march; the union of our maps with
    // τ = 0 must cover the same pixels.
    let sc = scene::sphere_on_plane(128);
    let rig = scene::ring_lights(8, 40.0);
    let (_, truth) = scene::render_lambert(&sc, &rig);
    let params = ShadowParams {
        attached_tolerance: 0.0,
        ..ShadowParams::default()
    };
    let maps = shadow_maps(
        &sc.depth,
        &sc.normals,
        &sc.mask,
        sc.width,
        sc.height,
        &rig.directions,
        &params,
    )
    .unwrap();
    for (k, t) in truth.iter().enumerate() {
        let (agree, iou) = agreement(&maps.union(k), t, &sc.mask);
        println!("sphere-on-plane light {k}: union vs renderer agreement {agree:.4} IoU {iou:.4}");
        assert!(agree >= 0.995 && iou >= 0.97, "light {k}: {agree} {iou}");
    }
}

#[test]
fn default_tolerance_keeps_smooth_lit_slopes_lit() {
    // False shadows on smooth lit slopes: pixels facing the light (n·l > 0.1) that the sweep
    // shadows and the exact ray march (no tolerance) does not, per tolerance; and the share of
    // the exact cast shadow on pixels facing the light that the sweep keeps (the tolerance
    // trims shadows near their edges; inside the attached shadow that does not matter).
    let fields = [sphere_cap(96), bowl(96), bumps(96, 1), bumps(96, 7)];
    let ls = lights(&TILTS, &SLANTS);
    let truths: Vec<Vec<Vec<bool>>> = fields
        .iter()
        .map(|f| {
            ls.iter()
                .map(|l| {
                    cast_shadows_ray_march(
                        &f.depth, &f.mask, f.width, f.height, *l, MARCH_STEP, 0.0,
                    )
                    .unwrap()
                })
                .collect()
        })
        .collect();
    let default = ShadowParams::default().cast_tolerance_px;
    for tol in [0.0, default, 0.1, 0.25, 0.5] {
        let p = ShadowParams {
            cast_tolerance_px: tol,
            ..ShadowParams::default()
        };
        let (mut lit, mut false_shadow, mut truth_shadow, mut kept) =
            (0usize, 0usize, 0usize, 0usize);
        for (f, truth) in fields.iter().zip(&truths) {
            let normals = numeric_normals(f);
            for (l, t) in ls.iter().zip(truth) {
                let s = cast_shadows(&f.depth, &f.mask, f.width, f.height, *l, &p).unwrap();
                for i in 0..s.len() {
                    let nl: f64 = (0..3).map(|c| l[c] * normals[i][c] as f64).sum();
                    if nl > 0.1 && !t[i] {
                        lit += 1;
                        false_shadow += s[i] as usize;
                    }
                    if nl > 0.0 {
                        truth_shadow += t[i] as usize;
                        kept += (t[i] && s[i]) as usize;
                    }
                }
            }
        }
        let rate = false_shadow as f64 / lit as f64;
        let recall = kept as f64 / truth_shadow as f64;
        println!(
            "tolerance {tol:.2} px: falsely shadowed lit pixels {false_shadow} of {lit} ({:.4}%), \
             exact cast shadow on pixels facing the light (n·l > 0) kept {:.2}%",
            100.0 * rate,
            100.0 * recall
        );
        if tol == default {
            assert!(rate < 1e-4, "false shadows {rate}");
            assert!(recall > 0.96, "recall {recall}");
        }
    }
}
