//! Synthetic captures as folders: a rendering written in the DiLiGenT layout with its ground
//! truth in `gt/` ([`write_capture`], [`synth_to_folder`], [`synth_streamed`] for captures too
//! large to render whole) or in the near-light layout ([`write_near_capture`],
//! [`near_synth_to_folder`]), each written atomically through an [`OutputFolder`].

use crate::base::error::{Error, Result};
use crate::io::export::{write_json, write_npy_bool, write_npy_f32, OutputFolder, OutputKind};
use crate::io::imageio::{write_png16, write_png8};
use crate::io::light_files::{write_directions, write_intensities};
use crate::model::lights::Lights;
use crate::scene::near::{synthesize_near, NearRendered, NearSpec};
use crate::scene::render::{
    highlight_rule, to_u16, CaptureStats, LightByLight, Rendered, SynthSpec,
};
use crate::scene::synthesize;
use rayon::prelude::*;
use serde::Serialize;
use std::path::{Path, PathBuf};

/// Parameters and statistics written to `synth.json`.
#[derive(Serialize)]
struct SynthRecord<'a> {
    scene: &'a str,
    rig: &'a str,
    width: usize,
    height: usize,
    lights: usize,
    brdf: Option<&'a str>,
    noise_sigma: Option<f64>,
    shot_full_well: Option<f64>,
    seed: Option<u64>,
    mask: Option<&'a str>,
    textured_albedo: Option<bool>,
    intensities: Option<&'a str>,
    highlight_rule: String,
    stats: &'a CaptureStats,
}

/// Writes a rendered capture into `dir` (an existing folder, e.g. an [`OutputFolder`]'s staging
/// folder): the DiLiGenT layout — `001.png`… (16-bit RGB), `filenames.txt`,
/// `light_directions.txt`, `light_intensities.txt`, `mask.png` (8-bit, 255 = object) — and
/// `gt/normal.npy` (float32 (H, W, 3)), `gt/depth.npy` (float32 (H, W), NaN outside the mask),
/// `gt/albedo.npy` (float32 (H, W, 3)), `gt/shadow.npy` and `gt/highlight.npy` (bool (N, H, W)),
/// and `synth.json` (parameters and statistics; `spec` fills the parameters when given).
pub fn write_capture(dir: &Path, rendered: &Rendered, spec: Option<&SynthSpec>) -> Result<()> {
    let (w, h) = (rendered.truth.width, rendered.truth.height);
    let n = rendered.images.len();
    let digits = n.to_string().len().max(3);
    let names: Vec<String> = (1..=n).map(|k| format!("{k:0digits$}.png")).collect();
    rendered
        .images
        .par_iter()
        .zip(&names)
        .try_for_each(|(img, name)| {
            let data: Vec<u16> = img.data.iter().map(|&v| to_u16(v)).collect();
            write_png16(&dir.join(name), w, h, img.channels, &data)
        })?;
    let list = dir.join("filenames.txt");
    std::fs::write(&list, names.join("\n") + "\n").map_err(|e| Error::io(&list, e))?;
    write_directions(&rendered.lights, &dir.join("light_directions.txt"))?;
    write_intensities(&rendered.lights, &dir.join("light_intensities.txt"))?;
    let mask: Vec<u8> = rendered
        .truth
        .mask
        .iter()
        .map(|&m| if m { 255 } else { 0 })
        .collect();
    write_png8(&dir.join("mask.png"), w, h, 1, &mask)?;
    let gt = dir.join("gt");
    // Not create_dir_all: an interrupted run's removed staging folder must not come back.
    if !gt.is_dir() {
        std::fs::create_dir(&gt).map_err(|e| Error::io(&gt, e))?;
    }
    let t = &rendered.truth;
    let flat3 = |v: &[[f32; 3]]| v.iter().flatten().copied().collect::<Vec<f32>>();
    write_npy_f32(&gt.join("normal.npy"), &[h, w, 3], &flat3(&t.normals))?;
    write_npy_f32(&gt.join("depth.npy"), &[h, w], &t.depth)?;
    write_npy_f32(&gt.join("albedo.npy"), &[h, w, 3], &flat3(&t.albedo))?;
    let stack = |v: &[Vec<bool>]| v.iter().flatten().copied().collect::<Vec<bool>>();
    write_npy_bool(&gt.join("shadow.npy"), &[n, h, w], &stack(&t.shadow))?;
    write_npy_bool(&gt.join("highlight.npy"), &[n, h, w], &stack(&t.highlight))?;
    let record = SynthRecord {
        scene: &rendered.scene,
        rig: &rendered.rig,
        width: w,
        height: h,
        lights: n,
        brdf: spec.map(|s| s.render.brdf.name()),
        noise_sigma: spec.map(|s| s.render.noise_sigma),
        shot_full_well: spec.map(|s| s.render.shot_full_well),
        seed: spec.map(|s| s.render.seed),
        mask: spec.map(|s| s.mask.unwrap_or(s.scene.default_mask()).name()),
        textured_albedo: spec.map(|s| s.textured_albedo),
        intensities: spec.map(|s| s.intensities.name()),
        highlight_rule: highlight_rule(),
        stats: &rendered.stats,
    };
    write_json(&dir.join("synth.json"), &record)
}

