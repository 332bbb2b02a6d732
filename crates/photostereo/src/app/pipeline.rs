//! The run driver: load → reconstruct → evaluate → report → export. Files are read and written
//! here (and in the io modules it calls); the algorithms are the engine's
//! ([`crate::method::engine::reconstruct`]), which holds no path and prints nothing.

use crate::base::error::{param, param_set, Error, Result};
use crate::base::progress::Progress;
use crate::io::export::{
    write_albedo, write_json, write_normals, write_npy_f32, OutputFolder, OutputKind,
};
use crate::io::figure::write_error_map;
use crate::io::groundtruth::read_normal_map;
use crate::io::imageio::write_png8;
use crate::io::layouts::CaptureFiles;
use crate::method::engine::{reconstruct_to_write, Params, Reconstruction};
use std::path::{Path, PathBuf};
use std::str::FromStr;
use std::time::Instant;

/// A subset of a capture's lights to use instead of all of them.
#[derive(Clone, Debug, PartialEq)]
pub enum LightSubset {
    /// These lights (0-based indices), in this order.
    Indices(Vec<usize>),
    /// The four lights closest to a square rig at this slant (degrees), tilts 90° apart.
    Square { slant_deg: f64 },
}

impl FromStr for LightSubset {
    type Err = Error;
    /// `square` (slant 35°, the paper's rig), `square:SLANT`, or 1-based indices `1,5,9,13`.
    fn from_str(s: &str) -> Result<Self> {
        if s == "square" {
            return Ok(LightSubset::Square { slant_deg: 35.0 });
        }
        if let Some(v) = s.strip_prefix("square:") {
            let slant: f64 = v.parse().map_err(|_| {
                Error::invalid(format!("light subset '{s}': slant '{v}' is not a number"))
            })?;
            if !(0.0..90.0).contains(&slant) {
                return Err(Error::invalid(format!(
                    "light subset '{s}': slant must be in [0, 90) degrees"
                )));
            }
            return Ok(LightSubset::Square { slant_deg: slant });
        }
        let idx: std::result::Result<Vec<usize>, _> =
            s.split(',').map(|t| t.trim().parse::<usize>()).collect();
        let v = match idx {
            Ok(v) if !v.is_empty() && v.iter().all(|&i| i >= 1) => v,
            _ => {
                return Err(Error::invalid(format!(
                    "light subset '{s}': expected 'square', 'square:SLANT' or 1-based indices like 1,5,9,13"
                )))
            }
        };
        // A light named twice would count its image twice in every fit.
        if let Some((i, &k)) = v.iter().enumerate().find(|(i, k)| v[..*i].contains(k)) {
            return Err(Error::invalid(format!(
                "light subset '{s}': light {k} is named twice (positions {} and {}); each light \
                 may be used once",
                v.iter().position(|&x| x == k).unwrap() + 1,
                i + 1
            )));
        }
        Ok(LightSubset::Indices(v.into_iter().map(|i| i - 1).collect()))
    }
}

impl LightSubset {
    /// The 0-based indices this subset picks from `lights`.
    pub fn resolve(&self, lights: &crate::model::lights::Lights) -> Result<Vec<usize>> {
        match self {
            LightSubset::Indices(v) => Ok(v.clone()),
            LightSubset::Square { slant_deg } => {
                crate::model::lights::closest_square_rig(lights, *slant_deg)
                    .map(|a| a.to_vec())
                    .ok_or_else(|| {
                        Error::invalid("no four distinct lights form a square rig in this capture")
                    })
            }
        }
    }
}

/// A run: the engine's parameters and what the driver does around them.
#[derive(Clone, Debug, Default)]
pub struct RunOptions {
    /// What shapes the reconstruction.
    pub params: Params,
    /// Ground-truth normal map to evaluate against.
    pub ground_truth: Option<PathBuf>,
    /// Write `error_map.png` (needs ground truth).
    pub error_map: bool,
    /// Upper end of the error map's colour scale, degrees (default 45 when `None`).
    pub error_map_max_deg: Option<f32>,
    /// Use only these lights.
    pub light_subset: Option<LightSubset>,
    /// Write `mesh.obj` at any size; by default it is skipped, with a note, above
    /// [`OBJ_MAX_VERTICES`] (the text format is about 10 times the binary PLY, which is written
    /// at every size).
    pub obj_any_size: bool,
    /// See [`crate::io::layouts::LoadOptions::return_freed_memory_when_tiled`].
    pub return_freed_memory_when_tiled: bool,
    /// Also fit this RTI basis to the readings and write its files beside the normals
    /// ([`crate::app::rti::write_fit`]), its figures in `report.json`'s `rti`.
    pub rti: Option<crate::solve::rti::Basis>,
}

