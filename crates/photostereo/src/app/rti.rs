//! The `rti` driver: load a capture, fit a relightable-image basis per pixel
//! ([`crate::solve::rti`]), measure its leave-one-out relighting error beside the Lambertian
//! relighting of photostereo's own normals and albedo, and write the viewer file, relight's web
//! folder for OpenLIME, the float coefficients and `report.json` into an output folder
//! atomically.
//!
//! Memory: the fit goes block by block into `coefficients.npy` (and `chroma.npy`) as it is made,
//! and every other file is written from them by row bands ([`crate::io::rti`]); what the fit and
//! the writing hold beside the run's stages ([`memory_beside`]) is part of the capture's memory
//! plan, so the budget rules are `run`'s.

use crate::base::error::{Error, Result};
use crate::base::progress::Progress;
use crate::io::export::{write_json, OutputFolder, OutputKind};
use crate::io::layouts::{CaptureFiles, LoadOptions};
use crate::io::rti::{CoefficientFiles, FitSource, StoredFit};
use crate::method::engine::{reconstruct, Method, Params, Reconstruction};
use crate::model::capture::Capture;
use crate::model::memory::{Beside, Stages};
use crate::solve::lambert::status;
use crate::solve::rti::{
    fit_penalised_into, lambert_errors, Basis, Penalty, Prior, ReadingMask, RelightErrors, RtiFit,
};
use serde_json::{json, Value};
use std::path::Path;
use std::time::Instant;

/// What an `rti` run does.
#[derive(Clone, Debug)]
pub struct RtiOptions {
    /// The basis fitted.
    pub basis: Basis,
    /// Run the recursive method first and leave out of each pixel's fit the readings it did
    /// not use (shadows and highlights) and those the camera clipped at full scale.
    pub exclude_unreliable: bool,
    /// The ridge weight per light, λ / N, of the linear bases' fits (0: unregularised least
    /// squares); `None`: chosen from the data by leave-one-out ([`Penalty::Auto`]). Not
    /// with rbf.
    pub ridge: Option<f64>,
    /// Memory budget in bytes (`None`: half the memory available), as `run`'s.
    pub memory_limit: Option<u64>,
    /// Also write each plane image of relight's web folder as IIIF Image API 3.0 level-0
    /// static tiles, `relight/plane_G/` (`info.json` and the tiles), served at this base URI
    /// (`id` = `BASE/relight/plane_G`).
    pub iiif: Option<String>,
}

/// The folder of relight's web format (info.json and the coefficient planes) in the output.
pub const WEB_FOLDER: &str = "relight";

/// The file name of the viewer file of `basis`.
pub fn image_name(basis: Basis) -> &'static str {
    match basis {
        Basis::PtmLrgb | Basis::PtmRgb => "image.ptm",
        Basis::Hsh2 | Basis::Hsh3 => "image.rti",
        Basis::Rbf => "basis.npy",
    }
}

/// What an RTI fit and the writing of its files hold beside the run's stages
/// ([`crate::model::memory::Beside`]), for a capture of `lights` images. Beside the stages:
/// per mask pixel the fit's copy of the mask pixels' frame indices (4 bytes), the fit's blocks
/// ([`crate::solve::rti::BLOCK_PIXELS`] pixels of at most 27 coefficients and 3 chroma, 8 MiB)
/// and for RBF the PCA's sample of pixels (12 bytes a reading) or, after it, the choice's
/// ([`crate::solve::rti::rbf::choice_bytes`]), whichever is more. While writing: the writers' row
/// band ([`crate::io::rti::BAND_BYTES`]), with `iiif` IIIF's whole small levels
/// ([`crate::io::rti::tiles::IIIF_FULL_BYTES`] and the levels below), and per column of the
/// frame the tile pyramids' row strips and the PNG encoder's bands
/// ([`crate::io::rti::tiles::BYTES_PER_COLUMN`]). `exclude_unreliable` adds nothing: the
/// statuses are read where the recursive method holds them. The stages are `run`'s; the `rti`
/// command's own are set by [`rti`].
pub fn memory_beside(basis: Basis, lights: usize, channels: usize, iiif: bool) -> Beside {
    let pca = if basis == Basis::Rbf {
        let sample = (crate::solve::rti::rbf::PCA_PIXELS * lights * channels * 12) as u64;
        sample.max(crate::solve::rti::rbf::choice_bytes(lights, channels))
    } else {
        0
    };
    let full = if iiif {
        (crate::io::rti::tiles::IIIF_FULL_BYTES * 4 / 3) as u64
    } else {
        0
    };
    Beside {
        per_frame_pixel: 0,
        per_mask_pixel: 4,
        fixed: (8 << 20) + pca,
        writing_per_column: crate::io::rti::tiles::BYTES_PER_COLUMN,
        writing_fixed: crate::io::rti::BAND_BYTES as u64 + full,
        stages: Stages::Run,
    }
}

