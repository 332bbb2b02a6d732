//! RTI fits against independent truth: coefficients recovered from readings synthesised from
//! known coefficients; the closed-form leave-one-out error against refits without each light
//! (nalgebra's SVD of the ridge-augmented system, not the library's normal equations); the
//! ridge's roughness penalty against quadratures of the Dirichlet energy and its shrinkage in
//! closed form on a rig with an orthogonal design; and the `.ptm` / `.rti` files read back
//! by readers written here from the format descriptions (PTM v1.2: bottom-up rows, a =
//! (c' − bias) · scale; RTIViewer's HSH: top-down rows, value = c / 255 · scale + bias).

use nalgebra::{DMatrix, DVector};
use ndarray::Array4;
use photostereo::model::capture::Stack;
use photostereo::solve::rti::rbf::{self, Interpolant, Smoothing, Width};
use photostereo::solve::rti::smoother;
use photostereo::solve::rti::{fit, fit_penalised, Basis, Penalty, Prior, RtiFit, MAX_TERMS};
use photostereo::{Capture, Lights};

/// `n` lights on a spiral over the upper hemisphere: elevations from 15° to 80°.
fn lights(n: usize) -> Vec<[f64; 3]> {
    (0..n)
        .map(|k| {
            let f = k as f64 / (n - 1) as f64;
            let elev = (15.0 + 65.0 * f).to_radians();
            let az = k as f64 * 2.399963; // golden angle
            [elev.cos() * az.cos(), elev.cos() * az.sin(), elev.sin()]
        })
        .collect()
}

/// A capture whose reading at pixel p, light k, channel c is `value(p, k, c, l_k)`.
fn capture(
    w: usize,
    h: usize,
    c: usize,
    dirs: &[[f64; 3]],
    value: impl Fn(usize, usize, usize, [f64; 3]) -> f64,
) -> Capture {
    let mut a = Array4::<f32>::zeros((dirs.len(), h, w, c));
    for (k, l) in dirs.iter().enumerate() {
        for p in 0..w * h {
            for ch in 0..c {
                a[[k, p / w, p % w, ch]] = value(p, k, ch, *l) as f32;
            }
        }
    }
    Capture::from_stack(Stack::F32(a.view()), Lights::new(dirs).unwrap(), None).unwrap()
}

/// Known coefficients of pixel p, channel c, term j: a smooth positive reflectance.
fn truth(basis: Basis, p: usize, c: usize, j: usize) -> f64 {
    let base = match basis {
        Basis::PtmLrgb | Basis::PtmRgb => [0.0, 0.0, 0.0, 0.0, 0.0, 0.5],
        _ => [1.0, 0.0, 0.0, 0.0, 0.0, 0.0],
    };
    let b = if j < 6 { base[j] } else { 0.0 };
    b + 0.05 * (((p * 7 + c * 3 + j * 5) % 11) as f64 / 11.0 - 0.5)
}

fn model(basis: Basis, p: usize, c: usize, l: [f64; 3]) -> f64 {
    let mut b = [0.0; MAX_TERMS];
    basis.eval(l, &mut b);
    (0..basis.terms())
        .map(|j| truth(basis, p, c, j) * b[j])
        .sum()
}

#[test]
fn coefficients_are_recovered_from_readings_of_the_basis() {
    let dirs = lights(40);
    for basis in [Basis::PtmRgb, Basis::Hsh2, Basis::Hsh3] {
        let cap = capture(5, 4, 3, &dirs, |p, _, c, l| model(basis, p, c, l));
        let f = fit(&cap, basis, None).unwrap();
        let t = basis.terms();
        for p in 0..20 {
            for c in 0..3 {
                for j in 0..t {
                    let got = f64::from(f.coefficients[(p * 3 + c) * t + j]) / f.gain;
                    let want = truth(basis, p, c, j);
                    assert!(
                        (got - want).abs() < 2e-5,
                        "{} p{p} c{c} term {j}: {got} vs {want}",
                        basis.name()
                    );
                }
            }
        }
        // An exact model leaves nothing to predict: the LOO error is at float precision.
        assert!(f.loo.mean_rmse_8bit() < 1e-3, "{}", f.loo.mean_rmse_8bit());
    }
    // LRGB: a grey luminance polynomial times a fixed chroma per pixel.
    let chroma = |p: usize, c: usize| [0.9, 1.0, 1.1][c] * (1.0 + 0.01 * p as f64);
    let cap = capture(5, 4, 3, &dirs, |p, _, c, l| {
        chroma(p, c) * model(Basis::PtmLrgb, p, 0, l)
    });
    let f = fit(&cap, Basis::PtmLrgb, None).unwrap();
    for p in 0..20 {
        let mean: f64 = (0..3).map(|c| chroma(p, c)).sum::<f64>() / 3.0;
        for j in 0..6 {
            let got = f64::from(f.coefficients[p * 6 + j]) / f.gain;
            let want = mean * truth(Basis::PtmLrgb, p, 0, j);
            assert!((got - want).abs() < 2e-5, "p{p} term {j}: {got} vs {want}");
        }
        for c in 0..3 {
            let got = f64::from(f.chroma[p * 3 + c]);
            assert!((got - chroma(p, c) / mean).abs() < 1e-5, "chroma p{p} c{c}");
        }
    }
}

/// A reflectance no basis holds exactly: Lambertian plus a Phong lobe, per channel.
fn glossy(p: usize, _k: usize, c: usize, l: [f64; 3]) -> f64 {
    let n = [0.1 * (p % 3) as f64, -0.1 * (p % 2) as f64, 1.0];
    let nn = (n[0] * n[0] + n[1] * n[1] + 1.0f64).sqrt();
    let ndl = ((n[0] * l[0] + n[1] * l[1] + n[2] * l[2]) / nn).max(0.0);
    let hz = (l[2] + 1.0) / (2.0 * (1.0 + l[2])).sqrt();
    0.3 + 0.1 * c as f64 + 0.6 * ndl + 0.4 * hz.powi(20)
}

/// The roughness of each term written out from the penalty's definition (HSH l(l + 1), PTM
/// the Dirichlet energy over the unit disk), independently of [`Basis::roughness`].
fn roughness(basis: Basis) -> Vec<f64> {
    use std::f64::consts::PI;
    match basis {
        Basis::PtmLrgb | Basis::PtmRgb => vec![PI, PI, PI / 2.0, PI, PI, 0.0],
        Basis::Hsh2 => vec![0.0, 2.0, 2.0, 2.0],
        _ => vec![0.0, 2.0, 2.0, 2.0, 6.0, 6.0, 6.0, 6.0, 6.0],
    }
}

/// Q of the ridge toward PTM, written out from its definition: the points i + ½ of a
/// 4000-point Fibonacci spiral over the hemisphere (l_z = 1 − (i + ½) / 4000, azimuth
/// (i + ½) · π (3 − √5)) at least as high as the lowest light.
fn cap(dirs: &[[f64; 3]]) -> Vec<[f64; 3]> {
    let lowest = dirs.iter().map(|l| l[2]).fold(f64::INFINITY, f64::min);
    (0..4000)
        .map(|i| {
            let (z, phi) = (
                1.0 - (i as f64 + 0.5) / 4000.0,
                (i as f64 + 0.5) * std::f64::consts::PI * (3.0 - 5f64.sqrt()),
            );
            let r = (1.0 - z * z).sqrt();
            [r * phi.cos(), r * phi.sin(), z]
        })
        .filter(|q| q[2] >= lowest)
        .collect()
}

/// The ridge fit of `basis` to the readings `y(k)` of the lights `lights`, as the
/// least-squares solution (nalgebra's SVD) of the basis rows against y stacked on the
/// penalty's rows: toward zero diag(√(λ D_j)) against zeros; toward PTM, for each q of
/// [`cap`], √(λ / |Q|) h(q) against √(λ / |Q|) p(q)ᵀ c_p, c_p PTM's ridge fit (λ_p) of the
/// same readings made the same way.
fn refit(
    dirs: &[[f64; 3]],
    basis: Basis,
    lambda: f64,
    prior: Prior,
    lights: &[usize],
    y: &dyn Fn(usize) -> f64,
) -> Vec<f64> {
    let t = basis.terms();
    let at = |l: [f64; 3], b: Basis| {
        let mut v = [0.0; MAX_TERMS];
        b.eval(l, &mut v);
        v
    };
    let mut rows: Vec<([f64; MAX_TERMS], f64)> =
        lights.iter().map(|&k| (at(dirs[k], basis), y(k))).collect();
    match prior {
        Prior::Zero => {
            for (j, dj) in roughness(basis).into_iter().enumerate() {
                let mut r = [0.0; MAX_TERMS];
                r[j] = (lambda * dj).sqrt();
                rows.push((r, 0.0));
            }
        }
        Prior::Ptm { ptm_lambda } => {
            let cp = refit(dirs, Basis::PtmRgb, ptm_lambda, Prior::Zero, lights, y);
            let q = cap(dirs);
            let w = (lambda / q.len() as f64).sqrt();
            for l in q {
                let p = at(l, Basis::PtmRgb);
                let target: f64 = (0..6).map(|i| p[i] * cp[i]).sum();
                rows.push((at(l, basis).map(|h| w * h), w * target));
            }
        }
    }
    let a = DMatrix::from_fn(rows.len(), t, |r, j| rows[r].0[j]);
    let b = DVector::from_fn(rows.len(), |r, _| rows[r].1);
    let x = a.svd(true, true).solve(&b, 1e-12).unwrap();
    (0..t).map(|j| x[j]).collect()
}

