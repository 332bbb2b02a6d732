//! `photostereo synth`: render a built-in scene under a light rig into a DiLiGenT-layout folder
//! with ground truth (`gt/`).

use crate::common::{print_json, OutputOpts};
use anyhow::{bail, Result};
use clap::Args;
use photostereo::io::synth::synth_to_folder;
use photostereo::scene::{render::LightIntensities, Brdf, MaskShape, Rig, SceneKind, SynthSpec};
use std::path::PathBuf;

#[derive(Args, Debug)]
pub struct SynthArgs {
    /// The scene to render (see --list).
    #[arg(required_unless_present = "list")]
    pub scene: Option<String>,
    /// Light rig: square4, ring8, ring-N, dome-N, a light-direction file, or a near-light rig
    /// with a perspective camera (near-ring, near-square, near-dome; written in the near-light
    /// layout, ground-truth depth Z in mm).
    #[arg(long, default_value = "square4")]
    pub rig: String,
    /// Image size, pixels: `N` (N×N) or `WxH` (e.g. `8000x6000`; the scene at the centre of
    /// the frame, its side the smaller of the two). Near-light rigs take square sizes.
    #[arg(long, default_value = "128", value_parser = parse_size)]
    pub size: (usize, usize),
    /// Memory budget (e.g. `3G`; default: half of the memory available). Captures whose
    /// images do not fit whole are rendered one light at a time and written as they come.
    #[arg(long, value_parser = crate::common::parse_memory_limit)]
    pub memory_limit: Option<u64>,
    /// Near-light rigs: the distance of the rig's centre from the camera, mm.
    #[arg(long, default_value_t = 300.0)]
    pub distance: f64,
    /// Reflectance model: lambert, blinn-phong or torrance-sparrow.
    #[arg(long, default_value = "blinn-phong")]
    pub brdf: String,
    /// Gaussian noise σ as a fraction of full scale (0.005 = 0.5%).
    #[arg(long, default_value_t = 0.005)]
    pub noise: f64,
    /// Shot noise: full-well count at white (variance = value / count); 0 = off.
    #[arg(long, default_value_t = 0.0)]
    pub shot: f64,
    /// Seed of the noise; the same seed gives byte-identical files.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Mask: full, circle or irregular (default: the scene's own).
    #[arg(long)]
    pub mask: Option<String>,
    /// Albedo: texture (smooth colour variation) or constant.
    #[arg(long, default_value = "texture")]
    pub albedo: String,
    /// Per-light intensities: uniform, varied (grey) or coloured.
    #[arg(long, default_value = "uniform")]
    pub intensities: String,
    /// Write the images as a camera would, through this response: linear, srgb or gamma:G
    /// (encoded = linear^(1/G)); the default writes linear 16-bit PNGs, and sRGB JPEGs with
    /// --format jpeg (a JPEG declares sRGB, or Adobe RGB's gamma:2.19921875, and is read so).
    #[arg(long, value_parser = parse_camera_response)]
    pub response: Option<photostereo::io::photometry::Response>,
    /// Ambient light added to every image, its brightest reading as a share of full scale
    /// (e.g. 0.08); its frame is written as ambient.* beside the images.
    #[arg(long, default_value_t = 0.0)]
    pub ambient: f64,
    /// Exposures that change from image to image over ×1/F to ×F about their middle
    /// (recorded in EXIF; needs --format jpeg).
    #[arg(long, default_value_t = 1.0)]
    pub exposure_jitter: f64,
    /// Image format: png (16-bit, or 8-bit with a --response other than linear), png8, png16
    /// or jpeg (baseline, with EXIF).
    #[arg(long, default_value = "png")]
    pub format: String,
    /// JPEG quality, 1 to 100.
    #[arg(long, default_value_t = 90)]
    pub quality: u8,
    /// Output folder (default: synth-SCENE).
    #[arg(short, long)]
    pub output: Option<PathBuf>,
    /// List the scenes, rigs, reflectance models, masks and intensity patterns, then exit.
    #[arg(long)]
    pub list: bool,
    #[command(flatten)]
    pub out: OutputOpts,
}

