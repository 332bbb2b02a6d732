//! Rendering a scene under a rig into 16-bit images with ground truth, in memory
//! ([`synthesize`], [`render`]) or as a DiLiGenT-layout folder with a `gt/` subfolder
//! ([`write_capture`](crate::io::synth::write_capture),
//! [`synth_to_folder`](crate::io::synth::synth_to_folder)).
//!
//! Image model, per light k, pixel p and channel c, in units of full scale:
//! `I = E_k,c · (ρ_p,c · max(n·l, 0) + specular(n, l))`, zero where the pixel is shadowed
//! (attached: n·l ≤ 0; cast: ray march), plus shot noise (Gaussian, variance I / full_well)
//! and Gaussian read noise (σ), then clipped to [0, 1] and quantised to 16 bits. Pixels outside
//! the mask are 0 (no noise). Noise comes from a PCG32 stream per (light, row), so parallel
//! rendering is deterministic: the same seed gives the same bytes.
//!
//! Highlight rule (ground truth): a mask pixel is a highlight for light k when it is not shadowed
//! and its specular contribution (mean over channels of E_k,c · specular) exceeds
//! max(0.02, 3σ) of full scale.

use super::reflectance::Brdf;
use super::rigs::Rig;
use super::shadows::{cast_shadows_in, ShadowField};
use super::surfaces::{MaskShape, SceneKind};
use super::Scene;
use crate::base::error::{Error, Result};
use crate::base::rng::{splitmix64, Pcg32};
use crate::model::capture::Capture;
use crate::model::image::Image;
use crate::model::lights::Lights;
use rayon::prelude::*;
use serde::Serialize;

/// Smallest specular contribution (fraction of full scale) that counts as a highlight.
pub const HIGHLIGHT_MIN_FULL_SCALE: f64 = 0.02;
/// A highlight's specular contribution must also exceed this many noise σ.
pub const HIGHLIGHT_MIN_SIGMAS: f64 = 3.0;

/// Per-light intensity patterns of the renderer.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LightIntensities {
    /// Every light (1, 1, 1).
    Uniform,
    /// Grey intensities in [0.7, 1.0] varying from light to light.
    Varied,
    /// Coloured lights: each channel in [0.65, 1.0], varying from light to light.
    Coloured,
}

impl LightIntensities {
    /// Every pattern, in `--list` order.
    pub const ALL: &'static [LightIntensities] = &[
        LightIntensities::Uniform,
        LightIntensities::Varied,
        LightIntensities::Coloured,
    ];

    /// The name `--intensities` accepts.
    pub fn name(self) -> &'static str {
        match self {
            LightIntensities::Uniform => "uniform",
            LightIntensities::Varied => "varied",
            LightIntensities::Coloured => "coloured",
        }
    }

    /// Parses a name of [`LightIntensities::ALL`].
    pub fn parse(s: &str) -> Result<Self> {
        Self::ALL
            .iter()
            .copied()
            .find(|k| k.name() == s)
            .ok_or_else(|| {
                Error::invalid(format!(
                    "unknown light intensities '{s}': expected uniform, varied or coloured"
                ))
            })
    }

    /// The RGB intensity of light `k` (a fixed low-discrepancy pattern, independent of the seed).
    pub fn of_light(self, k: usize) -> [f64; 3] {
        let frac = |x: f64| x - x.floor();
        let golden = 0.618_033_988_749_895;
        match self {
            LightIntensities::Uniform => [1.0; 3],
            LightIntensities::Varied => [0.7 + 0.3 * frac(0.5 + golden * k as f64); 3],
            LightIntensities::Coloured => {
                let mut v = [0.0; 3];
                for (c, x) in v.iter_mut().enumerate() {
                    *x = 0.65 + 0.35 * frac(golden * (k + 1) as f64 + 0.37 * c as f64);
                }
                v
            }
        }
    }
}

/// How images are formed from a scene and lights.
#[derive(Clone, Debug, PartialEq)]
pub struct RenderOptions {
    pub brdf: Brdf,
    /// Gaussian read-noise σ, fraction of full scale (0.005 = 0.5%).
    pub noise_sigma: f64,
    /// Shot noise: the full-well count (photo-electrons at full scale); the noise variance of a
    /// value I is I / full_well. 0 = no shot noise.
    pub shot_full_well: f64,
    /// Seed of the noise.
    pub seed: u64,
}