/// The leave-one-out sums by refitting without each light ([`refit`], the fit's ridge),
/// over the lights `kept(p, k)` admits.
fn brute_force_loo(cap: &Capture, f: &RtiFit, kept: &dyn Fn(usize, usize) -> bool) -> Vec<f64> {
    let (n, c, basis) = (cap.n_lights(), cap.channels, f.basis);
    let ridge = f.ridge.as_ref().unwrap();
    let dirs = &cap.lights.directions;
    let mut sse = vec![0.0; n];
    let mut row = [0.0; MAX_TERMS];
    for p in 0..cap.n_pixels() {
        let s = cap.pixel_samples(p);
        let y = |k: usize, ch: usize| f64::from(s[k * c + ch]) * f.gain;
        let lum = |k: usize| (0..c).map(|ch| y(k, ch)).sum::<f64>() / c as f64;
        for k in (0..n).filter(|&k| kept(p, k)) {
            let others: Vec<usize> = (0..n).filter(|&i| i != k && kept(p, i)).collect();
            basis.eval(dirs[k], &mut row);
            let solve = |v: &dyn Fn(usize) -> f64| {
                let x = refit(dirs, basis, ridge.lambda, ridge.prior, &others, v);
                x.iter().zip(row).map(|(x, r)| x * r).sum::<f64>()
            };
            if basis.luminance() {
                let l_pred = solve(&lum);
                let sy: f64 = others.iter().map(|&i| lum(i)).sum();
                for ch in 0..c {
                    let sc: f64 = others.iter().map(|&i| y(i, ch)).sum();
                    let d = sc / sy * l_pred - y(k, ch);
                    sse[k] += d * d;
                }
            } else {
                for ch in 0..c {
                    let d = solve(&|i| y(i, ch)) - y(k, ch);
                    sse[k] += d * d;
                }
            }
        }
    }
    sse
}

/// The fit's coefficients (per channel) against [`refit`] over every light.
fn assert_coefficients_are_refits(cap: &Capture, f: &RtiFit) {
    let (n, c, t) = (cap.n_lights(), cap.channels, f.basis.terms());
    let ridge = f.ridge.as_ref().unwrap();
    let all: Vec<usize> = (0..n).collect();
    for p in 0..cap.n_pixels() {
        let s = cap.pixel_samples(p);
        for ch in 0..c {
            let y = |k: usize| f64::from(s[k * c + ch]) * f.gain;
            let want = refit(
                &cap.lights.directions,
                f.basis,
                ridge.lambda,
                ridge.prior,
                &all,
                &y,
            );
            for (j, w) in want.iter().enumerate() {
                let got = f64::from(f.coefficients[(p * c + ch) * t + j]);
                assert!(
                    (got - w).abs() < 1e-5 * (1.0 + w.abs()),
                    "{} {:?} p{p} c{ch} term {j}: {got} vs {w}",
                    f.basis.name(),
                    ridge.prior
                );
            }
        }
    }
}

#[test]
fn closed_form_leave_one_out_equals_refits_without_each_light() {
    let dirs = lights(24);
    for c in [1, 3] {
        let cap = capture(4, 3, c, &dirs, glossy);
        for basis in Basis::LINEAR {
            // Unregularised, a strong ridge, the ridge chosen from the data and, for HSH, a
            // mild and a strong ridge toward PTM.
            let mut penalties = vec![Penalty::Fixed(0.0), Penalty::Fixed(2.4), Penalty::Auto];
            if matches!(basis, Basis::Hsh2 | Basis::Hsh3) {
                penalties.push(Penalty::TowardPtm {
                    lambda: 2.4,
                    ptm_lambda: 0.5,
                });
                penalties.push(Penalty::TowardPtm {
                    lambda: 240.0,
                    ptm_lambda: 0.0,
                });
            }
            for penalty in penalties {
                let f = fit_penalised(&cap, basis, None, penalty).unwrap();
                if !basis.luminance() {
                    assert_coefficients_are_refits(&cap, &f);
                }
                let brute = brute_force_loo(&cap, &f, &|_, _| true);
                for (k, (&a, &b)) in f.loo.sse.iter().zip(&brute).enumerate() {
                    assert!(
                        (a - b).abs() <= 1e-4 * b.max(1e-6),
                        "{} C={c} {penalty:?} light {k}: closed form {a} vs refits {b}",
                        basis.name()
                    );
                }
                // The glossy lobe is not in any basis: the error is real, not zero.
                assert!(f.loo.mean_rmse_8bit() > 0.1, "{}", basis.name());
            }
        }
    }
}

#[test]
fn the_chosen_ridge_predicts_left_out_lights_at_least_as_well_as_none() {
    // Noisy readings of a glossy reflectance under 14 lights: HSH3's 9 terms chase the noise.
    let dirs = lights(14);
    let noise = |p: usize, k: usize, c: usize| {
        0.05 * ((((p * 31 + k * 17 + c * 7) * 2654435761usize) % 1000) as f64 / 1000.0 - 0.5)
    };
    let cap = capture(8, 6, 3, &dirs, |p, k, c, l| {
        glossy(p, k, c, l) + noise(p, k, c)
    });
    for basis in Basis::LINEAR {
        let plain = fit_penalised(&cap, basis, None, Penalty::Fixed(0.0)).unwrap();
        let auto = fit(&cap, basis, None).unwrap();
        let ridge = auto.ridge.as_ref().unwrap();
        // The sample is every pixel (48 < 4096): the candidates' errors are the fits' own, and
        // λ = 0 is a candidate, so the chosen error is at most the unregularised one.
        assert_eq!(ridge.sample_pixels, 48);
        assert_eq!(ridge.candidates[0].0, 0.0);
        let plain_loo = plain.loo.mean_rmse_8bit();
        assert!((ridge.candidates[0].1 - plain_loo).abs() < 1e-9 * plain_loo);
        let least = ridge
            .candidates
            .iter()
            .chain(&ridge.toward_ptm)
            .map(|c| c.1)
            .fold(f64::INFINITY, f64::min);
        // HSH also tries every λ > 0 of the grid toward PTM; PTM has no such prior.
        let hsh = matches!(basis, Basis::Hsh2 | Basis::Hsh3);
        assert_eq!(ridge.toward_ptm.len(), if hsh { 17 } else { 0 });
        assert_eq!(
            matches!(ridge.prior, Prior::Ptm { .. }),
            least
                < ridge
                    .candidates
                    .iter()
                    .map(|c| c.1)
                    .fold(f64::INFINITY, f64::min)
        );
        assert_eq!(auto.loo.mean_rmse_8bit(), least, "{}", basis.name());
        assert!(least <= plain_loo, "{}", basis.name());
        if basis == Basis::Hsh3 {
            assert!(ridge.lambda > 0.0 && least < 0.9 * plain_loo, "{ridge:?}");
        }
    }
}

#[test]
fn hsh2_under_five_lights_keeps_its_ridge_toward_zero() {
    // Five lights determine HSH2's four terms but not PTM's six: no PTM to pull toward.
    let dirs = lights(5);
    let cap = capture(3, 2, 3, &dirs, glossy);
    let f = fit(&cap, Basis::Hsh2, None).unwrap();
    let ridge = f.ridge.as_ref().unwrap();
    assert_eq!(ridge.prior, Prior::Zero);
    assert!(ridge.toward_ptm.is_empty());
    assert_eq!(ridge.candidates.len(), 18);
    assert!(fit(&cap, Basis::PtmRgb, None).is_err());
}

#[test]
fn the_ridge_leaves_what_the_constant_term_holds() {
    // The constant term is not penalised: readings that do not depend on the light are fitted
    // exactly whatever λ, every other coefficient zero, nothing to predict when left out.
    let dirs = lights(14);
    let flat = capture(3, 2, 1, &dirs, |p, _, _, _| 0.2 + 0.1 * p as f64);
    for basis in Basis::LINEAR {
        let f = fit_penalised(&flat, basis, None, Penalty::Fixed(1400.0)).unwrap();
        let (t, constant) = match basis {
            Basis::PtmLrgb | Basis::PtmRgb => (6, 5),
            _ => (basis.terms(), 0),
        };
        let unit = if constant == 0 {
            (2.0 * std::f64::consts::PI).sqrt()
        } else {
            1.0
        };
        for p in 0..6 {
            for j in 0..t {
                let got = f64::from(f.coefficients[p * t + j]) / f.gain;
                let want = if j == constant {
                    (0.2 + 0.1 * p as f64) * unit
                } else {
                    0.0
                };
                assert!(
                    (got - want).abs() < 1e-5,
                    "{} p{p} term {j}: {got}",
                    basis.name()
                );
            }
        }
        assert!(f.loo.mean_rmse_8bit() < 1e-3, "{}", basis.name());
    }
}

