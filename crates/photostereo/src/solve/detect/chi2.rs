//! The χ² test of a pixel's readings (paper eqs. 4–6, generalised to N lights): the
//! per-capture constants ([`ChiSquareTest`]; per pixel with near lights, [`NearLightTest`]),
//! the least-squares residual sum of squares that equals ‖Aᵀ I‖², the shadow fault the linear
//! test cannot see, and the null-space basis A itself.

use super::noise::NoiseModel;
use super::params::DetectionParams;
use crate::base::error::{Error, Result};
use crate::base::stats::{chi2_quantile, normal_upper_quantile};
use crate::model::capture::Capture;
use nalgebra::{Matrix3, Vector3};

/// Per-capture constants of the test (per pixel with near lights: see [`ChiSquareTest::set_directions`]).
#[derive(Clone)]
pub(super) struct ChiSquareTest {
    pub(super) directions: Vec<Vector3<f64>>,
    /// Structure-of-arrays copies for vectorised loops: components and the products that
    /// give the leverage lᵀ G⁻¹ l from the six distinct entries of the symmetric G⁻¹.
    pub(super) lx: Vec<f64>,
    pub(super) ly: Vec<f64>,
    pub(super) lz: Vec<f64>,
    pub(super) quad: [Vec<f64>; 6],
    pub(super) gram: Matrix3<f64>,
    pub(super) gram_inv: Matrix3<f64>,
    /// thresholds[d] = χ²_d quantile at the confidence (d = 1..N−3).
    pub(super) thresholds: Vec<f64>,
    /// z² of the batch-removal test.
    pub(super) batch_z2: f64,
    pub(super) min_kept: usize,
    /// Per light 1 / c_k ([`NoiseModel::light_factor`]; empty: all 1). The test then works on
    /// the readings and light vectors divided by c_k — weighted least squares with weights
    /// 1 / c_k², whose statistic is χ² under the per-light noise — and `directions` (with the
    /// copies and the normal matrix) hold the divided vectors.
    pub(super) inv_factor: Vec<f64>,
}

impl ChiSquareTest {
    pub(super) fn new(capture: &Capture, params: &DetectionParams) -> Result<Self> {
        let n = capture.n_lights();
        if n < 4 {
            return Err(Error::invalid(format!(
                "detection needs at least four lights (the test has N − 3 degrees of freedom); the capture has {n}"
            )));
        }
        let directions: Vec<Vector3<f64>> = capture
            .lights
            .directions
            .iter()
            .map(|d| Vector3::from(*d))
            .collect();
        let gram = capture.lights.gram();
        let gram_inv = gram
            .try_inverse()
            .ok_or_else(|| Error::invalid("singular light matrix"))?;
        let mut thresholds = vec![f64::INFINITY; n - 2];
        for (d, t) in thresholds.iter_mut().enumerate().skip(1) {
            *t = chi2_quantile(params.confidence, d);
        }
        let z = normal_upper_quantile(params.batch_alpha / (2.0 * n as f64));
        let min_kept = ((params.min_kept_share * n as f64).ceil() as usize).max(3);
        let lx: Vec<f64> = directions.iter().map(|l| l.x).collect();
        let ly: Vec<f64> = directions.iter().map(|l| l.y).collect();
        let lz: Vec<f64> = directions.iter().map(|l| l.z).collect();
        let quad = [
            directions.iter().map(|l| l.x * l.x).collect(),
            directions.iter().map(|l| l.y * l.y).collect(),
            directions.iter().map(|l| l.z * l.z).collect(),
            directions.iter().map(|l| 2.0 * l.x * l.y).collect(),
            directions.iter().map(|l| 2.0 * l.x * l.z).collect(),
            directions.iter().map(|l| 2.0 * l.y * l.z).collect(),
        ];
        Ok(ChiSquareTest {
            directions,
            lx,
            ly,
            lz,
            quad,
            gram,
            gram_inv,
            thresholds,
            batch_z2: z * z,
            min_kept,
            inv_factor: Vec::new(),
        })
    }

    /// The test of a capture under a noise model: [`ChiSquareTest::new`] with the light vectors divided
    /// by the model's per-light factors (when it has them).
    pub(super) fn with_noise(
        capture: &Capture,
        params: &DetectionParams,
        noise: &NoiseModel,
    ) -> Result<Self> {
        let mut test = ChiSquareTest::new(capture, params)?;
        let n = test.directions.len();
        if noise.light_factor.len() == n && noise.light_factor.iter().any(|&c| c != 1.0) {
            test.inv_factor = noise.light_factor.iter().map(|&c| 1.0 / c).collect();
            let dirs: Vec<[f64; 3]> = capture.lights.directions.clone();
            if !test.set_directions(&dirs) {
                return Err(Error::invalid("singular light matrix"));
            }
        }
        Ok(test)
    }