/// The whole `rti` command: returns the report it wrote to `output/report.json`.
pub fn rti(
    files: &CaptureFiles,
    options: &RtiOptions,
    output: &Path,
    force: bool,
    progress: &dyn Progress,
) -> Result<Value> {
    let start = Instant::now();
    check_options(&files.lights, options)?;
    let iiif = options.iiif.as_deref().map(iiif_base).transpose()?;
    let folder = OutputFolder::create(output, force, OutputKind::Rti)?;
    let channels = crate::io::imageio::probe(&files.images[0])?.channels;
    let load = LoadOptions {
        budget: options.memory_limit,
        spill_dir: Some(folder.path().to_path_buf()),
        // The reference is the recursive method with `exclude_unreliable` (run's stages less
        // the integration), else a least-squares estimate.
        beside: Beside {
            stages: if options.exclude_unreliable {
                Stages::Run
            } else {
                Stages::Estimate
            },
            ..memory_beside(
                options.basis,
                files.images.len(),
                channels,
                options.iiif.is_some(),
            )
        },
        ..Default::default()
    };
    let capture = files.load_with(progress, &load)?;
    let t = Instant::now();
    let rec = reference(&capture, options, progress)?;
    let exclude = options
        .exclude_unreliable
        .then_some(&rec.light_status as &dyn ReadingMask);
    let reference_s = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let size = (capture.width, capture.height, capture.channels);
    let mut store = CoefficientFiles::create(folder.path(), options.basis, size, &capture.pixels)?;
    let penalty = penalty(options, capture.n_lights());
    let meta = fit_penalised_into(&capture, options.basis, exclude, penalty, &mut store)?;
    let fitted = store.finish(meta);
    let lambert = lambert_errors(
        &capture,
        &rec.normals,
        &rec.albedo,
        fitted.meta().gain,
        exclude,
    )?;
    let fit_s = t.elapsed().as_secs_f64();
    let mut report = report(&capture, fitted.meta(), &lambert, &rec, options);
    let plan = capture.memory.clone();
    // The files are written from the fit's float files alone.
    drop((capture, rec));
    let t = Instant::now();
    let (file, web) = write_fit(folder.path(), &fitted, iiif.as_deref())?;
    report["file"] = file;
    report["web"] = web;
    report["timings_s"] = json!({
        "reference": reference_s,
        "fit": fit_s,
        "write": t.elapsed().as_secs_f64(),
        "total": start.elapsed().as_secs_f64(),
    });
    report["memory"] = json!(plan);
    if let (Some(m), Some(peak)) = (
        report["memory"].as_object_mut(),
        crate::base::machine::peak_rss(),
    ) {
        m.insert("peak_rss".into(), peak.into());
    }
    write_json(&folder.file("report.json"), &report)?;
    folder.commit()?;
    Ok(report)
}

/// Writes a fit's files into the folder `dir`, beside its float coefficients (written as the
/// fit made them): the viewer file ([`image_name`]), `rti.json` and relight's web folder, with
/// `iiif` (an http(s) base URI without a trailing `/`) the IIIF tiles of its plane images; returns the report's
/// `file` and `web` entries.
pub fn write_fit(dir: &Path, fitted: &StoredFit, iiif: Option<&str>) -> Result<(Value, Value)> {
    let meta = fitted.meta();
    let name = image_name(meta.basis);
    let image = dir.join(name);
    let maps = match meta.basis {
        Basis::PtmLrgb | Basis::PtmRgb => json!(crate::io::rti::ptm::write_ptm(&image, fitted)?),
        Basis::Hsh2 | Basis::Hsh3 => json!(crate::io::rti::hsh::write_hsh(&image, fitted)?),
        Basis::Rbf => crate::io::rti::write_rbf_basis(&image, meta)?,
    };
    crate::io::rti::write_model_json(&dir.join(crate::io::rti::MODEL_JSON), meta)?;
    let served = iiif.map(|base| format!("{base}/{WEB_FOLDER}"));
    let (web, ids) = crate::io::rti::relight::write_relight_with(
        &dir.join(WEB_FOLDER),
        fitted,
        served.as_deref(),
    )?;
    let mut entry = json!({
        "folder": WEB_FOLDER,
        "type": web["type"],
        "colorspace": web["colorspace"],
        "nplanes": web["nplanes"],
    });
    if iiif.is_some() {
        entry["iiif"] = json!(ids);
    }
    Ok((json!({ "name": name, "terms": maps }), entry))
}