#[test]
fn the_ridge_shrinks_each_term_by_its_roughness_on_an_orthogonal_design() {
    // Two rings of 8 lights at cos θ = 0.3 and 0.7, azimuths 45° apart: Σ_k H_i H_j = 0 for
    // i ≠ j over HSH order 2 (Σ (2 cos θ − 1) = 0, the azimuth sums of cos φ, sin φ, cos φ sin φ
    // vanish), so the ridge solves each term alone: c_j = ĉ_j G_jj / (G_jj + λ D_j), ĉ the
    // coefficients the readings were made from, G_jj = Σ_k H_j(l_k)²:
    // G_00 = 16 / (2π), G_11 = G_33 = (6/π) · 8 · 0.21 (cos θ − cos² θ = 0.21 on both rings,
    // Σ cos² φ = 4 a ring), G_22 = (3 / (2π)) · 16 · 0.16; D = (0, 2, 2, 2).
    use std::f64::consts::PI;
    let dirs: Vec<[f64; 3]> = [0.3f64, 0.7]
        .iter()
        .flat_map(|&ct| {
            let st = (1.0 - ct * ct).sqrt();
            (0..8).map(move |i| {
                let phi = i as f64 * PI / 4.0;
                [st * phi.cos(), st * phi.sin(), ct]
            })
        })
        .collect();
    let truth = [1.0, 0.3, -0.2, 0.15];
    let cap = capture(2, 1, 1, &dirs, |_, _, _, l| {
        let mut b = [0.0; MAX_TERMS];
        Basis::Hsh2.eval(l, &mut b);
        (0..4).map(|j| truth[j] * b[j]).sum()
    });
    let g = [
        16.0 / (2.0 * PI),
        6.0 / PI * 8.0 * 0.21,
        3.0 / (2.0 * PI) * 16.0 * 0.16,
        6.0 / PI * 8.0 * 0.21,
    ];
    let d = [0.0, 2.0, 2.0, 2.0];
    for lambda in [0.0, 0.5, 4.0, 40.0] {
        let f = fit_penalised(&cap, Basis::Hsh2, None, Penalty::Fixed(lambda)).unwrap();
        for j in 0..4 {
            let want = truth[j] * g[j] / (g[j] + lambda * d[j]);
            let got = f64::from(f.coefficients[j]) / f.gain;
            assert!(
                (got - want).abs() < 1e-5,
                "λ {lambda} term {j}: {got} vs {want}"
            );
        }
    }
}

#[test]
fn the_roughness_is_the_dirichlet_energy_of_each_term() {
    use std::f64::consts::PI;
    let m = 400;
    // PTM: ∫ over the unit disk of |∇ b_j|², by a midpoint rule in polar coordinates, the
    // gradients written out ((2u, 0), (0, 2v), (v, u), (1, 0), (0, 1), 0).
    let mut want = [0.0; 6];
    for i in 0..m {
        let r = (i as f64 + 0.5) / m as f64;
        for a in 0..m {
            let phi = (a as f64 + 0.5) / m as f64 * 2.0 * PI;
            let (u, v) = (r * phi.cos(), r * phi.sin());
            let w = r * (2.0 * PI) / (m * m) as f64;
            let g2 = [4.0 * u * u, 4.0 * v * v, u * u + v * v, 1.0, 1.0, 0.0];
            for (a, g) in want.iter_mut().zip(g2) {
                *a += g * w;
            }
        }
    }
    let mut got = [0.0; MAX_TERMS];
    Basis::PtmRgb.roughness(&mut got);
    for (j, (g, w)) in got.iter().zip(want).enumerate() {
        assert!((g - w).abs() < 1e-4, "ptm term {j}: {g} vs {w}");
    }
    // HSH: on the sphere the hemisphere is stretched to (cos θ' = 2 cos θ − 1), H_j is an
    // eigenfunction of the Laplacian: ∫|∇H_j|² dω' = l(l + 1) ∫ H_j² dω' = 2 l(l + 1) (the
    // stretch doubles the measure of ∫ H_j² dω = 1). Finite differences of the library's H_j
    // in (θ', φ), |∇f|² = f_θ'² + f_φ² / sin² θ'.
    let h = |j: usize, tp: f64, phi: f64| {
        let ct = (tp.cos() + 1.0) / 2.0;
        let st = (1.0 - ct * ct).sqrt();
        let mut b = [0.0; MAX_TERMS];
        Basis::Hsh3.eval([st * phi.cos(), st * phi.sin(), ct], &mut b);
        b[j]
    };
    Basis::Hsh3.roughness(&mut got);
    let e = 1e-5;
    let independent = roughness(Basis::Hsh3);
    for (j, &dj) in got.iter().enumerate() {
        let mut energy = 0.0;
        for i in 0..m {
            let tp = (i as f64 + 0.5) / m as f64 * PI;
            for a in 0..m {
                let phi = (a as f64 + 0.5) / m as f64 * 2.0 * PI;
                let ft = (h(j, tp + e, phi) - h(j, tp - e, phi)) / (2.0 * e);
                let fp = (h(j, tp, phi + e) - h(j, tp, phi - e)) / (2.0 * e);
                let w = tp.sin() * PI * 2.0 * PI / (m * m) as f64;
                energy += (ft * ft + fp * fp / (tp.sin() * tp.sin())) * w;
            }
        }
        assert!(
            (energy - 2.0 * dj).abs() < 1e-2,
            "hsh term {j}: {energy} vs 2·{dj}"
        );
        assert_eq!(dj, independent[j]);
    }
}

#[test]
fn clipped_readings_leave_a_fit_that_excludes_readings() {
    // A 16-bit capture whose glossy readings pass full scale at some pixels: those readings
    // sit at 65535, bound their light's value from below only, and a fit that leaves
    // readings out (`exclude`, here flagging none) leaves them out too; a fit without `exclude`
    // keeps every reading.
    let dirs = lights(24);
    let (w, h, n) = (4, 3, dirs.len());
    let value = |p: usize, k: usize, c: usize| 0.8 * glossy(p, k, c, dirs[k]);
    let a = Array4::from_shape_fn((n, h, w, 3), |(k, y, x, c)| {
        (value(y * w + x, k, c).clamp(0.0, 1.0) * 65535.0).round() as u16
    });
    let cap = Capture::from_stack(Stack::U16(a.view()), Lights::new(&dirs).unwrap(), None).unwrap();
    let full = |p: usize, k: usize| (0..3).any(|c| a[[k, p / w, p % w, c]] == 65535);
    let clipped = (0..w * h).flat_map(|p| (0..n).map(move |k| (p, k)));
    let count = clipped.filter(|&(p, k)| full(p, k)).count();
    assert!(count > 10 && count < w * h * n / 2, "{count}");
    let none = vec![false; w * h * n];
    for basis in [Basis::PtmRgb, Basis::Hsh3] {
        let f = fit_penalised(&cap, basis, Some(&none), Penalty::Fixed(0.5)).unwrap();
        assert_eq!(f.excluded_readings, count as u64, "{}", basis.name());
        let brute = brute_force_loo(&cap, &f, &|p, k| !full(p, k));
        for (k, (&x, &y)) in f.loo.sse.iter().zip(&brute).enumerate() {
            assert!(
                (x - y).abs() <= 1e-4 * y.max(1e-6),
                "{} light {k}: {x} vs {y}",
                basis.name()
            );
        }
        let all = fit_penalised(&cap, basis, None, Penalty::Fixed(0.5)).unwrap();
        assert_eq!(all.excluded_readings, 0);
    }
}

#[test]
fn excluded_readings_leave_the_fit_and_its_error() {
    let dirs = lights(24);
    let cap = capture(4, 3, 3, &dirs, glossy);
    let n = dirs.len();
    // Exclude a different handful of lights per pixel (and none at pixel 0).
    let kept = |p: usize, k: usize| p == 0 || (k + p) % 5 != 0;
    let flags: Vec<bool> = (0..cap.n_pixels())
        .flat_map(|p| (0..n).map(move |k| !kept(p, k)))
        .collect();
    for (basis, penalty) in [
        (Basis::PtmLrgb, Penalty::Auto),
        (Basis::Hsh3, Penalty::Auto),
        (Basis::PtmLrgb, Penalty::Fixed(1.0)),
        (Basis::Hsh3, Penalty::Fixed(1.0)),
        (
            Basis::Hsh3,
            Penalty::TowardPtm {
                lambda: 2.4,
                ptm_lambda: 0.5,
            },
        ),
    ] {
        let f = fit_penalised(&cap, basis, Some(&flags), penalty).unwrap();
        let brute = brute_force_loo(&cap, &f, &kept);
        for (k, (&a, &b)) in f.loo.sse.iter().zip(&brute).enumerate() {
            assert!(
                (a - b).abs() <= 1e-4 * b.max(1e-6),
                "{} light {k}: {a} vs {b}",
                basis.name()
            );
        }
        assert_eq!(
            f.excluded_readings,
            flags.iter().filter(|&&x| x).count() as u64
        );
    }
}

