//! The design of a linear RTI fit under distant lights: the basis at the lights, the ridge
//! penalty, and the operators each pixel's fit applies to its readings.
//!
//! Ridge toward zero ([`Prior::Zero`]): c minimises ‖A c − y‖² + λ Σ_j D_j c_j², D the
//! roughness of the basis ([`Basis::roughness`]); c = P y with the projector
//! P = (AᵀA + λ D)⁻¹Aᵀ (T × N), and the leave-one-out residual of light k is e_k / (1 − h_kk),
//! h_kk = (A P)_kk (the PRESS identity).
//!
//! Ridge toward PTM ([`Prior::Ptm`], HSH only): the higher-order basis is pulled toward the
//! lower-order fit of the same readings instead of toward zero, the way a hierarchical model
//! shrinks a rich model toward a simpler one where the readings do not ask for more. With
//! c_p = P_p y PTM's ridge fit of the pixel's readings (per channel, ridge λ_p D_p), c
//! minimises
//!
//!   ‖A c − y‖² + λ · mean_{q ∈ Q} (h(q)ᵀ c − p(q)ᵀ c_p)²                       (1)
//!
//! with h, p the HSH and PTM functions and Q the cap of the light hemisphere at least as high
//! as the lowest light ([`cap_directions`]): the elevations the rig samples, where PTM's
//! quadratic interpolates its readings (below them it extrapolates toward the horizon, no
//! evidence for what HSH should do there). With M = mean_Q h hᵀ (T × T) and X = mean_Q h pᵀ
//! (T × 6) the normal equations are (AᵀA + λ M) c = Aᵀ y + λ X c_p, so
//!
//!   c = P y + V c_p,   P = (AᵀA + λ M)⁻¹ Aᵀ,   V = (AᵀA + λ M)⁻¹ λ X.              (2)
//!
//! λ → ∞ gives PTM's fit projected on HSH over Q; λ = 0 the plain least-squares HSH fit.
//! Leave-one-out, exactly: leaving light k out moves PTM's fit to
//! c_p − P_p[:, k] e^p_k / (1 − h^p_kk) (its own PRESS identity, e^p the PTM residuals), and a
//! ridge toward a fixed mean obeys PRESS, so the prediction of light k from the other lights is
//!
//!   y_k − (e_k + w_k e^p_k / (1 − h^p_kk)) / (1 − h_kk),   w_k = a_kᵀ V P_p[:, k],     (3)
//!
//! e_k = y_k − a_kᵀ c the residual of (2), h_kk = (A P)_kk.

use super::{Basis, MAX_TERMS};
use crate::base::cholesky::{self, SmallPivot};
use crate::base::error::{Error, Result};
use crate::model::capture::Capture;

/// PTM's terms.
pub const PTM_TERMS: usize = 6;

/// Points of the light hemisphere (a Fibonacci spiral, uniform in solid angle) whose cap above
/// the lowest light is Q of eq. (1).
pub const HEMISPHERE_POINTS: usize = 4000;

/// What the ridge of a linear fit pulls its coefficients toward.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Prior {
    /// Zero: the roughness penalty λ Σ_j D_j c_j² ([`Basis::roughness`]).
    Zero,
    /// HSH only: PTM's ridge fit of the same readings (per channel, ridge weight
    /// `ptm_lambda`), compared over the lit cap, eq. (1) of the module documentation.
    Ptm {
        /// λ_p of PTM's ridge (AᵀA + λ_p D_p).
        ptm_lambda: f64,
    },
}

/// The operators of the fits over one set of lights: the projector P (T × N, row-major), the
/// leverages h_kk and, toward PTM, PTM's operators and the pull V of eq. (2).
pub(super) struct Operators {
    pub projector: Vec<f64>,
    pub leverage: Vec<f64>,
    pub ptm: Option<PtmOperators>,
}

/// PTM's projector P_p (6 × N) and leverages, V (T × 6, row-major) and w_k of eq. (3).
pub(super) struct PtmOperators {
    pub projector: Vec<f64>,
    pub leverage: Vec<f64>,
    pub pull: [f64; MAX_TERMS * PTM_TERMS],
    pub carry: Vec<f64>,
}

impl Operators {
    /// Operators of `t` terms over `n` lights, zeros (filled by [`Design::operators_into`]).
    pub fn new(t: usize, n: usize, toward_ptm: bool) -> Operators {
        Operators {
            projector: vec![0.0; t * n],
            leverage: vec![0.0; n],
            ptm: toward_ptm.then(|| PtmOperators {
                projector: vec![0.0; PTM_TERMS * n],
                leverage: vec![0.0; n],
                pull: [0.0; MAX_TERMS * PTM_TERMS],
                carry: vec![0.0; n],
            }),
        }
    }
}

/// The PTM half of a design toward PTM: PTM at the lights (N × 6), its ridge λ_p D_p (6 × 6)
/// and λ X of eq. (2) (T × 6).
struct PtmDesign {
    a: Vec<f64>,
    penalty: [f64; MAX_TERMS * MAX_TERMS],
    cross: [f64; MAX_TERMS * PTM_TERMS],
}