impl Default for RenderOptions {
    fn default() -> Self {
        RenderOptions {
            brdf: Brdf::BlinnPhong,
            noise_sigma: 0.005,
            shot_full_well: 0.0,
            seed: 1,
        }
    }
}

/// A built-in scene under a rig: everything `synth` takes.
#[derive(Clone, Debug, PartialEq)]
pub struct SynthSpec {
    pub scene: SceneKind,
    pub rig: Rig,
    /// Image width (and height unless `height` is given), pixels.
    pub size: usize,
    /// Image height when it differs from the width (see [`Scene::builtin_wh`]).
    pub height: Option<usize>,
    /// Mask override (`None` = the scene's default).
    pub mask: Option<MaskShape>,
    /// Smooth colour texture on the albedo (else the scene's constant colour).
    pub textured_albedo: bool,
    pub intensities: LightIntensities,
    pub render: RenderOptions,
}

impl SynthSpec {
    /// A spec with the defaults of `photostereo synth`: size 128, textured albedo, uniform
    /// intensities, Blinn–Phong, σ = 0.5%, no shot noise, seed 1.
    pub fn new(scene: SceneKind, rig: Rig) -> Self {
        SynthSpec {
            scene,
            rig,
            size: 128,
            height: None,
            mask: None,
            textured_albedo: true,
            intensities: LightIntensities::Uniform,
            render: RenderOptions::default(),
        }
    }
}

/// Ground truth of a rendered capture. Maps are `height * width`, row-major.
#[derive(Clone, Debug)]
pub struct GroundTruth {
    pub width: usize,
    pub height: usize,
    /// Unit normals used for shading, camera frame; (0, 0, 0) outside the mask.
    pub normals: Vec<[f32; 3]>,
    /// Height toward the camera, pixel units; NaN outside the mask.
    pub depth: Vec<f32>,
    /// Albedo (RGB); 0 outside the mask.
    pub albedo: Vec<[f32; 3]>,
    pub mask: Vec<bool>,
    /// Per light: attached ∪ cast shadow (false outside the mask).
    pub shadow: Vec<Vec<bool>>,
    /// Per light: cast shadow on a surface facing the light (n·l > 0 but occluded); false
    /// outside the mask.
    pub cast_shadow: Vec<Vec<bool>>,
    /// Per light: highlight (see the module's rule; never where shadowed).
    pub highlight: Vec<Vec<bool>>,
}

/// Shares of mask pixels, averaged over lights.
#[derive(Clone, Debug, Default, Serialize, PartialEq)]
pub struct CaptureStats {
    /// Shadowed (attached or cast).
    pub shadow_fraction: f64,
    /// In a cast shadow while facing the light (not attached).
    pub cast_shadow_fraction: f64,
    /// Highlighted.
    pub highlight_fraction: f64,
    /// With at least one channel clipped at white.
    pub clipped_fraction: f64,
}

/// A rendered capture in memory.
#[derive(Clone, Debug)]
pub struct Rendered {
    /// Scene name.
    pub scene: String,
    /// Rig name.
    pub rig: String,
    /// One RGB image per light, values k/65535 (16-bit quantised), bit depth 16.
    pub images: Vec<Image>,
    /// Directions and intensities used.
    pub lights: Lights,
    pub truth: GroundTruth,
    pub stats: CaptureStats,
}

impl Rendered {
    /// The capture of the images (mask = the scene's mask; images divided by the intensities).
    pub fn capture(&self) -> Result<Capture> {
        Capture::from_images(
            &self.images,
            self.lights.clone(),
            Some(self.truth.mask.clone()),
        )
    }

    /// The object mask.
    pub fn mask(&self) -> &[bool] {
        &self.truth.mask
    }
}

/// Builds the spec's scene and renders it.
pub fn synthesize(spec: &SynthSpec) -> Result<Rendered> {
    synthesize_scene(spec, &spec_scene(spec)?)
}

/// The built-in scene that `spec` names (its kind, size, mask and albedo; not its rig).
pub fn spec_scene(spec: &SynthSpec) -> Result<Scene> {
    match spec.height {
        None => Scene::builtin(spec.scene, spec.size, spec.mask, spec.textured_albedo),
        Some(h) => Scene::builtin_wh(spec.scene, spec.size, h, spec.mask, spec.textured_albedo),
    }
}

