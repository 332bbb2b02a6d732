//! `photostereo synth`: render a built-in scene under a light rig into a DiLiGenT-layout folder
//! with ground truth (`gt/`).

use crate::common::{print_json, OutputOpts};
use anyhow::{bail, Result};
use clap::Args;
use photostereo::scene::{
    render::LightIntensities, synth_to_folder, Brdf, MaskShape, Rig, SceneKind, SynthSpec,
};
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
    /// Near-light rigs: the distance of the rig's centre from the camera, mm.
    #[arg(long, default_value_t = 300.0)]
    pub distance: f64,
    /// Image width and height, pixels.
    #[arg(long, default_value_t = 128)]
    pub size: usize,
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
    if !(8..=8192).contains(&a.size) {
        bail!("--size {}: expected 8..=8192 pixels", a.size);
    }
    if let Some(rig) = photostereo::scene::near::NearRig::parse(&a.rig) {
        return near(&a, scene, rig, mask, textured_albedo);
    }
    let mut spec = SynthSpec::new(scene, Rig::parse(&a.rig)?);
    spec.size = a.size;
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
        photostereo::export::check_output(&output, a.out.force, &[rig_file])?;
    }
    let (rendered, target) = synth_to_folder(&spec, &output, a.out.force)?;
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
        println!(
            "mask pixels, mean over lights: shadowed {:.1}% (cast {:.1}%), highlighted {:.1}%, clipped {:.1}%",
            100.0 * s.shadow_fraction,
            100.0 * s.cast_shadow_fraction,
            100.0 * s.highlight_fraction,
            100.0 * s.clipped_fraction
        );
        println!("wrote {}", target.display());
    }
    Ok(())
}

/// A near-light scene (issue 13) in the near-light layout.
fn near(
    a: &SynthArgs,
    scene: SceneKind,
    rig: photostereo::scene::near::NearRig,
    mask: Option<MaskShape>,
    textured_albedo: bool,
) -> Result<()> {
    use photostereo::scene::near::{near_synth_to_folder, NearSpec};
    if a.shot != 0.0 || a.intensities != "uniform" {
        bail!("--shot and --intensities apply to distant rigs; near rigs have their own LED radiances");
    }
    if a.size < 16 {
        bail!(
            "--size {}: near-light scenes need at least 16 pixels",
            a.size
        );
    }
    let spec = NearSpec {
        size: a.size,
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
        println!(
            "mask pixels, mean over lights: shadowed {:.1}% (cast {:.1}%), highlighted {:.1}%, clipped {:.1}%",
            100.0 * s.shadow_fraction,
            100.0 * s.cast_shadow_fraction,
            100.0 * s.highlight_fraction,
            100.0 * s.clipped_fraction
        );
        println!("wrote {}", target.display());
    }
    Ok(())
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