/// Renders `spec` and writes it to `output` atomically (staging folder renamed into place);
/// refuses an existing `output` unless `force`. Returns the rendering and the final path.
pub fn synth_to_folder(
    spec: &SynthSpec,
    output: &Path,
    force: bool,
) -> Result<(Rendered, PathBuf)> {
    let folder = OutputFolder::create(output, force, OutputKind::Synth)?;
    let rendered = synthesize(spec)?;
    write_capture(folder.path(), &rendered, Some(spec))?;
    let target = folder.commit()?;
    Ok((rendered, target))
}

/// [`synth_to_folder`], the images then written as a camera would (`camera`: response,
/// ambient light and its frame, exposures recorded in EXIF, format) in place of the linear
/// 16-bit PNGs; the ground truth is the same.
pub fn synth_camera_to_folder(
    spec: &SynthSpec,
    camera: &crate::io::camera::CameraSpec,
    output: &Path,
    force: bool,
) -> Result<(Rendered, PathBuf)> {
    let folder = OutputFolder::create(output, force, OutputKind::Synth)?;
    let rendered = synthesize(spec)?;
    write_capture(folder.path(), &rendered, Some(spec))?;
    let files = crate::io::layouts::CaptureFiles::diligent(folder.path())?;
    crate::io::camera::reencode_capture(&files, folder.path(), camera)?;
    let target = folder.commit()?;
    Ok((rendered, target))
}

/// Writes the header of a `.npy` file of booleans of `shape`
/// ([`npy_header`](crate::io::export::npy_header)); the data follows.
fn npy_bool_header(file: &mut impl std::io::Write, shape: &[usize]) -> std::io::Result<()> {
    file.write_all(&crate::io::export::npy_header("|b1", shape))
}

/// [`synth_to_folder`] for captures too large to render whole: the scene is built once, each
/// light is rendered and written at once (its image, and its rows of `gt/shadow.npy` and
/// `gt/highlight.npy`, which are streamed), so memory holds the scene and one light
/// ([`streamed_bytes`](crate::scene::render::streamed_bytes)) whatever the light count. The files are those of [`synth_to_folder`],
/// pixel for pixel (the same renderer per light). With a `camera`, the images are then
/// re-encoded as [`synth_camera_to_folder`] writes them, one image at a time once the scene is
/// released. `progress` sees one unit per light.
pub fn synth_streamed(
    spec: &SynthSpec,
    camera: Option<&crate::io::camera::CameraSpec>,
    output: &Path,
    force: bool,
    progress: &dyn crate::base::progress::Progress,
) -> Result<(CaptureStats, Lights, PathBuf)> {
    use std::io::Write;
    let folder = OutputFolder::create(output, force, OutputKind::Synth)?;
    let dir = folder.path();
    let renderer = LightByLight::new(spec)?;
    let (scene, lights) = (&renderer.scene, &renderer.lights);
    let (w, h) = (scene.width, scene.height);
    let n = lights.len();
    let digits = n.to_string().len().max(3);
    let names: Vec<String> = (1..=n).map(|k| format!("{k:0digits$}.png")).collect();
    let gt = dir.join("gt");
    std::fs::create_dir(&gt).map_err(|e| Error::io(&gt, e))?;
    let open = |name: &str| -> Result<std::io::BufWriter<std::fs::File>> {
        let p = gt.join(name);
        let mut f =
            std::io::BufWriter::new(std::fs::File::create(&p).map_err(|e| Error::io(&p, e))?);
        npy_bool_header(&mut f, &[n, h, w]).map_err(|e| Error::io(&p, e))?;
        Ok(f)
    };
    let mut shadow_file = open("shadow.npy")?;
    let mut highlight_file = open("highlight.npy")?;
    let mask_pixels = scene.mask.iter().filter(|&&m| m).count().max(1) as f64;
    let mut stats = CaptureStats::default();
    progress.begin("rendering", n as u64);
    for (k, name) in names.iter().enumerate() {
        crate::base::progress::check_cancelled(progress)?;
        let r = renderer.render(k);
        let count = |v: &[bool]| v.iter().filter(|&&b| b).count() as f64 / mask_pixels;
        stats.shadow_fraction += count(&r.shadow);
        stats.cast_shadow_fraction += count(&r.cast);
        stats.highlight_fraction += count(&r.highlight);
        stats.clipped_fraction += r.clipped as f64 / mask_pixels;
        let bytes = |v: &[bool]| v.iter().map(|&b| b as u8).collect::<Vec<u8>>();
        shadow_file
            .write_all(&bytes(&r.shadow))
            .map_err(|e| Error::io(gt.join("shadow.npy"), e))?;
        highlight_file
            .write_all(&bytes(&r.highlight))
            .map_err(|e| Error::io(gt.join("highlight.npy"), e))?;
        drop((r.shadow, r.cast, r.highlight));
        let data: Vec<u16> = r.image.iter().map(|&v| to_u16(v)).collect();
        drop(r.image);
        write_png16(&dir.join(name), w, h, 3, &data)?;
        progress.advance(1);
    }
    progress.end();
    for (f, name) in [
        (shadow_file, "shadow.npy"),
        (highlight_file, "highlight.npy"),
    ] {
        f.into_inner()
            .map_err(|e| Error::io(gt.join(name), e.into_error()))?;
    }
    stats.shadow_fraction /= n as f64;
    stats.cast_shadow_fraction /= n as f64;
    stats.highlight_fraction /= n as f64;
    stats.clipped_fraction /= n as f64;
    let list = dir.join("filenames.txt");
    std::fs::write(&list, names.join("\n") + "\n").map_err(|e| Error::io(&list, e))?;
    write_directions(lights, &dir.join("light_directions.txt"))?;
    write_intensities(lights, &dir.join("light_intensities.txt"))?;
    let mask: Vec<u8> = scene
        .mask
        .iter()
        .map(|&m| if m { 255 } else { 0 })
        .collect();
    write_png8(&dir.join("mask.png"), w, h, 1, &mask)?;
    drop(mask);
    let masked3 = |v: &[[f32; 3]]| {
        v.iter()
            .zip(&scene.mask)
            .flat_map(|(x, &m)| if m { *x } else { [0.0; 3] })
            .collect::<Vec<f32>>()
    };
    write_npy_f32(&gt.join("normal.npy"), &[h, w, 3], &masked3(&scene.normals))?;
    write_npy_f32(&gt.join("albedo.npy"), &[h, w, 3], &masked3(&scene.albedo))?;
    let depth: Vec<f32> = scene
        .depth
        .iter()
        .zip(&scene.mask)
        .map(|(d, &m)| if m { *d } else { f32::NAN })
        .collect();
    write_npy_f32(&gt.join("depth.npy"), &[h, w], &depth)?;
    let record = SynthRecord {
        scene: &scene.name,
        rig: &spec.rig.name(),
        width: w,
        height: h,
        lights: n,
        brdf: Some(spec.render.brdf.name()),
        noise_sigma: Some(spec.render.noise_sigma),
        shot_full_well: Some(spec.render.shot_full_well),
        seed: Some(spec.render.seed),
        mask: Some(spec.mask.unwrap_or(spec.scene.default_mask()).name()),
        textured_albedo: Some(spec.textured_albedo),
        intensities: Some(spec.intensities.name()),
        highlight_rule: highlight_rule(),
        stats: &stats,
    };
    write_json(&dir.join("synth.json"), &record)?;
    let lights = renderer.lights.clone();
    drop(renderer);
    if let Some(camera) = camera {
        let files = crate::io::layouts::CaptureFiles::diligent(dir)?;
        crate::io::camera::reencode_capture(&files, dir, camera)?;
    }
    let target = folder.commit()?;
    Ok((stats, lights, target))
}