// ---- Readers from the format descriptions -------------------------------------------------

/// Splits `n` newline-terminated ASCII lines off the front of `bytes`.
fn lines(bytes: &[u8], n: usize) -> (Vec<String>, &[u8]) {
    let mut out = Vec::new();
    let mut rest = bytes;
    while out.len() < n {
        let end = rest.iter().position(|&b| b == b'\n').unwrap();
        out.push(
            String::from_utf8(rest[..end].to_vec())
                .unwrap()
                .trim()
                .to_string(),
        );
        rest = &rest[end + 1..];
    }
    (out, rest)
}

/// A `.ptm` file: (format, width, height, coefficients `[row from top][col][plane][6]`, scales,
/// rgb `[row from top][col][3]` for LRGB).
fn read_ptm(path: &std::path::Path) -> (String, usize, usize, Vec<f64>, Vec<f64>, Vec<u8>) {
    let bytes = std::fs::read(path).unwrap();
    let (head, mut rest) = lines(&bytes, 6);
    assert_eq!(head[0], "PTM_1.2");
    let (w, h): (usize, usize) = (head[2].parse().unwrap(), head[3].parse().unwrap());
    let scale: Vec<f64> = head[4]
        .split_whitespace()
        .map(|v| v.parse().unwrap())
        .collect();
    let bias: Vec<i32> = head[5]
        .split_whitespace()
        .map(|v| v.parse().unwrap())
        .collect();
    assert_eq!((scale.len(), bias.len()), (6, 6));
    let planes = if head[1] == "PTM_FORMAT_LRGB" { 1 } else { 3 };
    let mut coeffs = vec![0.0; w * h * planes * 6];
    for plane in 0..planes {
        for y in (0..h).rev() {
            for x in 0..w {
                for j in 0..6 {
                    let v = (f64::from(rest[0]) - f64::from(bias[j])) * scale[j];
                    coeffs[((y * w + x) * planes + plane) * 6 + j] = v;
                    rest = &rest[1..];
                }
            }
        }
    }
    let mut rgb = vec![0u8; if planes == 1 { w * h * 3 } else { 0 }];
    if planes == 1 {
        for y in (0..h).rev() {
            rgb[y * w * 3..(y + 1) * w * 3].copy_from_slice(&rest[..w * 3]);
            rest = &rest[w * 3..];
        }
    }
    assert!(rest.is_empty(), "{} bytes after the data", rest.len());
    (head[1].clone(), w, h, coeffs, scale, rgb)
}

/// A `.rti` HSH file: (width, height, terms, coefficients `[row][col][band][term]`, scales).
fn read_hsh(path: &std::path::Path) -> (usize, usize, usize, Vec<f64>, Vec<f64>) {
    let bytes = std::fs::read(path).unwrap();
    let (head, rest) = lines(&bytes, 4);
    assert!(head[0].starts_with('#'));
    assert_eq!(head[1], "3");
    let dims: Vec<usize> = head[2]
        .split_whitespace()
        .map(|v| v.parse().unwrap())
        .collect();
    let basis: Vec<usize> = head[3]
        .split_whitespace()
        .map(|v| v.parse().unwrap())
        .collect();
    let (w, h, t) = (dims[0], dims[1], basis[0]);
    assert_eq!((dims[2], basis[1], basis[2]), (3, 2, 1));
    let f32s = |at: usize| -> Vec<f64> {
        (0..t)
            .map(|j| {
                f64::from(f32::from_le_bytes(
                    rest[at + 4 * j..at + 4 * j + 4].try_into().unwrap(),
                ))
            })
            .collect()
    };
    let (scale, bias) = (f32s(0), f32s(4 * t));
    let data = &rest[8 * t..];
    assert_eq!(data.len(), w * h * 3 * t);
    let coeffs = data
        .iter()
        .enumerate()
        .map(|(i, &b)| f64::from(b) / 255.0 * scale[i % t] + bias[i % t])
        .collect();
    (w, h, t, coeffs, scale)
}