/// [`synthesize`] with the scene already built (`spec_scene(spec)`, e.g. shared by several
/// rigs): the same result.
pub fn synthesize_scene(spec: &SynthSpec, scene: &Scene) -> Result<Rendered> {
    let mut lights = spec.rig.lights()?;
    let intensities = (0..lights.len())
        .map(|k| spec.intensities.of_light(k))
        .collect();
    lights = lights.with_intensities(intensities)?;
    let mut out = render(scene, &lights, &spec.render)?;
    out.rig = spec.rig.name();
    Ok(out)
}

/// Renders `scene` under `lights` (directions and RGB intensities) with `options`.
pub fn render(scene: &Scene, lights: &Lights, options: &RenderOptions) -> Result<Rendered> {
    if lights.is_empty() {
        return Err(Error::invalid("rendering needs at least one light"));
    }
    if !(options.noise_sigma.is_finite() && options.noise_sigma >= 0.0) {
        return Err(Error::invalid(format!(
            "noise σ {}: expected a finite value ≥ 0 (fraction of full scale)",
            options.noise_sigma
        )));
    }
    if !(options.shot_full_well.is_finite() && options.shot_full_well >= 0.0) {
        return Err(Error::invalid(format!(
            "shot-noise full well {}: expected a finite value ≥ 0 (0 = off)",
            options.shot_full_well
        )));
    }
    let (w, h) = (scene.width, scene.height);
    let threshold = HIGHLIGHT_MIN_FULL_SCALE.max(HIGHLIGHT_MIN_SIGMAS * options.noise_sigma);
    let seed = splitmix64(options.seed);
    let field = ShadowField::new(scene);
    let per_light: Vec<LightResult> = lights
        .directions
        .par_iter()
        .zip(&lights.intensities)
        .enumerate()
        .map(|(k, (l, e))| render_light(scene, &field, k, *l, *e, options, seed, threshold))
        .collect();
    let n = lights.len();
    let mask_pixels = scene.mask.iter().filter(|&&m| m).count().max(1) as f64;
    let mut truth = GroundTruth {
        width: w,
        height: h,
        normals: scene
            .normals
            .iter()
            .zip(&scene.mask)
            .map(|(nrm, &m)| if m { *nrm } else { [0.0; 3] })
            .collect(),
        depth: scene
            .depth
            .iter()
            .zip(&scene.mask)
            .map(|(d, &m)| if m { *d } else { f32::NAN })
            .collect(),
        albedo: scene
            .albedo
            .iter()
            .zip(&scene.mask)
            .map(|(a, &m)| if m { *a } else { [0.0; 3] })
            .collect(),
        mask: scene.mask.clone(),
        shadow: Vec::with_capacity(n),
        cast_shadow: Vec::with_capacity(n),
        highlight: Vec::with_capacity(n),
    };
    let (images, stats) = gather_lights(per_light, w, h, mask_pixels, &mut truth);
    Ok(Rendered {
        scene: scene.name.clone(),
        rig: String::new(),
        images,
        lights: lights.clone(),
        truth,
        stats,
    })
}

/// One light's rendering: its 16-bit RGB image as f32 and its ground-truth maps.
pub struct LightResult {
    /// `height * width * 3` samples in [0, 1], quantised to 16 bits ([`to_u16`]).
    pub image: Vec<f32>,
    /// `height * width` flags: shadowed (attached or cast).
    pub shadow: Vec<bool>,
    /// `height * width` flags: cast shadow.
    pub cast: Vec<bool>,
    /// `height * width` flags: highlight (module documentation's rule).
    pub highlight: Vec<bool>,
    /// Clipped mask pixels.
    pub clipped: usize,
}