/// Writes a near-light scene in the near-light layout: everything [`write_capture`]
/// writes (`light_directions.txt` then holds the distant approximation at the object's centre,
/// which a near-light capture does not read, and `gt/depth.npy` Z in mm), with
/// `light_intensities.txt` replaced by each LED's radiance at 1 mm, plus `K.txt`,
/// `light_positions.txt`, `light_axes.txt`, `light_anisotropy.txt` and `mean_distance.txt`.
pub fn write_near_capture(dir: &Path, near: &NearRendered) -> Result<()> {
    write_capture(dir, &near.rendered, None)?;
    let write = |name: &str, text: String| {
        let p = dir.join(name);
        std::fs::write(&p, text).map_err(|e| Error::io(&p, e))
    };
    let rows3 = |v: &[[f64; 3]]| {
        v.iter()
            .map(|r| format!("{:.9} {:.9} {:.9}\n", r[0], r[1], r[2]))
            .collect::<String>()
    };
    let k = &near.camera;
    write(
        "K.txt",
        format!("{} 0 {}\n0 {} {}\n0 0 1\n", k.fx, k.cx, k.fy, k.cy),
    )?;
    write("light_positions.txt", rows3(&near.positions))?;
    write("light_axes.txt", rows3(&near.axes))?;
    write("light_intensities.txt", rows3(&near.radiance))?;
    write(
        "light_anisotropy.txt",
        near.anisotropy.iter().map(|m| format!("{m}\n")).collect(),
    )?;
    write("mean_distance.txt", format!("{}\n", near.distance))
}

/// Renders `spec` and writes it in the near-light layout to `output` atomically; refuses an
/// existing `output` unless `force`. Returns the rendering and the final path.
pub fn near_synth_to_folder(
    spec: &NearSpec,
    output: &Path,
    force: bool,
) -> Result<(NearRendered, std::path::PathBuf)> {
    let folder = OutputFolder::create(output, force, OutputKind::Synth)?;
    let rendered = synthesize_near(spec)?;
    write_near_capture(folder.path(), &rendered)?;
    let target = folder.commit()?;
    Ok((rendered, target))
}