#[test]
fn files_hold_the_fit_within_their_quantisation() {
    let dirs = lights(30);
    let (w, h) = (7, 5);
    let cap = capture(w, h, 3, &dirs, glossy);
    let dir = std::env::temp_dir().join(format!("photostereo-rti-files-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    for basis in Basis::LINEAR {
        let f = fit(&cap, basis, None).unwrap();
        let t = basis.terms();
        let mut b = [0.0; MAX_TERMS];
        let mut want = [0.0; 3];
        if basis.luminance() || basis == Basis::PtmRgb {
            let path = dir.join("image.ptm");
            let maps = photostereo::io::rti::ptm::write_ptm(&path, &f).unwrap();
            let (format, fw, fh, coeffs, scale, rgb) = read_ptm(&path);
            assert_eq!((fw, fh), (w, h));
            assert_eq!(format == "PTM_FORMAT_LRGB", basis.luminance());
            let planes = if basis.luminance() { 1 } else { 3 };
            for p in 0..w * h {
                for (k, l) in dirs.iter().enumerate().step_by(7) {
                    basis.eval(*l, &mut b);
                    f.predict(p, *l, &mut want);
                    for ch in 0..3 {
                        let plane = ch.min(planes - 1);
                        let c = &coeffs[(p * planes + plane) * 6..(p * planes + plane + 1) * 6];
                        let poly: f64 = (0..6).map(|j| c[j] * b[j]).sum();
                        // A viewer's colour: R · L / 255 (LRGB) or the polynomial (RGB).
                        let shown = if basis.luminance() {
                            f64::from(rgb[p * 3 + ch]) * poly / 255.0
                        } else {
                            poly
                        };
                        // Quantisation: half a step per coefficient (and per chroma byte).
                        let step: f64 = (0..6).map(|j| 0.5 * scale[j] * b[j].abs()).sum::<f64>()
                            + if basis.luminance() {
                                poly.abs() / 255.0
                            } else {
                                0.0
                            };
                        let err = (shown - 255.0 * want[ch]).abs();
                        assert!(
                            err <= step * 1.01 + 1e-6,
                            "{} p{p} k{k} ch{ch}: {err} > {step}",
                            basis.name()
                        );
                    }
                }
            }
            assert_eq!(maps.len(), 6);
        } else {
            let path = dir.join("image.rti");
            photostereo::io::rti::hsh::write_hsh(&path, &f).unwrap();
            let (fw, fh, ft, coeffs, scale) = read_hsh(&path);
            assert_eq!((fw, fh, ft), (w, h, t));
            for p in 0..w * h {
                for ch in 0..3 {
                    for j in 0..t {
                        let got = coeffs[(p * 3 + ch) * t + j];
                        let float = f64::from(f.coefficients[(p * 3 + ch) * t + j]);
                        assert!((got - float).abs() <= scale[j] / 255.0 * 0.5 * 1.001 + 1e-7);
                    }
                }
            }
        }
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn near_lights_and_degenerate_rigs_are_refused() {
    // Every light at one elevation: PTM's l_u² + l_v² equals its constant term.
    let ring: Vec<[f64; 3]> = (0..12)
        .map(|k| {
            let a = k as f64 * std::f64::consts::PI / 6.0;
            [0.6 * a.cos(), 0.6 * a.sin(), 0.8]
        })
        .collect();
    let cap = capture(3, 3, 1, &ring, |_, k, _, _| 0.5 + 0.01 * k as f64);
    let e = fit(&cap, Basis::PtmLrgb, None).unwrap_err().to_string();
    assert!(e.contains("do not determine"), "{e}");
}

#[test]
fn hsh_basis_is_orthonormal_over_the_hemisphere() {
    // ∫ H_i H_j dω over the upper hemisphere = δ_ij (Gautron et al. 2004), by a midpoint rule
    // in (cos θ, φ) with dω = d(cos θ) dφ.
    let (m, t) = (400, 9);
    let mut gram = vec![0.0; t * t];
    let mut b = [0.0; MAX_TERMS];
    let w = 2.0 * std::f64::consts::PI / (m * m) as f64;
    for i in 0..m {
        let ct = (i as f64 + 0.5) / m as f64;
        let st = (1.0 - ct * ct).sqrt();
        for j in 0..m {
            let phi = (j as f64 + 0.5) / m as f64 * 2.0 * std::f64::consts::PI;
            Basis::Hsh3.eval([st * phi.cos(), st * phi.sin(), ct], &mut b);
            for a in 0..t {
                for c in 0..t {
                    gram[a * t + c] += b[a] * b[c] * w;
                }
            }
        }
    }
    for a in 0..t {
        for c in 0..t {
            let want = if a == c { 1.0 } else { 0.0 };
            let got = gram[a * t + c];
            assert!((got - want).abs() < 1e-3, "({a},{c}) {got}");
        }
    }
}

/// A reflectance that varies from pixel to pixel in normal, colour and shininess, so that the
/// pixels' readings span many dimensions.
fn varied(p: usize, _k: usize, c: usize, l: [f64; 3]) -> f64 {
    let h = |s: usize| ((p * 2654435761 + s * 40503) % 1000) as f64 / 1000.0;
    let n = [0.5 * (h(1) - 0.5), 0.5 * (h(2) - 0.5), 1.0];
    let nn = (n[0] * n[0] + n[1] * n[1] + 1.0f64).sqrt();
    let ndl = ((n[0] * l[0] + n[1] * l[1] + n[2] * l[2]) / nn).max(0.0);
    let hz = ((n[0] * l[0] + n[1] * l[1] + n[2] * (l[2] + 1.0)) / nn) / (2.0 * (1.0 + l[2])).sqrt();
    let albedo = 0.3 + 0.5 * h(3 + c);
    albedo * ndl + 0.3 * h(7) * hz.max(0.0).powf(5.0 + 30.0 * h(8))
}

/// relight's RBF weights written from its description: exp(−|l − l_i|²/σ²) normalised, those
/// ≤ 0.001 dropped, the rest renormalised; light `skip` left out.
fn rbf_weights(lights: &[[f64; 3]], sigma: f64, l: [f64; 3], skip: usize) -> Vec<f64> {
    let mut w: Vec<f64> = lights
        .iter()
        .enumerate()
        .map(|(i, li)| {
            let d2: f64 = (0..3).map(|a| (li[a] - l[a]).powi(2)).sum();
            if i == skip {
                0.0
            } else {
                (-d2 / (sigma * sigma)).exp()
            }
        })
        .collect();
    let s: f64 = w.iter().sum();
    w.iter_mut().for_each(|x| *x /= s);
    w.iter_mut().filter(|x| **x <= 0.001).for_each(|x| *x = 0.0);
    let s: f64 = w.iter().sum();
    w.iter_mut().for_each(|x| *x /= s);
    w
}

/// The median over the lights of the distance to the nearest other light.
fn median_nearest(lights: &[[f64; 3]]) -> f64 {
    let mut d: Vec<f64> = (0..lights.len())
        .map(|i| {
            (0..lights.len())
                .filter(|&j| j != i)
                .map(|j| {
                    (0..3)
                        .map(|a| (lights[i][a] - lights[j][a]).powi(2))
                        .sum::<f64>()
                })
                .fold(f64::INFINITY, f64::min)
                .sqrt()
        })
        .collect();
    d.sort_by(f64::total_cmp);
    d[d.len() / 2]
}

/// The leave-one-out SSE per light of an RBF fit with kernel width `sigma`, by refits: PCA by
/// nalgebra's SVD of the centred readings without each light (not the library's covariance
/// eigenvectors), projection, kernel interpolation.
fn rbf_refit_sse(cap: &Capture, gain: f64, dirs: &[[f64; 3]], sigma: f64) -> Vec<f64> {
    let (n, c, m) = (dirs.len(), cap.channels, cap.n_pixels());
    let planes = rbf::components(n, c);
    let x = |p: usize, r: usize| f64::from(cap.pixel_samples(p)[r]) * gain;
    let mut sse = vec![0.0; n];
    for k in 0..n {
        let cols: Vec<usize> = (0..n * c).filter(|&r| r / c != k).collect();
        let mean: Vec<f64> = cols
            .iter()
            .map(|&r| (0..m).map(|p| x(p, r)).sum::<f64>() / m as f64)
            .collect();
        let centred = DMatrix::from_fn(m, cols.len(), |p, j| x(p, cols[j]) - mean[j]);
        let svd = centred.svd(false, true);
        let vt = svd.v_t.unwrap();
        let mut order: Vec<usize> = (0..svd.singular_values.len()).collect();
        order.sort_by(|&a, &b| svd.singular_values[b].total_cmp(&svd.singular_values[a]));
        let wk = rbf_weights(dirs, sigma, dirs[k], k);
        for p in 0..m {
            let coef: Vec<f64> = order[..planes]
                .iter()
                .map(|&o| {
                    (0..cols.len())
                        .map(|j| vt[(o, j)] * (x(p, cols[j]) - mean[j]))
                        .sum()
                })
                .collect();
            for ch in 0..c {
                let mut pred = 0.0;
                for (j, &r) in cols.iter().enumerate() {
                    if r % c == ch {
                        let rec: f64 = mean[j]
                            + (0..planes)
                                .map(|q| coef[q] * vt[(order[q], j)])
                                .sum::<f64>();
                        pred += wk[r / c] * rec;
                    }
                }
                sse[k] += (pred - x(p, k * c + ch)).powi(2);
            }
        }
    }
    sse
}

#[test]
fn rbf_kernel_leave_one_out_equals_refits_without_each_light() {
    // relight's own interpolant (the readings' values at the lights), the chosen width and a
    // fixed one twice the default: the closed-form leave-one-out error equals refits without
    // each light under the fit's σ.
    let dirs = lights(20);
    let default = median_nearest(&dirs);
    for c in [1, 3] {
        let cap = capture(6, 5, c, &dirs, varied);
        for width in [Width::Auto, Width::Fixed(2.0 * default)] {
            let f = rbf::fit_with(&cap, width, Smoothing::Fixed(Interpolant::Kernel)).unwrap();
            let model = f.rbf.as_ref().unwrap();
            let kernel = f.kernel.as_ref().unwrap();
            assert!((kernel.default - default).abs() < 1e-12);
            assert_eq!(model.lights.len(), dirs.len());
            if width != Width::Auto {
                assert_eq!(model.sigma, 2.0 * default);
            }
            let sse = rbf_refit_sse(&cap, f.gain, &dirs, model.sigma);
            for (k, (&a, &b)) in f.loo.sse.iter().zip(&sse).enumerate() {
                assert!(
                    (a - b).abs() <= 1e-6 * b.max(1e-9),
                    "C={c} {width:?} light {k}: {a} vs {b}"
                );
            }
            assert!(f.loo.mean_rmse_8bit() > 0.1);
        }
    }
}

/// `varied` with pixel 0 white under every light: the 99.5th percentile of the readings, so
/// the display gain, is 1 with or without any one light.
fn varied_white(p: usize, k: usize, c: usize, l: [f64; 3]) -> f64 {
    if p == 0 {
        1.0
    } else {
        0.9 * varied(p, k, c, l)
    }
}

/// The smoother with a ridge and a smoothing in the middle of their grids.
fn smooth(dirs: &[[f64; 3]], lambda: f64) -> Interpolant {
    Interpolant::Smooth {
        lambda,
        ridge: 1e-3 * dirs.len() as f64,
        width: smoother::spacing(dirs),
    }
}

#[test]
fn rbf_leave_one_out_is_the_file_written_without_each_light() {
    // The closed form against refits: the capture without light k fitted by the library with
    // the same σ and interpolant (its own PCA, smoother, render positions, deconvolution) and
    // rendered at l_k.
    let dirs = lights(20);
    let step = smoother::render_positions(&dirs).1;
    for c in [1, 3] {
        let cap = capture(6, 5, c, &dirs, varied_white);
        for interp in [
            smooth(&dirs, 0.1),
            smooth(&dirs, 0.0),
            smooth(&dirs, f64::INFINITY),
        ] {
            let (width, smoothing) = (Width::Fixed(0.5 * step), Smoothing::Fixed(interp));
            let f = rbf::fit_with(&cap, width, smoothing).unwrap();
            assert_eq!(f.gain, 1.0);
            assert_eq!(f.rbf.as_ref().unwrap().interpolant, interp);
            for k in 0..dirs.len() {
                let rest: Vec<[f64; 3]> = (0..dirs.len())
                    .filter(|&i| i != k)
                    .map(|i| dirs[i])
                    .collect();
                let without = capture(6, 5, c, &rest, |p, i, ch, l| {
                    varied_white(p, if i < k { i } else { i + 1 }, ch, l)
                });
                let g = rbf::fit_with(&without, width, smoothing).unwrap();
                assert_eq!(g.gain, 1.0);
                let mut got = [0.0; 3];
                let mut sse = 0.0;
                for p in 0..30 {
                    g.predict(p, dirs[k], &mut got);
                    for (ch, &v) in got.iter().enumerate().take(c) {
                        sse += (v - varied_white(p, k, ch, dirs[k])).powi(2);
                    }
                }
                // The refit predicts from its f32 coefficients: agreement to their precision.
                let a = f.loo.sse[k];
                assert!(
                    (a - sse).abs() <= 1e-4 * sse + 1e-10,
                    "C={c} {interp:?} light {k}: {a} vs {sse}"
                );
            }
            assert!(f.loo.mean_rmse_8bit() > 0.1);
        }
    }
}

#[test]
fn rbf_chooses_the_candidate_of_least_error_never_worse_than_the_quadratic_or_the_kernel() {
    // 30 pixels: the sample is every pixel, so each candidate's error is the fit's own.
    let dirs = lights(20);
    let cap = capture(6, 5, 3, &dirs, varied);
    let f = rbf::fit_width(&cap, Width::Auto).unwrap();
    let kernel = f.kernel.as_ref().unwrap();
    assert_eq!(kernel.sample_pixels, 30);
    assert_eq!(kernel.ridge_candidates.len(), 18);
    let finite: Vec<&rbf::Candidate> = kernel
        .candidates
        .iter()
        .filter(|c| c.loo.is_finite())
        .collect();
    let least = finite.iter().map(|c| c.loo).fold(f64::INFINITY, f64::min);
    let got = f.loo.mean_rmse_8bit();
    assert!((got - least).abs() <= 1e-9 * least, "{got} vs {least}");
    let model = f.rbf.as_ref().unwrap();
    assert!(kernel
        .candidates
        .iter()
        .any(|c| c.sigma == model.sigma && c.interpolant == model.interpolant));
    // Among the candidates: the ridge quadratic (PTM's fit, rendered) and relight's kernel
    // average at each σ, refitted alone with the same error.
    let quadratic = finite
        .iter()
        .find(|c| c.interpolant.name() == "quadratic")
        .unwrap();
    let relight = finite
        .iter()
        .find(|c| c.interpolant == Interpolant::Kernel)
        .unwrap();
    for c in [quadratic, relight] {
        assert!(got <= c.loo);
        let alone = rbf::fit_with(&cap, Width::Fixed(c.sigma), Smoothing::Fixed(c.interpolant))
            .unwrap()
            .loo
            .mean_rmse_8bit();
        assert!((alone - c.loo).abs() <= 1e-9 * alone, "{c:?}: {alone}");
    }
    // relight's own fit with its σ chosen as before is never better.
    let old = rbf::fit_with(&cap, Width::Auto, Smoothing::Fixed(Interpolant::Kernel)).unwrap();
    assert!(got <= old.loo.mean_rmse_8bit());
    // The plain fit chooses as fit_width(Auto); values out of range are refused by name.
    assert_eq!(
        fit(&cap, Basis::Rbf, None).unwrap().rbf.unwrap().sigma,
        model.sigma
    );
    for bad in [0.0, -1.0, f64::NAN] {
        let e = rbf::fit_width(&cap, Width::Fixed(bad))
            .unwrap_err()
            .to_string();
        assert!(e.contains("rbf_sigma"), "{e}");
        let s = Smoothing::Fixed(Interpolant::Smooth {
            lambda: bad - 1.0,
            ridge: 0.0,
            width: 0.1,
        });
        let e = rbf::fit_with(&cap, Width::Auto, s).unwrap_err().to_string();
        assert!(e.contains("rbf_smoothing"), "{e}");
    }
}

#[test]
fn rbf_renders_quadratic_readings_exactly_at_its_positions() {
    // Readings quadratic in (l_x, l_y): the components hold them, the smoother (ρ = 0)
    // reproduces them at every λ, and the deconvolution makes the file's kernel average equal
    // them at every render position, beyond the outermost lights as well.
    // Lights within 55° of the view axis, so that render positions lie beyond them.
    let dirs: Vec<[f64; 3]> = lights(16)
        .iter()
        .map(|l| {
            let (u, v) = (0.85 * l[0], 0.85 * l[1]);
            [u, v, (1.0 - u * u - v * v).sqrt()]
        })
        .collect();
    let q = |p: usize, c: usize, l: [f64; 3]| {
        let a = |j: usize| ((p * 5 + c * 3 + j * 7) % 11) as f64 / 11.0 - 0.5;
        let (u, v) = (l[0], l[1]);
        0.5 + 0.1 * (a(0) * u + a(1) * v + a(2) * u * u + a(3) * v * v + a(4) * u * v)
    };
    let cap = capture(5, 4, 3, &dirs, |p, _, c, l| q(p, c, l));
    let step = smoother::render_positions(&dirs).1;
    for lambda in [0.0, 0.1, f64::INFINITY] {
        let interp = Interpolant::Smooth {
            lambda,
            ridge: 0.0,
            width: smoother::spacing(&dirs),
        };
        let f = rbf::fit_with(&cap, Width::Fixed(0.5 * step), Smoothing::Fixed(interp)).unwrap();
        let m = f.rbf.as_ref().unwrap();
        assert!(m.lights.len() > dirs.len());
        let outer = dirs.iter().map(|l| l[0].hypot(l[1])).fold(0.0, f64::max);
        assert!(m.lights.iter().any(|l| l[0].hypot(l[1]) > outer));
        let mut got = [0.0; 3];
        for &l in &m.lights {
            for p in 0..20 {
                f.predict(p, l, &mut got);
                for (c, &g) in got.iter().enumerate() {
                    let want = q(p, c, l) * f.gain;
                    assert!(
                        (g - want).abs() < 1e-6,
                        "λ {lambda} p{p} c{c} {l:?}: {g} vs {want}"
                    );
                }
            }
        }
    }
    // A light mask is refused by name, and so is a rig whose lights do not determine a
    // quadratic (one ring).
    let flags = vec![false; 20 * 16];
    let e = fit(&cap, Basis::Rbf, Some(&flags)).unwrap_err().to_string();
    assert!(
        e.contains("exclude_unreliable") || e.contains("light mask"),
        "{e}"
    );
    // 8 grey lights leave 7 dimensions without a light: 7 unit components, the rest zero,
    // and every pixel's coefficients on those zero.
    let few = capture(3, 3, 1, &dirs[..8], |p, k, _, _| {
        0.5 + 0.01 * ((p * 3 + k * 5) % 7) as f64
    });
    let kernel = Smoothing::Fixed(Interpolant::Kernel);
    let f = rbf::fit_with(&few, Width::Fixed(0.5 * step), kernel).unwrap();
    let m = f.rbf.as_ref().unwrap();
    assert_eq!(rbf::components(8, 1), 7);
    for j in 0..rbf::PLANES {
        let norm: f64 = m.pca_planes[j * 8..(j + 1) * 8].iter().map(|v| v * v).sum();
        let want = if j < 7 { 1.0 } else { 0.0 };
        assert!((norm - want).abs() < 1e-9, "plane {j}: |e|² {norm}");
    }
    assert!(f
        .coefficients
        .chunks(rbf::PLANES)
        .all(|c| c[7..].iter().all(|&v| v == 0.0)));
    let ring: Vec<[f64; 3]> = (0..12)
        .map(|i| {
            let a = i as f64 * std::f64::consts::FRAC_PI_6;
            [0.6 * a.cos(), 0.6 * a.sin(), 0.8]
        })
        .collect();
    let one_ring = capture(3, 3, 3, &ring, |p, k, c, _| {
        0.3 + 0.01 * ((p + k * c) % 7) as f64
    });
    let e = fit(&one_ring, Basis::Rbf, None).unwrap_err().to_string();
    assert!(e.contains("conic"), "{e}");
}

/// relight's light functions as the format's readers define them (OpenLIME's `ShaderRTI`):
/// PTM 1, x, y, x², xy, y²; HSH H0…H8 of θ = acos l_z and φ = atan2(l_y, l_x).
fn relight_weights(kind: &str, l: [f64; 3]) -> Vec<f64> {
    use std::f64::consts::PI;
    let (x, y) = (l[0], l[1]);
    if kind == "ptm" {
        return vec![1.0, x, y, x * x, x * y, y * y];
    }
    let phi = y.atan2(x);
    let ct = l[2];
    let s = (ct - ct * ct).max(0.0).sqrt();
    let k = (30.0 / PI).sqrt();
    vec![
        1.0 / (2.0 * PI).sqrt(),
        (6.0 / PI).sqrt() * phi.cos() * s,
        (3.0 / (2.0 * PI)).sqrt() * (2.0 * ct - 1.0),
        (6.0 / PI).sqrt() * phi.sin() * s,
        k * (2.0 * phi).cos() * (ct * ct - ct),
        k * phi.cos() * (2.0 * ct - 1.0) * s,
        (5.0 / (2.0 * PI)).sqrt() * (6.0 * ct * ct - 6.0 * ct + 1.0),
        k * phi.sin() * (2.0 * ct - 1.0) * s,
        k * (2.0 * phi).sin() * (ct * ct - ct),
    ]
}

/// A relight web folder read back: info.json and the dequantised planes `[pixel][plane]`.
fn read_relight(dir: &std::path::Path) -> (serde_json::Value, Vec<f64>) {
    let info: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("info.json")).unwrap()).unwrap();
    let (w, h) = (
        info["width"].as_u64().unwrap() as usize,
        info["height"].as_u64().unwrap() as usize,
    );
    let n = info["nplanes"].as_u64().unwrap() as usize;
    let ext = info["format"].as_str().unwrap();
    let m = &info["materials"][0];
    let f = |key: &str, q: usize| m[key][q].as_f64().unwrap();
    let mut planes = vec![0.0; w * h * n];
    for g in 0..n.div_ceil(3) {
        assert_eq!(ext, "png");
        let file = std::fs::File::open(dir.join(format!("plane_{g}.{ext}"))).unwrap();
        let mut reader = png::Decoder::new(std::io::BufReader::new(file))
            .read_info()
            .unwrap();
        let mut bytes = vec![0u8; reader.output_buffer_size().unwrap()];
        let frame = reader.next_frame(&mut bytes).unwrap();
        assert_eq!((frame.width as usize, frame.height as usize), (w, h));
        assert_eq!(frame.color_type, png::ColorType::Rgb);
        for (i, px) in bytes[..w * h * 3].chunks_exact(3).enumerate() {
            for (k, &byte) in px.iter().enumerate() {
                let q = 3 * g + k;
                if q < n {
                    let t = f64::from(byte) / 255.0;
                    planes[i * n + q] = (t - f("bias", q)) * f("scale", q);
                }
            }
        }
    }
    (info, planes)
}

#[test]
fn relight_web_folders_relight_as_the_fit_within_their_quantisation() {
    let dirs = lights(30);
    let (w, h) = (7, 5);
    let tmp = std::env::temp_dir().join(format!("photostereo-relight-{}", std::process::id()));
    // Lights photographed and not, up to 70° from the view axis.
    let mut probes: Vec<[f64; 3]> = dirs.iter().step_by(6).copied().collect();
    probes.extend([[0.0, 0.0, 1.0], [0.4, -0.3, 0.866], [-0.9, 0.1, 0.42]]);
    for c in [3, 1] {
        let cap = capture(w, h, c, &dirs, varied);
        for basis in Basis::ALL {
            let f = fit(&cap, basis, None).unwrap();
            let dir = tmp.join(format!("{}-{c}", basis.name()));
            photostereo::io::rti::relight::write_relight(&dir, &f).unwrap();
            let (info, planes) = read_relight(&dir);
            let n = info["nplanes"].as_u64().unwrap() as usize;
            let kind = info["type"].as_str().unwrap().to_string();
            let space = info["colorspace"].as_str().unwrap().to_string();
            let m = &info["materials"][0];
            let half = |q: usize| 0.5 * m["scale"][q].as_f64().unwrap() / 255.0;
            let mut want = [0.0; 3];
            for &l in &probes {
                let norm = (l[0] * l[0] + l[1] * l[1] + l[2] * l[2]).sqrt();
                let l = [l[0] / norm, l[1] / norm, l[2] / norm];
                for p in 0..w * h {
                    let v = &planes[p * n..(p + 1) * n];
                    f.predict(p, l, &mut want);
                    for ch in 0..3 {
                        let (shown, bound) = match space.as_str() {
                            "rgb" => {
                                let b = relight_weights(&kind, l);
                                let terms = n / 3;
                                let shown: f64 = (0..terms).map(|j| b[j] * v[3 * j + ch]).sum();
                                let bound: f64 =
                                    (0..terms).map(|j| b[j].abs() * half(3 * j + ch)).sum();
                                (shown, bound)
                            }
                            "lrgb" => {
                                let b = relight_weights(&kind, l);
                                let lum: f64 = (0..6).map(|j| b[j] * v[3 + j]).sum();
                                let dl: f64 = (0..6).map(|j| b[j].abs() * half(3 + j)).sum();
                                let base = v[ch];
                                (lum * base, dl * base + lum.abs() * 0.5 / 255.0 + dl / 255.0)
                            }
                            _ => {
                                let sigma = info["sigma"].as_f64().unwrap();
                                let ls: Vec<[f64; 3]> = info["lights"]
                                    .as_array()
                                    .unwrap()
                                    .chunks(3)
                                    .map(|x| [0, 1, 2].map(|a| x[a].as_f64().unwrap()))
                                    .collect();
                                let wts = rbf_weights(&ls, sigma, l, usize::MAX);
                                let basis = info["basis"].as_array().unwrap();
                                let range = &m["range"];
                                let nl = ls.len();
                                let at = |plane: usize, i: usize| {
                                    basis[(plane * nl + i) * 3 + ch].as_f64().unwrap()
                                };
                                let mut shown: f64 =
                                    (0..nl).map(|i| wts[i] * at(0, i) / 255.0).sum();
                                let mut bound = 0.5 / 255.0 + 1e-3 / 255.0;
                                for j in 0..n {
                                    let r = range[j].as_f64().unwrap();
                                    let e: f64 =
                                        (0..nl).map(|i| wts[i] * (at(j + 1, i) - 127.0) / r).sum();
                                    shown += v[j] * e;
                                    bound += v[j].abs() * 0.5 / r + e.abs() * half(j);
                                }
                                (shown, bound)
                            }
                        };
                        let err = (shown - want[ch.min(c - 1)]).abs();
                        assert!(
                            err <= bound * 1.001 + 1e-6,
                            "{} C={c} p{p} ch{ch} l={l:?}: {shown} vs {} ({err} > {bound})",
                            basis.name(),
                            want[ch.min(c - 1)]
                        );
                    }
                }
            }
            // Pixels are not all equal: the test relights something.
            assert!(planes.iter().any(|&x| x.abs() > 1e-3));
        }
    }
    std::fs::remove_dir_all(&tmp).unwrap();
}

/// A test image whose pixels name their position.
fn test_rgb(w: usize, h: usize) -> Vec<u8> {
    (0..w * h)
        .flat_map(|i| {
            let (x, y) = (i % w, i / w);
            [
                (x % 251) as u8,
                (y % 241) as u8,
                ((x * 7 + y * 13) % 256) as u8,
            ]
        })
        .collect()
}

fn png_rgb(path: &std::path::Path) -> (usize, usize, Vec<u8>) {
    let file = std::fs::File::open(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut reader = png::Decoder::new(std::io::BufReader::new(file))
        .read_info()
        .unwrap();
    let mut bytes = vec![0u8; reader.output_buffer_size().unwrap()];
    let frame = reader.next_frame(&mut bytes).unwrap();
    assert_eq!(frame.color_type, png::ColorType::Rgb);
    bytes.truncate(frame.width as usize * frame.height as usize * 3);
    (frame.width as usize, frame.height as usize, bytes)
}

fn names(dir: &std::path::Path) -> std::collections::BTreeSet<String> {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect()
}

#[test]
fn deep_zoom_pyramid_follows_the_published_layout() {
    // The Deep Zoom layout (Microsoft's DZI schema, as OpenSeadragon reads it): levels 0…L,
    // L = ⌈log2 max(W, H)⌉, level k ⌈W/2^(L−k)⌉ wide; tiles `col_row` of T plus the overlap
    // on the sides that have a neighbour.
    let (w, h, t, o) = (600, 300, 254, 1);
    let rgb = test_rgb(w, h);
    let tmp = tempfile::tempdir().unwrap();
    let dzi = tmp.path().join("img.dzi");
    let (levels, tiles) =
        photostereo::io::rti::tiles::write_deep_zoom(&dzi, (w, h), &rgb, t, o).unwrap();
    let xml = std::fs::read_to_string(&dzi).unwrap();
    for attr in [
        "xmlns=\"http://schemas.microsoft.com/deepzoom/2008\"",
        "Format=\"png\"",
        "Overlap=\"1\"",
        "TileSize=\"254\"",
        "Width=\"600\"",
        "Height=\"300\"",
    ] {
        assert!(xml.contains(attr), "{attr} in {xml}");
    }
    let top = 10; // 2^9 < 600 ≤ 2^10
    assert_eq!(levels, top + 1);
    let files = tmp.path().join("img_files");
    assert_eq!(names(&files).len(), top + 1);
    let mut counted = 0;
    for k in 0..=top {
        let div = 1usize << (top - k);
        let (lw, lh) = (w.div_ceil(div), h.div_ceil(div));
        let (cols, rows) = (lw.div_ceil(t), lh.div_ceil(t));
        let dir = files.join(k.to_string());
        let want: std::collections::BTreeSet<String> = (0..cols)
            .flat_map(|c| (0..rows).map(move |r| format!("{c}_{r}.png")))
            .collect();
        assert_eq!(names(&dir), want, "level {k}");
        for c in 0..cols {
            for r in 0..rows {
                let x0 = if c == 0 { 0 } else { c * t - o };
                let y0 = if r == 0 { 0 } else { r * t - o };
                let x1 = ((c + 1) * t + o).min(lw);
                let y1 = ((r + 1) * t + o).min(lh);
                let (tw, th, px) = png_rgb(&dir.join(format!("{c}_{r}.png")));
                assert_eq!((tw, th), (x1 - x0, y1 - y0), "level {k} tile {c}_{r}");
                if k == top - 1 {
                    // One level down: each pixel the rounded mean of the 2 × 2 block it covers.
                    for y in 0..th {
                        for x in 0..tw {
                            let (gx, gy) = (x0 + x, y0 + y);
                            for ch in 0..3 {
                                let block: Vec<u32> = [(0, 0), (1, 0), (0, 1), (1, 1)]
                                    .iter()
                                    .map(|(dx, dy)| (2 * gx + dx, 2 * gy + dy))
                                    .filter(|&(sx, sy)| sx < w && sy < h)
                                    .map(|(sx, sy)| u32::from(rgb[(sy * w + sx) * 3 + ch]))
                                    .collect();
                                let n = block.len() as u32;
                                let mean = (block.iter().sum::<u32>() + n / 2) / n;
                                assert_eq!(u32::from(px[(y * tw + x) * 3 + ch]), mean);
                            }
                        }
                    }
                }
                if k == top {
                    for y in 0..th {
                        for x in 0..tw {
                            let src = ((y0 + y) * w + x0 + x) * 3;
                            assert_eq!(&px[(y * tw + x) * 3..][..3], &rgb[src..src + 3]);
                        }
                    }
                }
                counted += 1;
            }
        }
    }
    assert_eq!(tiles, counted);
}

#[test]
fn iiif_level0_tiles_are_where_a_client_asks_for_them() {
    // IIIF Image API 3.0: info.json of a level-0 service, and the tile requests
    // {x},{y},{w},{h}/{w'},{h'}/0/default.jpg a client derives from it.
    let (w, h, t) = (1100, 700, 512);
    let rgb = test_rgb(w, h);
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("iiif");
    photostereo::io::rti::tiles::write_iiif(&dir, "https://example.org/img", (w, h), &rgb, t)
        .unwrap();
    let info: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("info.json")).unwrap()).unwrap();
    assert_eq!(info["@context"], "http://iiif.io/api/image/3/context.json");
    assert_eq!(info["type"], "ImageService3");
    assert_eq!(info["protocol"], "http://iiif.io/api/image");
    assert_eq!(info["profile"], "level0");
    assert_eq!(info["id"], "https://example.org/img");
    assert_eq!(
        (info["width"].as_u64(), info["height"].as_u64()),
        (Some(1100), Some(700))
    );
    let tiles = &info["tiles"][0];
    assert_eq!(
        (tiles["width"].as_u64(), tiles["height"].as_u64()),
        (Some(512), Some(512))
    );
    // 1100 / 4 = 275 ≤ 512: scale factors 1, 2, 4.
    let scales: Vec<u64> = tiles["scaleFactors"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_u64().unwrap())
        .collect();
    assert_eq!(scales, [1, 2, 4]);
    let mut expected = std::collections::BTreeSet::from(["info.json".to_string(), "full".into()]);
    for &s in &scales {
        let s = s as usize;
        let span = t * s;
        for y in (0..h).step_by(span) {
            for x in (0..w).step_by(span) {
                let (rw, rh) = (span.min(w - x), span.min(h - y));
                let (tw, th) = (rw.div_ceil(s), rh.div_ceil(s));
                let region = format!("{x},{y},{rw},{rh}");
                let path = dir.join(format!("{region}/{tw},{th}/0/default.jpg"));
                let img = image::open(&path)
                    .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
                    .to_rgb8();
                assert_eq!((img.width() as usize, img.height() as usize), (tw, th));
                if s == 1 {
                    // JPEG at quality 90: the tile's pixels within a few levels of the image's.
                    let err: f64 = img
                        .pixels()
                        .enumerate()
                        .map(|(i, p)| {
                            let src = ((y + i / tw) * w + x + i % tw) * 3;
                            (0..3)
                                .map(|k| (f64::from(p[k]) - f64::from(rgb[src + k])).abs())
                                .sum::<f64>()
                        })
                        .sum::<f64>()
                        / (3 * tw * th) as f64;
                    assert!(err < 6.0, "{region}: mean error {err}");
                }
                expected.insert(region);
            }
        }
    }
    assert_eq!(names(&dir), expected);
    // The sizes, each a whole image at full/{w},{h}.
    let sizes = info["sizes"].as_array().unwrap();
    assert_eq!(sizes.len(), 3);
    for sz in sizes {
        let (sw, sh) = (
            sz["width"].as_u64().unwrap(),
            sz["height"].as_u64().unwrap(),
        );
        assert!(dir.join(format!("full/{sw},{sh}/0/default.jpg")).is_file());
    }
}