/// The lights' renderings as the capture's images (`width` × `height`, RGB, 16-bit), their maps
/// pushed onto `truth`, and the shares of shadowed, cast-shadowed, highlighted and clipped mask
/// pixels averaged over the lights (`mask_pixels` mask pixels).
pub(crate) fn gather_lights(
    per_light: Vec<LightResult>,
    width: usize,
    height: usize,
    mask_pixels: f64,
    truth: &mut GroundTruth,
) -> (Vec<Image>, CaptureStats) {
    let n = per_light.len().max(1) as f64;
    let mut stats = CaptureStats::default();
    let mut images = Vec::with_capacity(per_light.len());
    let count = |v: &[bool]| v.iter().filter(|&&b| b).count() as f64 / mask_pixels;
    for r in per_light {
        stats.shadow_fraction += count(&r.shadow);
        stats.cast_shadow_fraction += count(&r.cast);
        stats.highlight_fraction += count(&r.highlight);
        stats.clipped_fraction += r.clipped as f64 / mask_pixels;
        images.push(Image {
            width,
            height,
            channels: 3,
            bit_depth: 16,
            data: r.image,
        });
        truth.shadow.push(r.shadow);
        truth.cast_shadow.push(r.cast);
        truth.highlight.push(r.highlight);
    }
    stats.shadow_fraction /= n;
    stats.cast_shadow_fraction /= n;
    stats.highlight_fraction /= n;
    stats.clipped_fraction /= n;
    (images, stats)
}

/// Light `k` of direction `l` and RGB intensity `e` on `scene`, whose [`ShadowField`] is
/// `field`.
#[allow(clippy::too_many_arguments)]
fn render_light(
    scene: &Scene,
    field: &ShadowField,
    k: usize,
    l: [f64; 3],
    e: [f64; 3],
    options: &RenderOptions,
    seed: u64,
    highlight_threshold: f64,
) -> LightResult {
    let (w, h) = (scene.width, scene.height);
    // Rays are marched only from pixels facing the light: the others are in attached shadow.
    let facing: Vec<bool> = scene
        .normals
        .iter()
        .map(|n| n[0] as f64 * l[0] + n[1] as f64 * l[1] + n[2] as f64 * l[2] > 0.0)
        .collect();
    let mut cast = cast_shadows_in(scene, field, l, Some(&facing));
    let half = Brdf::half_vector(l);
    let mut image = vec![0f32; w * h * 3];
    let mut shadow = vec![false; w * h];
    let mut highlight = vec![false; w * h];
    let clipped: usize = image
        .par_chunks_mut(w * 3)
        .zip(shadow.par_chunks_mut(w))
        .zip(highlight.par_chunks_mut(w))
        .zip(cast.par_chunks_mut(w))
        .enumerate()
        .map(|(row, (((img, sh), hl), cs))| {
            let mut rng = Pcg32::new(seed, (k as u64) * (h as u64) + row as u64);
            let mut clipped = 0;
            for col in 0..w {
                let i = row * w + col;
                if !scene.mask[i] {
                    cs[col] = false;
                    continue;
                }
                let nf = scene.normals[i];
                let n = [nf[0] as f64, nf[1] as f64, nf[2] as f64];
                let n_dot_l = n[0] * l[0] + n[1] * l[1] + n[2] * l[2];
                let attached = n_dot_l <= 0.0;
                let shadowed = attached || cs[col];
                cs[col] = cs[col] && !attached;
                sh[col] = shadowed;
                let (diffuse, specular) = if shadowed {
                    (0.0, 0.0)
                } else {
                    (n_dot_l, options.brdf.specular_with_half(n, l, half))
                };
                let spec_mean = specular * (e[0] + e[1] + e[2]) / 3.0;
                hl[col] = !shadowed && spec_mean > highlight_threshold;
                let mut clip = false;
                for c in 0..3 {
                    let clean = e[c] * (scene.albedo[i][c] as f64 * diffuse + specular);
                    let mut value = clean;
                    if options.shot_full_well > 0.0 {
                        value +=
                            (clean.max(0.0) / options.shot_full_well).sqrt() * rng.next_normal();
                    }
                    if options.noise_sigma > 0.0 {
                        value += options.noise_sigma * rng.next_normal();
                    }
                    if value >= 1.0 {
                        clip = true;
                    }
                    let q = (value.clamp(0.0, 1.0) * 65535.0).round();
                    img[col * 3 + c] = (q / 65535.0) as f32;
                }
                clipped += clip as usize;
            }
            clipped
        })
        .sum();
    LightResult {
        image,
        shadow,
        cast,
        highlight,
        clipped,
    }
}

/// `(v.clamp(0, 1) · 65535).round()` as u16 (NaN gives 0), without a libm call: for x in
/// [0, 65535] the fraction x − trunc(x) is exact, so comparing it with ½ rounds half away from
/// zero as `f32::round` does.
#[inline]
pub fn to_u16(v: f32) -> u16 {
    let x = v.clamp(0.0, 1.0) * 65535.0;
    let whole = x as u32; // truncation; NaN gives 0, as `NaN as u16` does
    let up = x - whole as f32 >= 0.5;
    (whole + up as u32) as u16
}