/// Above this many vertices `mesh.obj` is skipped unless asked for.
pub const OBJ_MAX_VERTICES: usize = 10_000_000;

/// Upper end of the error map's colour scale when none is given, degrees.
pub const DEFAULT_ERROR_MAP_MAX_DEG: f32 = 45.0;

/// Writes a reconstruction's files into a (staging) folder.
pub fn write_reconstruction(rec: &Reconstruction, dir: &Path, options: &RunOptions) -> Result<()> {
    write_normals(dir, rec.width, rec.height, &rec.normals)?;
    write_albedo_of(rec, dir)?;
    write_statuses(rec, dir)?;
    write_detection(rec, dir)?;
    write_recursive(rec, dir)?;
    write_surface(rec, dir, options)?;
    write_error_figure(rec, dir, options)
}

/// [`write_reconstruction`], each map released once its files are written: the statuses, the
/// detector's and the recursion's maps and the albedo first, the surface and its meshes
/// (which read the normals) last, so that the writers' buffers are never held beside every
/// map. The reconstruction keeps its report and figures; its maps are empty afterwards.
pub fn write_releasing(rec: &mut Reconstruction, dir: &Path, options: &RunOptions) -> Result<()> {
    write_statuses(rec, dir)?;
    rec.light_status = crate::method::statusmap::StatusMap::packed(
        rec.width,
        rec.height,
        rec.n_lights,
        Vec::new(),
        None,
    );
    write_detection(rec, dir)?;
    rec.residual = None;
    rec.unreliable = None;
    write_recursive(rec, dir)?;
    if let Some(r) = rec.recursive.as_mut() {
        r.shadows = crate::geometry::shadows::ShadowMaps::empty(0, 0, 0);
        for map in [&mut r.highlight, &mut r.fewer_than_three, &mut r.reliable] {
            drop(std::mem::take(map));
        }
        r.gloss = None;
    }
    drop(std::mem::take(&mut rec.trust));
    write_albedo_of(rec, dir)?;
    drop(std::mem::take(&mut rec.albedo));
    write_error_figure(rec, dir, options)?;
    rec.error_map = None;
    write_normals(dir, rec.width, rec.height, &rec.normals)?;
    // The surface's maps, parked under a tight budget ([`reconstruct_to_write`]), come back
    // once every other map but the normals is written and released.
    rec.unpark_surface()?;
    note_skipped_obj(rec, options);
    write_surface(rec, dir, options)?;
    drop(std::mem::take(&mut rec.normals));
    drop(std::mem::take(&mut rec.mask));
    if let Some(s) = rec.surface.as_mut() {
        drop(std::mem::take(&mut s.depth.values));
        s.depth.discontinuities = None;
        drop(std::mem::take(&mut s.curl));
    }
    Ok(())
}

/// The report's note that `mesh.obj` is not written, when the surface has more vertices than
/// [`OBJ_MAX_VERTICES`] and the options do not ask for it at any size.
fn note_skipped_obj(rec: &mut Reconstruction, options: &RunOptions) {
    if let Some(s) = &rec.surface {
        let vertices = s.depth.values.iter().filter(|v| v.is_finite()).count();
        if vertices > OBJ_MAX_VERTICES && !options.obj_any_size {
            rec.report.notes.push(format!(
                "mesh.obj skipped: {vertices} vertices, more than {OBJ_MAX_VERTICES} (mesh.ply holds the mesh)"
            ));
        }
    }
}

/// The albedo's files ([`write_albedo`]) of `rec`.
fn write_albedo_of(rec: &Reconstruction, dir: &Path) -> Result<()> {
    write_albedo(
        dir,
        rec.width,
        rec.height,
        rec.channels,
        &rec.albedo,
        &rec.mask,
    )
}

/// `light_status.npy` and `unusable_lights.png`, when the statuses were decided.
fn write_statuses(rec: &Reconstruction, dir: &Path) -> Result<()> {
    if !rec.statuses_decided {
        return Ok(());
    }
    let (w, h) = (rec.width, rec.height);
    // Light by light: one frame of bytes at a time, not the (N, H, W) array.
    crate::io::export::write_npy_u8_planes(
        &dir.join("light_status.npy"),
        &[rec.n_lights, h, w],
        |k, plane| rec.light_status.write_plane(k, plane),
    )?;
    crate::io::maps::write_unusable_lights(dir, rec)
}