/// The bytes of every file under `dir`, by relative path.
fn tree(dir: &std::path::Path) -> std::collections::BTreeMap<String, Vec<u8>> {
    let mut out = std::collections::BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                let name = p.strip_prefix(dir).unwrap().display().to_string();
                out.insert(name, std::fs::read(&p).unwrap());
            }
        }
    }
    out
}

#[test]
fn files_streamed_from_the_coefficient_files_equal_those_of_a_fit_held_whole() {
    use photostereo::io::rti::{
        hsh::write_hsh, ptm::write_ptm, relight::write_relight, write_float_coefficients,
        CoefficientFiles,
    };
    let dirs = lights(30);
    let (w, h) = (9, 7);
    // A mask with gaps within rows and whole rows out: the files' runs and holes.
    let mask = ndarray::Array2::from_shape_fn((h, w), |(y, x)| y != 2 && (x + 2 * y) % 5 != 0);
    let mut a = Array4::<f32>::zeros((dirs.len(), h, w, 3));
    for (k, l) in dirs.iter().enumerate() {
        for p in 0..w * h {
            for ch in 0..3 {
                a[[k, p / w, p % w, ch]] = glossy(p, k, ch, *l) as f32;
            }
        }
    }
    let lights = Lights::new(&dirs).unwrap();
    let cap = Capture::from_stack(Stack::F32(a.view()), lights, Some(mask.view())).unwrap();
    let root = std::env::temp_dir().join(format!("photostereo-rti-stream-{}", std::process::id()));
    for basis in Basis::ALL {
        let (whole, streamed) = (root.join("whole"), root.join("streamed"));
        for d in [&whole, &streamed] {
            let _ = std::fs::remove_dir_all(d);
            std::fs::create_dir_all(d).unwrap();
        }
        let f = fit(&cap, basis, None).unwrap();
        write_float_coefficients(&whole, &f).unwrap();
        let mut files = CoefficientFiles::create(&streamed, basis, (w, h, 3), &cap.pixels).unwrap();
        let meta = photostereo::solve::rti::fit_into(&cap, basis, None, &mut files).unwrap();
        assert_eq!(meta.ranges, f.coefficient_ranges());
        // Bands of 2 rows: the bottom-up PTM rows and the plane images cross band edges.
        let stored = files.finish(meta).with_band_rows(2);
        match basis {
            Basis::PtmLrgb | Basis::PtmRgb => {
                write_ptm(&whole.join("image.ptm"), &f).unwrap();
                write_ptm(&streamed.join("image.ptm"), &stored).unwrap();
            }
            Basis::Hsh2 | Basis::Hsh3 => {
                write_hsh(&whole.join("image.rti"), &f).unwrap();
                write_hsh(&streamed.join("image.rti"), &stored).unwrap();
            }
            Basis::Rbf => {}
        }
        write_relight(&whole.join("relight"), &f).unwrap();
        write_relight(&streamed.join("relight"), &stored).unwrap();
        let (a, b) = (tree(&whole), tree(&streamed));
        assert!(
            a.contains_key("coefficients.npy") && a.len() > 5,
            "{:?}",
            a.keys()
        );
        assert_eq!(a.keys().collect::<Vec<_>>(), b.keys().collect::<Vec<_>>());
        for (name, bytes) in &a {
            assert!(bytes == &b[name], "{}: {name} differs", basis.name());
        }
    }
    std::fs::remove_dir_all(&root).unwrap();
}