pub fn main(a: SynthArgs) -> Result<()> {
    if a.list {
        return list(&a.out);
    }
    let Some(scene_name) = a.scene.as_deref() else {
        bail!("SCENE is required (see --list)");
    };
    let scene: SceneKind = scene_name.parse()?;
    let mask = a.mask.as_deref().map(str::parse::<MaskShape>).transpose()?;
    let textured_albedo = match a.albedo.as_str() {
        "texture" => true,
        "constant" => false,
        other => bail!("--albedo {other}: expected texture or constant"),
    };
    let (width, height) = a.size;
    let camera = camera_spec(&a)?;
    if let Some(rig) = photostereo::scene::near::NearRig::parse(&a.rig) {
        if camera.is_some() {
            bail!(
                "--response, --ambient, --exposure-jitter and --format apply to distant rigs; \
                 {} is a near-light rig",
                a.rig
            );
        }
        if width != height {
            bail!("--size {width}x{height}: near-light rigs take square images (--size N)");
        }
        return near(&a, scene, rig, mask, textured_albedo);
    }
    let mut spec = SynthSpec::new(scene, photostereo::io::light_files::parse_rig(&a.rig)?);
    spec.size = width;
    spec.height = (height != width).then_some(height);
    spec.mask = mask;
    spec.textured_albedo = textured_albedo;
    spec.intensities = LightIntensities::parse(&a.intensities)?;
    spec.render.brdf = a.brdf.parse::<Brdf>()?;
    spec.render.noise_sigma = a.noise;
    spec.render.shot_full_well = a.shot;
    spec.render.seed = a.seed;
    let output = a
        .output
        .clone()
        .unwrap_or_else(|| PathBuf::from(format!("synth-{}", scene.name())));
    // A rig given as a light file is an input: --force never replaces it or its folder.
    let rig_file = std::path::Path::new(&a.rig);
    if rig_file.exists() {
        photostereo::io::export::check_output(
            &output,
            a.out.force,
            photostereo::io::export::OutputKind::Synth,
            &[rig_file],
        )?;
    }
    let budget = a
        .memory_limit
        .unwrap_or_else(photostereo::model::memory::default_budget);
    let n_lights = spec.rig.lights()?.len();
    if photostereo::scene::render::in_memory_bytes(width, height, n_lights) > budget
        || width != height
    {
        let need = photostereo::scene::render::streamed_bytes(width, height);
        if need > budget {
            bail!(
                "--memory-limit {}: rendering {width}×{height} needs about {} (the scene and one light); \
                 the smallest budget that works is {}",
                photostereo::model::memory::size_flag(budget),
                photostereo::model::memory::size_flag(need),
                photostereo::model::memory::size_flag(need)
            );
        }
        let bar = a.out.progress();
        let (s, lights, target) = photostereo::io::synth::synth_streamed(
            &spec,
            camera.as_ref(),
            &output,
            a.out.force,
            &bar,
        )?;
        if a.out.json {
            print_json(&serde_json::json!({
                "output": target.display().to_string(),
                "scene": scene.name(),
                "rig": spec.rig.name(),
                "lights": lights.len(),
                "width": width,
                "height": height,
                "streamed": true,
                "camera": camera_json(camera.as_ref(), &a.format),
                "stats": s,
            }));
        } else if a.out.text() {
            println!(
                "{} under {} ({} lights), {width}×{height}, rendered one light at a time; shadowed {:.1}%, highlighted {:.1}%",
                scene.name(),
                spec.rig.name(),
                lights.len(),
                100.0 * s.shadow_fraction,
                100.0 * s.highlight_fraction
            );
            println!("wrote {}", target.display());
        }
        return Ok(());
    }
    if !(8..=8192).contains(&width) {
        bail!("--size {width}: expected 8..=8192 pixels for a square capture rendered whole");
    }
    let (rendered, target) = match &camera {
        Some(c) => photostereo::io::synth::synth_camera_to_folder(&spec, c, &output, a.out.force)?,
        None => synth_to_folder(&spec, &output, a.out.force)?,
    };
    let s = &rendered.stats;
    if a.out.json {
        print_json(&serde_json::json!({
            "output": target.display().to_string(),
            "scene": rendered.scene,
            "rig": rendered.rig,
            "lights": rendered.lights.len(),
            "size": spec.size,
            "mask": spec.mask.unwrap_or(scene.default_mask()).name(),
            "brdf": spec.render.brdf.name(),
            "noise_sigma": spec.render.noise_sigma,
            "shot_full_well": spec.render.shot_full_well,
            "seed": spec.render.seed,
            "camera": camera_json(camera.as_ref(), &a.format),
            "stats": s,
        }));
    } else if a.out.text() {
        println!(
            "{} under {} ({} lights), {}×{}, {}, σ {}%, seed {}",
            rendered.scene,
            rendered.rig,
            rendered.lights.len(),
            spec.size,
            spec.size,
            spec.render.brdf,
            spec.render.noise_sigma * 100.0,
            spec.render.seed
        );
        print_stats(s, &target);
    }
    Ok(())
}