/// Bytes [`synthesize`] holds for a spec (every image as `f32`, the per-light maps, the scene
/// and its ground truth), to choose between it and [`synth_streamed`](crate::io::synth::synth_streamed).
pub fn in_memory_bytes(width: usize, height: usize, lights: usize) -> u64 {
    let px = (width * height) as u64;
    px * (lights as u64 * (12 + 3) + 64)
}

/// Bytes [`synth_streamed`](crate::io::synth::synth_streamed) holds at most: the scene (29 bytes per pixel), its ground truth
/// written from it, and one light's image and maps at a time (about 30 bytes per pixel). A
/// camera's re-encoding comes after the scene is released and holds less: the ambient frame,
/// one image and its decoder's buffer, and the encoded bytes (about 42 bytes per RGB pixel).
/// Beside them the program's fixed allowance ([`FIXED_BYTES`](crate::model::memory::FIXED_BYTES):
/// code, thread stacks, small tables).
pub fn streamed_bytes(width: usize, height: usize) -> u64 {
    (width * height) as u64 * 64 + crate::model::memory::FIXED_BYTES
}

/// A scene rendered one light at a time, for captures too large to render whole: the scene and
/// its shadow field are built once and each light's image and maps made on demand, so memory
/// holds the scene and one light ([`streamed_bytes`]) whatever the light count. Each light is
/// rendered as [`synthesize`] renders it, pixel for pixel.
pub struct LightByLight {
    /// The scene.
    pub scene: Scene,
    /// The rig's lights with the spec's intensities.
    pub lights: Lights,
    field: ShadowField,
    options: RenderOptions,
    seed: u64,
    threshold: f64,
}

impl LightByLight {
    /// Builds `spec`'s scene and lights.
    pub fn new(spec: &SynthSpec) -> Result<Self> {
        let scene = match spec.height {
            None => Scene::builtin(spec.scene, spec.size, spec.mask, spec.textured_albedo)?,
            Some(h) => {
                Scene::builtin_wh(spec.scene, spec.size, h, spec.mask, spec.textured_albedo)?
            }
        };
        let lights = spec.rig.lights()?;
        let intensities = (0..lights.len())
            .map(|k| spec.intensities.of_light(k))
            .collect();
        let lights = lights.with_intensities(intensities)?;
        let options = spec.render.clone();
        let threshold = HIGHLIGHT_MIN_FULL_SCALE.max(HIGHLIGHT_MIN_SIGMAS * options.noise_sigma);
        Ok(LightByLight {
            field: ShadowField::new(&scene),
            seed: splitmix64(options.seed),
            scene,
            lights,
            options,
            threshold,
        })
    }

    /// Light `k`'s image and maps.
    pub fn render(&self, k: usize) -> LightResult {
        render_light(
            &self.scene,
            &self.field,
            k,
            self.lights.directions[k],
            self.lights.intensities[k],
            &self.options,
            self.seed,
            self.threshold,
        )
    }
}

/// The ground-truth highlight rule as `synth.json` states it.
pub fn highlight_rule() -> String {
    format!(
        "not shadowed and mean-over-channels specular > max({HIGHLIGHT_MIN_FULL_SCALE}, {HIGHLIGHT_MIN_SIGMAS}·noise σ) of full scale"
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn to_u16_is_the_rounded_scaled_value() {
        let reference = |v: f32| (v.clamp(0.0, 1.0) * 65535.0).round() as u16;
        let mut values = vec![f32::NAN, -1.0, 0.0, 1.0, 2.0, f32::INFINITY, 0.5 / 65535.0];
        for q in 0..=65535u32 {
            let v = q as f32 / 65535.0;
            values.extend([v, (q as f64 / 65535.0) as f32]);
            let tie = (q as f32 + 0.5) / 65535.0;
            values.extend([
                tie,
                f32::from_bits(tie.to_bits() - 1),
                f32::from_bits(tie.to_bits() + 1),
            ]);
        }
        for v in values {
            assert_eq!(to_u16(v), reference(v), "{v:?}");
        }
    }
}