/// The detector's maps: `residual.npy`, `unreliable.png` and `unreliable_mask.png`.
fn write_detection(rec: &Reconstruction, dir: &Path) -> Result<()> {
    let (w, h) = (rec.width, rec.height);
    if let (Some(residual), Some(unreliable)) = (&rec.residual, &rec.unreliable) {
        write_npy_f32(&dir.join("residual.npy"), &[h, w], residual)?;
        // Fig. 6a: the statistic as grey with its scale and the test's threshold; Fig. 6b: binary.
        crate::io::maps::write_unreliable(dir, rec, residual)?;
        let binary: Vec<u8> = unreliable
            .iter()
            .map(|&u| if u { 255 } else { 0 })
            .collect();
        write_png8(&dir.join("unreliable_mask.png"), w, h, 1, &binary)?;
    }
    Ok(())
}

/// The recursive method's maps: shadows, highlights, pixels with fewer than three lights, and
/// the lobes' maps when modelled.
fn write_recursive(rec: &Reconstruction, dir: &Path) -> Result<()> {
    let (w, h) = (rec.width, rec.height);
    if let Some(r) = &rec.recursive {
        crate::io::shadow_figure::shadow_maps_montage(&r.shadows, Some(&rec.mask))
            .save(&dir.join("shadows.png"))?;
        let bytes = |m: &[bool]| {
            m.iter()
                .map(|&b| if b { 255u8 } else { 0 })
                .collect::<Vec<u8>>()
        };
        write_png8(&dir.join("highlight.png"), w, h, 1, &bytes(&r.highlight))?;
        write_png8(
            &dir.join("fewer_than_three.png"),
            w,
            h,
            1,
            &bytes(&r.fewer_than_three),
        )?;
        if let Some(g) = &r.gloss {
            write_npy_f32(&dir.join("specular_strength.npy"), &[h, w], &g.strength)?;
            write_npy_f32(&dir.join("roughness.npy"), &[h, w], &g.roughness)?;
        }
    }
    Ok(())
}

/// The depth, curl and discontinuity maps and the meshes, when integrated.
fn write_surface(rec: &Reconstruction, dir: &Path, options: &RunOptions) -> Result<()> {
    if let Some(surface) = &rec.surface {
        let d = &surface.depth;
        let vertices = d.values.iter().filter(|v| v.is_finite()).count();
        let camera = rec.camera.as_ref();
        if vertices > OBJ_MAX_VERTICES && !options.obj_any_size {
            crate::io::surface::write_surface_camera(dir, surface, &rec.normals, false, camera)?;
            crate::io::surface::write_mesh_ply_camera(
                &dir.join("mesh.ply"),
                d.width,
                d.height,
                &d.values,
                &rec.normals,
                camera,
            )?;
        } else {
            crate::io::surface::write_surface_camera(dir, surface, &rec.normals, true, camera)?;
        }
    }
    Ok(())
}

/// `error_map.png`, when asked for and made.
fn write_error_figure(rec: &Reconstruction, dir: &Path, options: &RunOptions) -> Result<()> {
    if options.error_map {
        if let Some(map) = &rec.error_map {
            write_error_map(
                &dir.join("error_map.png"),
                map,
                rec.width,
                rec.height,
                options
                    .error_map_max_deg
                    .unwrap_or(DEFAULT_ERROR_MAP_MAX_DEG),
            )?;
        }
    }
    Ok(())
}

/// What `run --rti` holds beside the run's stages ([`crate::app::rti::memory_beside`]);
/// nothing without it.
fn rti_beside(files: &CaptureFiles, options: &RunOptions) -> Result<crate::model::memory::Beside> {
    let Some(basis) = options.rti else {
        return Ok(Default::default());
    };
    let channels = crate::io::imageio::probe(&files.images[0])?.channels;
    Ok(crate::app::rti::memory_beside(
        basis,
        files.images.len(),
        channels,
        false,
    ))
}