/// The design of a capture's lights for one basis and ridge: A (N × T, row-major), the
/// penalty (T × T: λ D, or λ M toward PTM) and the operators over every light.
pub(super) struct Design {
    pub t: usize,
    pub n: usize,
    pub a: Vec<f64>,
    penalty: [f64; MAX_TERMS * MAX_TERMS],
    ptm: Option<PtmDesign>,
    /// The operators over every light.
    pub all: Operators,
}

impl Design {
    /// The design of `basis` under the capture's lights with ridge weight `lambda` toward
    /// `prior`; refused when the lights do not determine the coefficients without the ridge
    /// (a penalty would hide a rig that cannot tell the terms apart), or `prior` is PTM for a
    /// basis other than HSH.
    pub fn new(capture: &Capture, basis: Basis, lambda: f64, prior: Prior) -> Result<Design> {
        let dirs = &capture.lights.directions;
        let (n, t) = (dirs.len(), basis.terms());
        let a = at_lights(basis, dirs);
        let mut penalty = [0.0; MAX_TERMS * MAX_TERMS];
        let ptm = match prior {
            Prior::Zero => {
                let mut d = [0.0; MAX_TERMS];
                basis.roughness(&mut d);
                (0..t).for_each(|j| penalty[j * t + j] = lambda * d[j]);
                None
            }
            Prior::Ptm { ptm_lambda } => {
                if !matches!(basis, Basis::Hsh2 | Basis::Hsh3) {
                    return Err(Error::parameter(
                        "ridge",
                        format!("{} has no PTM prior (only hsh2 and hsh3 do)", basis.name()),
                    ));
                }
                let (m, x) = cap_moments(basis, dirs);
                penalty[..t * t]
                    .iter_mut()
                    .zip(&m)
                    .for_each(|(p, m)| *p = lambda * m);
                let mut cross = [0.0; MAX_TERMS * PTM_TERMS];
                cross.iter_mut().zip(&x).for_each(|(c, x)| *c = lambda * x);
                let mut d = [0.0; MAX_TERMS];
                Basis::PtmRgb.roughness(&mut d);
                let mut ptm_penalty = [0.0; MAX_TERMS * MAX_TERMS];
                (0..PTM_TERMS).for_each(|j| ptm_penalty[j * PTM_TERMS + j] = ptm_lambda * d[j]);
                Some(PtmDesign {
                    a: at_lights(Basis::PtmRgb, dirs),
                    penalty: ptm_penalty,
                    cross,
                })
            }
        };
        let mut design = Design {
            t,
            n,
            a,
            penalty,
            all: Operators::new(t, n, ptm.is_some()),
            ptm,
        };
        let mut all = Operators::new(t, n, design.ptm.is_some());
        if n < t + 1 || !design.operators_into(|_| true, &mut all) {
            return Err(Error::invalid(format!(
                "the {n} light directions do not determine the {t} coefficients of {} (the \
                 basis needs at least {} lights spread in azimuth and elevation; lights all at \
                 one elevation leave PTM's l_u² + l_v² and its constant term apart only by the \
                 readings' noise)",
                basis.name(),
                t + 1
            )));
        }
        design.all = all;
        Ok(design)
    }

    /// PTM at the lights (N × 6) when the design pulls toward PTM.
    pub fn ptm_at_lights(&self) -> Option<&[f64]> {
        self.ptm.as_ref().map(|p| p.a.as_slice())
    }

    /// Fills `out` with the operators over the lights `keep` admits (the penalty the design's);
    /// false when those lights alone do not determine the coefficients.
    pub fn operators_into(&self, keep: impl Fn(usize) -> bool + Copy, out: &mut Operators) -> bool {
        let (n, t) = (self.n, self.t);
        let mut g = [0.0; MAX_TERMS * MAX_TERMS];
        let (projector, leverage) = (&mut out.projector, &mut out.leverage);
        if !solve_into(&self.a, t, keep, &self.penalty, projector, leverage, &mut g) {
            return false;
        }
        let (Some(pd), Some(po)) = (&self.ptm, out.ptm.as_mut()) else {
            return true;
        };
        let mut gp = [0.0; MAX_TERMS * MAX_TERMS];
        let (projector, leverage) = (&mut po.projector, &mut po.leverage);
        let solved = solve_into(
            &pd.a,
            PTM_TERMS,
            keep,
            &pd.penalty,
            projector,
            leverage,
            &mut gp,
        );
        if solved {
            // V = (AᵀA + λ M)⁻¹ λ X, column by column (eq. 2).
            let mut x = [0.0; MAX_TERMS];
            for i in 0..PTM_TERMS {
                (0..t).for_each(|j| x[j] = pd.cross[j * PTM_TERMS + i]);
                cholesky::solve(&g[..t * t], t, &mut x[..t]);
                (0..t).for_each(|j| po.pull[j * PTM_TERMS + i] = x[j]);
            }
            // w_k = a_kᵀ V P_p[:, k] (eq. 3).
            for k in 0..n {
                let row = &self.a[k * t..(k + 1) * t];
                po.carry[k] = (0..PTM_TERMS)
                    .map(|i| {
                        let av: f64 = (0..t).map(|j| row[j] * po.pull[j * PTM_TERMS + i]).sum();
                        av * po.projector[i * n + k]
                    })
                    .sum();
            }
        }
        solved
    }
}