    /// 1 / c_k of light k.
    #[inline]
    pub(super) fn inv_factor(&self, k: usize) -> f64 {
        self.inv_factor.get(k).copied().unwrap_or(1.0)
    }
}

impl ChiSquareTest {
    /// Replaces the light vectors (a pixel's own near-light vectors, ALGORITHMS.md §9): the
    /// structure-of-arrays copies and the normal matrix follow. Returns false when the vectors
    /// do not determine a normal (singular normal matrix).
    pub(super) fn set_directions(&mut self, dirs: &[[f64; 3]]) -> bool {
        let mut gram = Matrix3::zeros();
        for (k, d) in dirs.iter().enumerate() {
            let l = Vector3::from(*d) * self.inv_factor(k);
            self.directions[k] = l;
            self.lx[k] = l.x;
            self.ly[k] = l.y;
            self.lz[k] = l.z;
            self.quad[0][k] = l.x * l.x;
            self.quad[1][k] = l.y * l.y;
            self.quad[2][k] = l.z * l.z;
            self.quad[3][k] = 2.0 * l.x * l.y;
            self.quad[4][k] = 2.0 * l.x * l.z;
            self.quad[5][k] = 2.0 * l.y * l.z;
            gram += l * l.transpose();
        }
        self.gram = gram;
        match gram.try_inverse() {
            Some(inv) => {
                self.gram_inv = inv;
                true
            }
            None => false,
        }
    }
}

/// Per-pixel test constants with near lights: a copy of the test and the light model's access.
pub(super) struct NearLightTest<'a> {
    test: ChiSquareTest,
    lights: crate::model::lightmodel::PixelLights<'a>,
}

impl<'a> NearLightTest<'a> {
    pub(super) fn of(capture: &'a Capture, test: &ChiSquareTest) -> Option<Self> {
        capture.lights.near.as_deref().map(|m| NearLightTest {
            test: test.clone(),
            lights: crate::model::lightmodel::PixelLights::new(
                &capture.lights.directions,
                Some(m),
                capture.width,
            ),
        })
    }

    /// The test at full-frame pixel `pixel`; None where its vectors are singular.
    pub(super) fn at(&mut self, pixel: usize) -> Option<&ChiSquareTest> {
        let dirs = self.lights.at(pixel);
        self.test.set_directions(dirs).then_some(&self.test)
    }
}

/// Least squares over the kept lights: (m, RSS, kept count, G⁻¹), or None if singular.
#[inline]
pub(super) fn least_squares_rss(
    test: &ChiSquareTest,
    grey: &[f64],
    kept: &[bool],
    gram_inv: &Matrix3<f64>,
) -> (Vector3<f64>, f64, usize) {
    let mut b = Vector3::zeros();
    let mut count = 0;
    for ((l, &i), &k) in test.directions.iter().zip(grey).zip(kept) {
        if k {
            b += l * i;
            count += 1;
        }
    }
    let m = gram_inv * b;
    let mut rss = 0.0;
    for ((l, &i), &k) in test.directions.iter().zip(grey).zip(kept) {
        if k {
            let e = i - l.dot(&m);
            rss += e * e;
        }
    }
    (m, rss, count)
}

/// Faults confined to a set S of lights are invisible to the linear test when they can be
/// absorbed by another normal, which needs |S| ≥ N − 2 (the fault vector must lie in the light
/// matrix's column space while vanishing on the other lights). Such pixels are recognisable when
/// the faults are shadows: at least N − 2 readings at the shadow level. They are flagged
/// unreliable: a pixel lit by at most two lights does not determine a normal anyway.
pub(super) fn dark_beyond_the_test(
    params: &DetectionParams,
    noise: &NoiseModel,
    grey: &[f64],
) -> bool {
    let n = grey.len();
    let level = grey.iter().sum::<f64>() / n as f64;
    let shadow_level = noise.shadow_level(params, level);
    grey.iter().filter(|&&g| g <= shadow_level).count() + 2 >= n
}

/// An orthonormal basis A (N × (N−3)) of the null space of Lᵀ: the eigenvectors of L Lᵀ with
/// eigenvalue zero (for four lights, the paper's vector a). The detector never needs it (it uses
/// the equal least-squares residual); it is exposed for analysis and tests.
pub fn null_space(lights: &crate::model::lights::Lights) -> nalgebra::DMatrix<f64> {
    let n = lights.len();
    let l = nalgebra::DMatrix::from_fn(n, 3, |r, c| lights.directions[r][c]);
    let eig = nalgebra::SymmetricEigen::new(&l * l.transpose());
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
    let k = n.saturating_sub(3);
    nalgebra::DMatrix::from_fn(n, k, |r, c| eig.eigenvectors[(r, order[c])])
}