/// The camera's settings as `synth --json` reports them (null without one).
fn camera_json(
    camera: Option<&photostereo::io::camera::CameraSpec>,
    format: &str,
) -> serde_json::Value {
    camera.map_or(serde_json::Value::Null, |c| {
        serde_json::json!({
            "response": c.response.name(),
            "ambient": c.ambient,
            "exposure_jitter": c.exposure_jitter,
            "format": format,
        })
    })
}

fn parse_camera_response(s: &str) -> Result<photostereo::io::photometry::Response, String> {
    use photostereo::io::photometry::ResponseChoice;
    match s.parse::<ResponseChoice>().map_err(|e| e.to_string())? {
        ResponseChoice::Fixed(r) => Ok(r),
        ResponseChoice::Auto => Err("auto: expected linear, srgb or gamma:G".into()),
    }
}

/// The camera the images are written as, when a flag asks for one.
fn camera_spec(a: &SynthArgs) -> Result<Option<photostereo::io::camera::CameraSpec>> {
    use photostereo::io::camera::{CameraFormat, CameraSpec};
    use photostereo::io::photometry::Response;
    // A JPEG is read as the colour space it declares, sRGB without a declaration: its
    // default response is sRGB, as a camera's.
    let jpeg = matches!(a.format.as_str(), "jpeg" | "jpg");
    let response = a.response.unwrap_or(if jpeg {
        Response::Srgb
    } else {
        Response::Linear
    });
    let format = match a.format.as_str() {
        "png" if response == Response::Linear => CameraFormat::Png16,
        "png" | "png8" => CameraFormat::Png8,
        "png16" => CameraFormat::Png16,
        "jpeg" | "jpg" => CameraFormat::Jpeg(a.quality),
        other => bail!("--format {other}: expected png, png8, png16 or jpeg"),
    };
    if a.exposure_jitter != 1.0 && !matches!(format, CameraFormat::Jpeg(_)) {
        bail!(
            "--exposure-jitter {}: needs --format jpeg (the exposures are recorded in EXIF)",
            a.exposure_jitter
        );
    }
    if a.response.is_none() && a.ambient == 0.0 && a.exposure_jitter == 1.0 && a.format == "png" {
        return Ok(None);
    }
    Ok(Some(CameraSpec {
        response,
        ambient: a.ambient,
        exposure_jitter: a.exposure_jitter,
        format,
        seed: a.seed,
    }))
}