/// The basis at each light, N × T row-major.
fn at_lights(basis: Basis, dirs: &[[f64; 3]]) -> Vec<f64> {
    let t = basis.terms();
    let mut a = vec![0.0; dirs.len() * t];
    for (row, l) in a.chunks_exact_mut(t).zip(dirs) {
        basis.eval(*l, row);
    }
    a
}

/// Solves (G + R) X = Aᵀ over the lights `keep` admits, G = Σ_kept a_k a_kᵀ, R = `penalty`
/// (T × T): the projector (T × N) and the leverages (every light's column, the kept lights'
/// used), the factor of G + R into `factor`. False when G alone or G + R is not positive
/// definite.
fn solve_into(
    a: &[f64],
    t: usize,
    keep: impl Fn(usize) -> bool,
    penalty: &[f64; MAX_TERMS * MAX_TERMS],
    projector: &mut [f64],
    leverage: &mut [f64],
    factor: &mut [f64; MAX_TERMS * MAX_TERMS],
) -> bool {
    let n = a.len() / t;
    normal_matrix(a, t, keep, factor);
    let mut plain = *factor;
    factor[..t * t]
        .iter_mut()
        .zip(&penalty[..t * t])
        .for_each(|(g, p)| *g += p);
    if !cholesky::factor(&mut plain[..t * t], t, SmallPivot::Refuse)
        || !cholesky::factor(&mut factor[..t * t], t, SmallPivot::Refuse)
    {
        return false;
    }
    let mut x = [0.0; MAX_TERMS];
    for k in 0..n {
        x[..t].copy_from_slice(&a[k * t..(k + 1) * t]);
        cholesky::solve(&factor[..t * t], t, &mut x[..t]);
        for (j, &xj) in x.iter().enumerate().take(t) {
            projector[j * n + k] = xj;
        }
        leverage[k] = (0..t).map(|j| a[k * t + j] * x[j]).sum();
    }
    true
}

/// G = Σ_k a_k a_kᵀ over the lights `keep` admits (T × T into `g`).
fn normal_matrix(
    a: &[f64],
    t: usize,
    keep: impl Fn(usize) -> bool,
    g: &mut [f64; MAX_TERMS * MAX_TERMS],
) {
    g.fill(0.0);
    for (k, row) in a.chunks_exact(t).enumerate() {
        if keep(k) {
            for i in 0..t {
                for j in 0..=i {
                    g[i * t + j] += row[i] * row[j];
                }
            }
        }
    }
    for i in 0..t {
        for j in i + 1..t {
            g[i * t + j] = g[j * t + i];
        }
    }
}

/// Q of eq. (1): the points of a Fibonacci spiral of [`HEMISPHERE_POINTS`] over the light
/// hemisphere (uniform in solid angle) at least as high (l_z) as the lowest of `dirs`; the
/// lights themselves if none is.
pub fn cap_directions(dirs: &[[f64; 3]]) -> Vec<[f64; 3]> {
    let lowest = dirs.iter().map(|l| l[2]).fold(f64::INFINITY, f64::min);
    let q = HEMISPHERE_POINTS as f64;
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    let cap: Vec<[f64; 3]> = (0..HEMISPHERE_POINTS)
        .map(|i| {
            let z = 1.0 - (i as f64 + 0.5) / q;
            let r = (1.0 - z * z).sqrt();
            let phi = (i as f64 + 0.5) * golden;
            [r * phi.cos(), r * phi.sin(), z]
        })
        .filter(|d| d[2] >= lowest)
        .collect();
    if cap.is_empty() {
        dirs.to_vec()
    } else {
        cap
    }
}

/// M = mean_Q h hᵀ (T × T) and X = mean_Q h pᵀ (T × 6) of eq. (2), Q = [`cap_directions`].
fn cap_moments(basis: Basis, dirs: &[[f64; 3]]) -> (Vec<f64>, Vec<f64>) {
    let t = basis.terms();
    let cap = cap_directions(dirs);
    let (mut m, mut x) = (vec![0.0; t * t], vec![0.0; t * PTM_TERMS]);
    let (mut h, mut p) = ([0.0; MAX_TERMS], [0.0; MAX_TERMS]);
    for q in &cap {
        basis.eval(*q, &mut h);
        Basis::PtmRgb.eval(*q, &mut p);
        for i in 0..t {
            (0..t).for_each(|j| m[i * t + j] += h[i] * h[j]);
            (0..PTM_TERMS).for_each(|j| x[i * PTM_TERMS + j] += h[i] * p[j]);
        }
    }
    let w = 1.0 / cap.len() as f64;
    m.iter_mut().chain(x.iter_mut()).for_each(|v| *v *= w);
    (m, x)
}