/// The whole `run`: load, reconstruct, evaluate, report, and write `output` atomically.
/// Returns the reconstruction with its report and figures; its maps are released as they are
/// written ([`write_releasing`]).
pub fn run(
    files: &CaptureFiles,
    options: &RunOptions,
    output: &Path,
    force: bool,
    progress: &dyn Progress,
) -> Result<Reconstruction> {
    if options.error_map && options.ground_truth.is_none() {
        return Err(Error::invalid(format!(
            "{} needs ground truth ({})",
            param("error_map"),
            param_set("gt", "")
        )));
    }
    options.params.validate()?;
    // Refuse an existing output before any work.
    let folder = OutputFolder::create(output, force, OutputKind::Run)?;
    let start = Instant::now();
    // Read the ground truth first: a bad file fails fast, before decoding the capture.
    let truth = match &options.ground_truth {
        Some(p) => Some(read_normal_map(p)?),
        None => None,
    };
    let t = Instant::now();
    let load_options = crate::io::layouts::LoadOptions {
        budget: options.params.memory_limit,
        spill_dir: Some(folder.path().to_path_buf()),
        return_freed_memory_when_tiled: options.return_freed_memory_when_tiled,
        ground_truth: truth.is_some(),
        beside: rti_beside(files, options)?,
        ..Default::default()
    };
    let (mut capture, photometry) = files.load_measured(progress, &load_options)?;
    let mut subset = None;
    if let Some(s) = &options.light_subset {
        let keep = s.resolve(&capture.lights)?;
        capture = capture.select_lights(&keep)?;
        subset = Some(keep);
    }
    // With `refine_lights`, the lights (the chosen subset's) refined from the readings, once
    // for every method that runs on this capture.
    crate::method::engine::prepare(&mut capture, &options.params)?;
    let load_seconds = t.elapsed().as_secs_f64();
    if let (Some(t), Some(path)) = (&truth, &options.ground_truth) {
        if (t.width, t.height) != (capture.width, capture.height) {
            return Err(Error::file(
                path,
                format!(
                    "ground truth is {}×{} but the capture is {}×{}",
                    t.width, t.height, capture.width, capture.height
                ),
            ));
        }
    }
    // The truth is held at the mask pixels only from here (12 bytes a mask pixel instead of
    // a frame pixel): the run and the evaluation read it there.
    let truth = truth
        .map(|t| {
            crate::solve::metrics::truth_at_pixels(&t.normals, t.width, t.height, &capture.pixels)
                .map(|c| c.into_owned())
        })
        .transpose()?;
    let mut rec = reconstruct_to_write(&capture, &options.params, truth.as_deref(), progress)?;
    // `rti`: the relightable image from the same readings, while they are loaded.
    let rti = options
        .rti
        .map(|basis| crate::app::rti::fit_beside_run(&capture, basis, &rec, folder.path()))
        .transpose()?;
    drop(capture);
    rec.report
        .notes
        .extend(crate::solve::plausibility::unestimated_note(
            &rec.normals,
            &rec.mask,
        ));
    let report = &mut rec.report;
    report.input.mask_file = files.mask.as_ref().map(|p| p.display().to_string());
    report.extra.insert(
        "photometry".into(),
        serde_json::to_value(&photometry).map_err(|e| Error::invalid(e.to_string()))?,
    );
    report
        .timings_s
        .shift_insert(0, "load".into(), load_seconds.into());
    if let Some(keep) = subset {
        report.param(
            "light_subset",
            keep.iter().map(|k| k + 1).collect::<Vec<_>>(),
        );
    }
    if let (Some(truth), Some(path)) = (&truth, &options.ground_truth) {
        let t = Instant::now();
        progress.begin("evaluating", 1);
        rec.evaluate(truth)?;
        progress.end();
        rec.report.param("ground_truth", path.display().to_string());
        rec.report.time("evaluate", t);
    }
    // The error figures and map are made: the truth (12 bytes a pixel) is not held while writing.
    drop(truth);
    let t = Instant::now();
    progress.begin("writing", 1);
    write_releasing(&mut rec, folder.path(), options)?;
    if let Some((fitted, mut entry)) = rti {
        let (file, web) = crate::app::rti::write_fit(folder.path(), &fitted, None)?;
        entry["file"] = file;
        entry["web"] = web;
        rec.report.extra.insert("rti".into(), entry);
    }
    progress.end();
    rec.report.time("write", t);
    rec.report.time("total", start);
    if let (Some(serde_json::Value::Object(m)), Some(peak)) = (
        rec.report.extra.get_mut("memory"),
        crate::base::machine::peak_rss(),
    ) {
        m.insert("peak_rss".into(), peak.into());
    }
    write_json(&folder.file("report.json"), &rec.report)?;
    folder.commit()?;
    Ok(rec)
}