/// A near-light scene in the near-light layout.
fn near(
    a: &SynthArgs,
    scene: SceneKind,
    rig: photostereo::scene::near::NearRig,
    mask: Option<MaskShape>,
    textured_albedo: bool,
) -> Result<()> {
    use photostereo::io::synth::near_synth_to_folder;
    use photostereo::scene::near::NearSpec;
    if a.shot != 0.0 || a.intensities != "uniform" {
        bail!("--shot and --intensities apply to distant rigs; near rigs have their own LED radiances");
    }
    if a.size.0 < 16 {
        bail!(
            "--size {}: near-light scenes need at least 16 pixels",
            a.size.0
        );
    }
    let spec = NearSpec {
        size: a.size.0,
        distance: a.distance,
        mask,
        textured_albedo,
        brdf: a.brdf.parse::<Brdf>()?,
        noise_sigma: a.noise,
        seed: a.seed,
        ..NearSpec::new(scene, rig)
    };
    let output = a
        .output
        .clone()
        .unwrap_or_else(|| PathBuf::from(format!("synth-{}", scene.name())));
    let (r, target) = near_synth_to_folder(&spec, &output, a.out.force)?;
    let s = &r.rendered.stats;
    if a.out.json {
        print_json(&serde_json::json!({
            "output": target.display().to_string(),
            "scene": r.rendered.scene,
            "rig": r.rendered.rig,
            "lights": r.positions.len(),
            "size": spec.size,
            "mean_distance_mm": r.distance,
            "camera": {"fx": r.camera.fx, "fy": r.camera.fy, "cx": r.camera.cx, "cy": r.camera.cy},
            "brdf": spec.brdf.name(),
            "noise_sigma": spec.noise_sigma,
            "seed": spec.seed,
            "stats": s,
        }));
    } else if a.out.text() {
        println!(
            "{} under {} ({} LEDs, object at {:.1} mm, fx {:.1} px), {}×{}, {}, σ {}%, seed {}",
            r.rendered.scene,
            r.rendered.rig,
            r.positions.len(),
            r.distance,
            r.camera.fx,
            spec.size,
            spec.size,
            spec.brdf,
            spec.noise_sigma * 100.0,
            spec.seed
        );
        print_stats(s, &target);
    }
    Ok(())
}

/// The closing lines of a rendered capture's text summary: its shadow, highlight and clipping
/// shares and where it was written.
fn print_stats(s: &photostereo::scene::render::CaptureStats, target: &std::path::Path) {
    println!(
        "mask pixels, mean over lights: shadowed {:.1}% (cast {:.1}%), highlighted {:.1}%, clipped {:.1}%",
        100.0 * s.shadow_fraction,
        100.0 * s.cast_shadow_fraction,
        100.0 * s.highlight_fraction,
        100.0 * s.clipped_fraction
    );
    println!("wrote {}", target.display());
}

fn list(out: &OutputOpts) -> Result<()> {
    let scenes: Vec<&str> = SceneKind::ALL.iter().map(|s| s.name()).collect();
    let mut rigs: Vec<&str> = Rig::NAMES.to_vec();
    rigs.extend(
        photostereo::scene::near::NearRig::ALL
            .iter()
            .map(|r| r.name()),
    );
    let brdfs: Vec<&str> = Brdf::ALL.iter().map(|b| b.name()).collect();
    let masks: Vec<&str> = MaskShape::ALL.iter().map(|m| m.name()).collect();
    let intens: Vec<&str> = LightIntensities::ALL.iter().map(|m| m.name()).collect();
    if out.json {
        print_json(&serde_json::json!({
            "scenes": scenes, "rigs": rigs, "brdfs": brdfs, "masks": masks, "intensities": intens,
        }));
    } else if !out.quiet {
        for (heading, names) in [
            ("scenes:", &scenes),
            ("rigs:", &rigs),
            ("reflectance models:", &brdfs),
            ("masks:", &masks),
            ("light intensities:", &intens),
        ] {
            println!("{heading}");
            for n in names {
                println!("{n}");
            }
        }
    }
    Ok(())
}

/// `--size N` or `--size WxH`.
fn parse_size(s: &str) -> std::result::Result<(usize, usize), String> {
    let bad = || format!("'{s}': expected N or WxH pixels, e.g. 128 or 8000x6000");
    let parse = |t: &str| t.trim().parse::<usize>().map_err(|_| bad());
    let (w, h) = match s.split_once(['x', 'X', '×']) {
        Some((w, h)) => (parse(w)?, parse(h)?),
        None => {
            let n = parse(s)?;
            (n, n)
        }
    };
    if w < 8 || h < 8 {
        return Err(format!("'{s}': expected at least 8 pixels a side"));
    }
    Ok((w, h))
}