/// The base URI of `--iiif` without a trailing `/`; refused unless http:// or https://.
fn iiif_base(base: &str) -> Result<String> {
    let base = base.trim_end_matches('/');
    if !(base.starts_with("http://") || base.starts_with("https://")) {
        return Err(Error::parameter(
            "iiif",
            format!("'{base}': expected the http:// or https:// URI the tiles will be served at"),
        ));
    }
    Ok(base.to_string())
}

/// The fit `run --rti` makes beside the normals: `basis` over every reading of `capture`
/// (loaded with [`memory_beside`] in its plan), its coefficients into the float files of the
/// output folder `dir`, with its leave-one-out error and the Lambertian relighting of the
/// run's normals and albedo; returns the fit and its report entry (`report.json`'s `rti`).
pub fn fit_beside_run(
    capture: &Capture,
    basis: Basis,
    rec: &Reconstruction,
    dir: &Path,
) -> Result<(StoredFit, Value)> {
    let options = RtiOptions {
        basis,
        exclude_unreliable: false,
        ridge: None,
        memory_limit: None,
        iiif: None,
    };
    check_options(&capture.lights, &options)?;
    let t = Instant::now();
    let size = (capture.width, capture.height, capture.channels);
    let mut store = CoefficientFiles::create(dir, basis, size, &capture.pixels)?;
    let meta = fit_penalised_into(capture, basis, None, Penalty::Auto, &mut store)?;
    let fitted = store.finish(meta);
    let gain = fitted.meta().gain;
    let lambert = lambert_errors(capture, &rec.normals, &rec.albedo, gain, None)?;
    let mut entry = report(capture, fitted.meta(), &lambert, rec, &options);
    entry["timings_s"] = json!({ "fit": t.elapsed().as_secs_f64() });
    Ok((fitted, entry))
}

/// The ridge weight of `options` for a capture of `lights` lights.
fn penalty(options: &RtiOptions, lights: usize) -> Penalty {
    options.ridge.map_or(Penalty::Auto, |per_light| {
        Penalty::Fixed(per_light * lights as f64)
    })
}

/// Refuses what the fit cannot serve, before any image is read: near lights, rbf with a
/// per-pixel light mask or a ridge weight, a ridge weight that is not a finite number ≥ 0.
fn check_options(lights: &crate::model::lights::Lights, options: &RtiOptions) -> Result<()> {
    if let Some(r) = options.ridge {
        if options.basis == Basis::Rbf {
            return Err(Error::parameter(
                "ridge",
                "rbf interpolates principal components over the lights and has no ridge \
                 weight; give --ridge with ptm, ptm-rgb, hsh2 or hsh3",
            ));
        }
        if !(r.is_finite() && r >= 0.0) {
            return Err(Error::parameter(
                "ridge",
                format!("{r}: expected auto or a weight per light ≥ 0"),
            ));
        }
    }
    if options.basis == Basis::Rbf && options.exclude_unreliable {
        return Err(Error::parameter(
            "exclude_unreliable",
            "rbf projects every pixel's readings under all the lights on one set of principal \
             components and has no per-pixel light mask; use it without --exclude-unreliable, \
             or fit ptm or hsh",
        ));
    }
    if lights.near.is_some() {
        return Err(Error::invalid(
            "rti: this capture has near lights (light_positions.txt); RTI bases (PTM, HSH) \
             model the reflectance under distant lights, whose direction is the same at every \
             pixel, and photostereo does not fit them with per-pixel directions",
        ));
    }
    Ok(())
}

/// photostereo's own normals and albedo: the recursive method with `exclude_unreliable` (its
/// statuses make the light mask), else least squares over every light.
fn reference(
    capture: &Capture,
    options: &RtiOptions,
    progress: &dyn Progress,
) -> Result<Reconstruction> {
    let d = Params::default();
    let params = Params {
        method: if options.exclude_unreliable {
            Method::Recursive
        } else {
            Method::L2
        },
        detect: options.exclude_unreliable,
        integrate: false,
        memory_limit: options.memory_limit,
        ..d
    };
    reconstruct(capture, &params, progress)
}

/// The readings the reconstruction left out (any status but USED), read from its statuses in
/// place.
impl ReadingMask for crate::method::statusmap::StatusMap {
    fn readings(&self) -> usize {
        self.n_pixels() * self.lights
    }
    fn excluded(&self, p: usize, k: usize, _n: usize) -> bool {
        self.code(p, k) != status::USED
    }
}

/// Per-light and mean figures of a relighting error.
fn errors_json(e: &RelightErrors) -> Value {
    let n = e.sse.len();
    json!({
        "mean_rmse_8bit": e.mean_rmse_8bit(),
        "mean_relative": e.mean_relative(),
        "rmse_8bit": (0..n).map(|k| e.rmse_8bit(k)).collect::<Vec<_>>(),
        "relative": (0..n).map(|k| e.relative(k)).collect::<Vec<_>>(),
        "readings": e.count.clone(),
    })
}