#[test]
fn pyramids_streamed_by_rows_are_those_of_the_whole_image() {
    // The pyramids are written from rows as they come (a few hundred rows held per level):
    // pushed in uneven bands, the files are byte for byte those of the whole image at once,
    // whose layout the two tests above check against the DZI and IIIF specifications.
    let (w, h) = (1100, 1300);
    let rgb = test_rgb(w, h);
    let tmp = tempfile::tempdir().unwrap();
    let (whole, bands) = (tmp.path().join("whole"), tmp.path().join("bands"));
    use photostereo::io::rti::tiles::{write_deep_zoom, write_iiif, TilePyramid};
    std::fs::create_dir_all(&whole).unwrap();
    write_deep_zoom(&whole.join("p.dzi"), (w, h), &rgb, 254, 1).unwrap();
    write_iiif(
        &whole.join("iiif"),
        "https://example.org/p",
        (w, h),
        &rgb,
        512,
    )
    .unwrap();
    std::fs::create_dir_all(&bands).unwrap();
    let dzi = bands.join("p.dzi");
    let iiif = bands.join("iiif");
    let mut p = TilePyramid::new(
        (w, h),
        Some((&dzi, 254, 1)),
        Some((&iiif, "https://example.org/p", 512)),
    )
    .unwrap();
    let mut y = 0;
    for step in [1usize, 7, 64, 255, 3].iter().cycle() {
        let y1 = (y + step).min(h);
        p.push(&rgb[y * w * 3..y1 * w * 3]).unwrap();
        y = y1;
        if y == h {
            break;
        }
    }
    let ((levels, tiles), info) = p.finish().unwrap();
    assert_eq!(levels, 12); // 2^10 < 1300 ≤ 2^11
    assert!(tiles > 0 && info.is_some());
    let (a, b) = (tree(&whole), tree(&bands));
    assert_eq!(a.keys().collect::<Vec<_>>(), b.keys().collect::<Vec<_>>());
    for (k, v) in &a {
        assert!(v == &b[k], "{k} differs");
    }
    // Rows beyond the image, or not whole, are refused.
    let mut p = TilePyramid::new((4, 2), Some((&bands.join("q.dzi"), 254, 1)), None).unwrap();
    assert!(p.push(&[0; 5]).is_err());
    assert!(p.push(&[0; 36]).is_err());
    p.push(&[0; 12]).unwrap();
    assert!(p.finish().is_err());
}