fn report(
    capture: &Capture,
    fitted: &RtiFit,
    lambert: &RelightErrors,
    rec: &Reconstruction,
    options: &RtiOptions,
) -> Value {
    let ranges: Vec<[f32; 2]> = fitted
        .coefficient_ranges()
        .into_iter()
        .map(|(a, b)| [a, b])
        .collect();
    let rbf = fitted.rbf.as_ref().map(|m| {
        json!({
            "sigma": m.sigma,
            "interpolant": m.interpolant.name(),
            "lambda": m.interpolant.lambda().filter(|l| l.is_finite()),
            "ridge_per_light": match m.interpolant {
                crate::solve::rti::rbf::Interpolant::Smooth { ridge, .. } => Some(ridge / capture.n_lights() as f64),
                crate::solve::rti::rbf::Interpolant::Kernel => None,
            },
            "gaussian_width": match m.interpolant {
                crate::solve::rti::rbf::Interpolant::Smooth { width, .. } => Some(width),
                crate::solve::rti::rbf::Interpolant::Kernel => None,
            },
            "render_positions": m.lights.len(),
            "components": crate::solve::rti::rbf::components(capture.n_lights(), capture.channels),
            "sigma_default": fitted.kernel.as_ref().map(|k| k.default),
            "sample_pixels": fitted.kernel.as_ref().map(|k| k.sample_pixels),
            "ridge_candidates": fitted.kernel.as_ref().map(|k| {
                k.ridge_candidates.iter().map(|&(per_light, loo)| json!({
                    "ridge_per_light": per_light,
                    "loo_mean_rmse_8bit": loo,
                })).collect::<Vec<_>>()
            }),
            "candidates": fitted.kernel.as_ref().map(|k| {
                k.candidates.iter().map(|c| json!({
                    "sigma": c.sigma,
                    "interpolant": c.interpolant.name(),
                    "lambda": c.interpolant.lambda().filter(|l| l.is_finite()),
                    "loo_mean_rmse_8bit": c.loo.is_finite().then_some(c.loo),
                })).collect::<Vec<_>>()
            }),
            "planes": options.basis.terms(),
            "explained_variance": m.explained_variance,
            "pca_pixels": m.pca_pixels,
        })
    });
    let per_light = |lambda: f64| lambda / capture.n_lights().max(1) as f64;
    let listed = |candidates: &[(f64, f64)]| {
        candidates
            .iter()
            .map(|&(lambda, loo)| json!({ "lambda": lambda, "loo_mean_rmse_8bit": loo }))
            .collect::<Vec<_>>()
    };
    let ridge = fitted.ridge.as_ref().map(|r| {
        let ptm_lambda = match r.prior {
            Prior::Zero => None,
            Prior::Ptm { ptm_lambda } => Some(ptm_lambda),
        };
        json!({
            "lambda": r.lambda,
            "lambda_per_light": per_light(r.lambda),
            "toward": if ptm_lambda.is_some() { "ptm" } else { "zero" },
            "ptm_lambda": ptm_lambda,
            "penalty": "toward zero: (AᵀA + λ D) c = Aᵀ y, D the Dirichlet energy of the basis \
                        over the light hemisphere (HSH l(l+1), PTM over the unit disk; constant \
                        free); toward ptm (HSH): λ · mean over the directions at least as high \
                        as the lowest light of (HSH(c) − PTM's ridge fit)²",
            "sample_pixels": r.sample_pixels,
            "candidates": listed(&r.candidates),
            "candidates_toward_ptm": listed(&r.toward_ptm),
        })
    });
    json!({
        "basis": options.basis.name(),
        "rbf": rbf,
        "ridge": ridge,
        "terms": options.basis.terms(),
        "input": {
            "width": capture.width,
            "height": capture.height,
            "channels": capture.channels,
            "lights": capture.n_lights(),
            "mask_pixels": capture.n_pixels(),
        },
        "display_gain": fitted.gain,
        "coefficient_ranges": ranges,
        "exclude_unreliable": options.exclude_unreliable,
        "excluded_readings": fitted.excluded_readings,
        "pixels_fitted_with_every_light": fitted.fell_back_to_all_lights,
        "leave_one_out": errors_json(&fitted.loo),
        "lambertian_reference": {
            "method": rec.report.method.clone(),
            "note": "photostereo's normals × albedo, I = ρ max(0, n·l), relit under every light \
                     over the readings the RTI fit used; its normals were fitted with those \
                     lights (not left out)",
            "errors": errors_json(lambert),
        },
    })
}
