//! The result viewer: `photostereo view FOLDER` turns a run's output folder into a page,
//! `FOLDER/index.html`, that relights the normals and albedo, shows every map as a layer with a
//! legend, turns the mesh in 3D and probes pixels — WebGL2, no network, opened straight from the
//! file system. The maps travel beside it in `FOLDER/view/` as a tiled pyramid ([`pyramid`]) of
//! small JavaScript files, so that an 8000 × 6000 result opens at its reduced level first and
//! loads only the tiles on screen.
//!
//! - [`relight`](mod@relight): the relighting model, the expression the page's shader evaluates.
//! - [`folder`]: reading an output folder.
//! - [`pyramid`], [`mesh`]: the files the page loads.
//! - [`page`]: the page itself (HTML, JavaScript and GLSL from `assets/`).
//! - [`openlime`]: what OpenLIME's BRDF layer reads.
//!
//! The page's state lives in its URL fragment (`#layer=relight&light=x,y,z&probe=row,col…`), so
//! a view can be shared, and in the `<pre id="ps-state">` element as JSON, which tests read.

pub mod folder;
pub mod mesh;
pub mod openlime;
pub mod page;
pub mod pyramid;
pub mod relight;
pub mod rti;

pub use folder::RunFolder;
pub use relight::{albedo_white, relight, RelightParams};

use crate::base::error::{Error, Result};
use serde_json::{json, Value};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Options of [`write_view`].
#[derive(Clone, Debug)]
pub struct ViewOptions {
    /// Ground-truth normals for the error layer (default: the file named in `report.json`).
    pub ground_truth: Option<PathBuf>,
    /// Light directions, one per light of `light_status.npy` (shown in the probe and usable as
    /// relighting presets).
    pub lights: Option<Vec<[f64; 3]>>,
    /// Upper end of the error layer's colour bar, degrees.
    pub error_max_deg: f32,
    /// The page's title (default: the folder's name).
    pub title: Option<String>,
}

impl Default for ViewOptions {
    fn default() -> Self {
        ViewOptions {
            ground_truth: None,
            lights: None,
            error_max_deg: 45.0,
            title: None,
        }
    }
}

/// What [`write_view`] wrote.
#[derive(Clone, Debug, serde::Serialize)]
pub struct ViewSummary {
    pub index: PathBuf,
    pub width: usize,
    pub height: usize,
    pub levels: usize,
    pub files: usize,
    pub bytes: u64,
    pub layers: Vec<String>,
    pub seconds: f64,
    pub notes: Vec<String>,
}

/// What the staging step wrote: pyramid levels, tile groups, mesh, file count and bytes.
struct Written {
    levels: Vec<Value>,
    groups: Vec<char>,
    mesh: Option<mesh::MeshInfo>,
    files: usize,
    bytes: u64,
    /// Per RTI plane, its least value and span ([`pyramid::Level::rti_ranges`]).
    rti_ranges: Vec<(f32, f32)>,
}

/// The manifest's layers, in the page's order.
fn layers_of(f: &RunFolder, mesh: bool) -> Vec<&'static str> {
    let mut v = vec!["relight", "normals"];
    if f.rti.is_some() {
        v.push("rti");
    }
    if f.has_albedo {
        v.push("albedo");
    }
    if f.depth.is_some() {
        v.push("depth");
    }
    if f.residual.is_some() || f.unreliable.is_some() {
        v.push("unreliable");
    }
    if f.status.is_some() {
        v.push("count");
        v.push("status");
    }
    if f.error_deg.is_some() {
        v.push("error");
    }
    if f.gloss.is_some() {
        v.push("gloss");
    }
    if mesh {
        v.push("mesh");
    }
    v
}

fn finite_max(v: impl Iterator<Item = f32>) -> Option<f32> {
    v.filter(|x| x.is_finite()).fold(None, |m, x| {
        Some(match m {
            Some(m) if m >= x => m,
            _ => x,
        })
    })
}

/// Writes `dir/index.html` and `dir/view/` for the output folder `dir`, replacing an earlier
/// view (and nothing else). The new files are written beside and renamed into place.
pub fn write_view(dir: &Path, options: &ViewOptions) -> Result<ViewSummary> {
    let start = Instant::now();
    let f = RunFolder::read(dir, options.ground_truth.as_deref())?;
    write_view_of(&f, options, start)
}

/// [`write_view`] for an output folder already read: the maps' scales, the tiled pyramid and
/// the mesh staged beside the view, the manifest and page, then the swap into place.
pub fn write_view_of(f: &RunFolder, options: &ViewOptions, start: Instant) -> Result<ViewSummary> {
    let dir = &f.dir;
    let mut notes = f.notes.clone();
    let n_lights = f.status.as_ref().map(|(n, _)| *n);
    let lights = match (&options.lights, n_lights) {
        (Some(l), Some(n)) if l.len() != n => {
            return Err(Error::invalid(format!(
                "{} light directions given but light_status.npy has {n} lights",
                l.len()
            )))
        }
        (Some(l), _) => Some(l.clone()),
        _ => None,
    };
    let scales = MapScales::of(f);
    // Stage everything in view.tmp-PID, then swap it in.
    let staging = dir.join(format!(".view.tmp-{}", std::process::id()));
    if staging.exists() {
        std::fs::remove_dir_all(&staging).map_err(|e| Error::io(&staging, e))?;
    }
    let tiles_dir = staging.join("tiles");
    std::fs::create_dir_all(&tiles_dir).map_err(|e| Error::io(&tiles_dir, e))?;
    let written = match write_staged(f, &staging, &scales) {
        Ok(v) => v,
        Err(e) => {
            let _ = std::fs::remove_dir_all(&staging);
            return Err(e);
        }
    };
    let layers = layers_of(f, written.mesh.is_some());
    let manifest = manifest(
        f,
        options,
        &scales,
        &written,
        &layers,
        lights.as_deref(),
        &notes,
    );
    let html = page::render(&manifest)?;
    let index = swap_in(dir, &staging, &html)?;
    if lights.is_none() && n_lights.is_some() {
        notes.push(
            "light directions unknown (give the light directions, `lights`): the probe lists lights by number only"
                .into(),
        );
    }
    Ok(ViewSummary {
        index,
        width: f.width,
        height: f.height,
        levels: written.levels.len(),
        files: written.files + 1,
        bytes: written.bytes + html.len() as u64,
        layers: layers.iter().map(|s| s.to_string()).collect(),
        seconds: start.elapsed().as_secs_f64(),
        notes,
    })
}

/// The scales of the maps the page shows: the albedo's white and largest value (mask pixels),
/// the depth range, the largest residual.
struct MapScales {
    white: f32,
    albedo_max: f32,
    depth_range: Option<(f32, f32)>,
    residual_max: Option<f32>,
}

impl MapScales {
    fn of(f: &RunFolder) -> Self {
        let white = albedo_white(&f.albedo, f.albedo_channels, &f.mask);
        let albedo_max = finite_max(
            f.albedo
                .chunks_exact(f.albedo_channels)
                .zip(&f.mask)
                .filter(|(_, &m)| m)
                .flat_map(|(a, _)| a.iter().copied()),
        )
        .filter(|&m| m > 0.0)
        .unwrap_or(1.0);
        let depth_range = f.depth.as_deref().and_then(pyramid::depth_range);
        let residual_max = f
            .residual
            .as_ref()
            .and_then(|r| finite_max(r.iter().zip(&f.mask).filter(|(_, &m)| m).map(|(v, _)| *v)));
        MapScales {
            white,
            albedo_max,
            depth_range,
            residual_max,
        }
    }
}

/// Writes the view's files into `staging` (whose `tiles` folder exists): the tiled pyramid of
/// every map group, level by level down to a single tile, and the mesh.
fn write_staged(f: &RunFolder, staging: &Path, scales: &MapScales) -> Result<Written> {
    let tiles_dir = staging.join("tiles");
    let mut level = pyramid::Level::base(f, scales.depth_range);
    let rti_ranges = level.rti_ranges.clone();
    let mut groups = vec!['n', 'a', 'q'];
    if level.depth_rgb.is_some() {
        groups.push('d');
    }
    if level.r.is_some() {
        groups.push('r');
    }
    if level.status.is_some() {
        groups.push('s');
    }
    if level.rti.is_some() {
        groups.push('c');
        groups.push('u');
    }
    if level.gloss.is_some() {
        groups.push('g');
    }
    let (mut files, mut bytes) = (0usize, 0u64);
    let mut levels = Vec::new();
    for l in 0.. {
        let (nf, nb) = pyramid::write_level(&tiles_dir, l, &level, &groups, scales.albedo_max)?;
        files += nf;
        bytes += nb;
        levels.push(json!({
            "width": level.width, "height": level.height,
            "cols": level.cols(), "rows": level.rows(),
        }));
        if level.width <= pyramid::TILE && level.height <= pyramid::TILE {
            break;
        }
        level = level.reduce();
    }
    let mesh = match mesh::write_mesh(&staging.join("mesh.js"), f, scales.white)? {
        Some((info, size)) => {
            files += 1;
            bytes += size;
            Some(info)
        }
        None => None,
    };
    Ok(Written {
        levels,
        groups,
        mesh,
        files,
        bytes,
        rti_ranges,
    })
}

/// The page's manifest: size, pyramid, layers, the maps' scales, lights, error, mesh, the
/// run's report summary, the relighting defaults and the notes.
fn manifest(
    f: &RunFolder,
    options: &ViewOptions,
    scales: &MapScales,
    written: &Written,
    layers: &[&str],
    lights: Option<&[[f64; 3]]>,
    notes: &[String],
) -> Value {
    let n_lights = f.status.as_ref().map(|(n, _)| *n);
    let title = options.title.clone().unwrap_or_else(|| {
        std::fs::canonicalize(&f.dir)
            .ok()
            .and_then(|p| p.file_name().map(|n| n.to_string_lossy().to_string()))
            .unwrap_or_else(|| "photostereo".into())
    });
    let report = f.report.clone().unwrap_or(Value::Null);
    json!({
        "format": "photostereo-view 1",
        "title": title,
        "width": f.width,
        "height": f.height,
        "tile": pyramid::TILE,
        "levels": written.levels,
        "groups": written.groups.iter().map(|g| g.to_string()).collect::<Vec<_>>(),
        "layers": layers,
        "albedo": {
            "present": f.has_albedo,
            "channels": f.albedo_channels,
            "max": scales.albedo_max,
            "white": scales.white,
        },
        "depth": scales.depth_range.map(|(lo, hi)| json!({
            "min": lo, "max": hi,
            "unit": if report["parameters"]["perspective"].as_bool() == Some(true) { "mm" } else { "px" },
        })),
        "residual": scales.residual_max.map(|m| json!({ "max": m })),
        "lights": n_lights.map(|n| json!({
            "count": n,
            "planes": n.div_ceil(4),
            "directions": lights,
        })),
        "error": f.error_deg.as_ref().map(|_| json!({
            "max_deg": options.error_max_deg,
            "ground_truth": f.ground_truth.as_ref().map(|p| p.display().to_string()),
            "stats": report.get("error").cloned().unwrap_or(Value::Null),
        })),
        "mesh": written.mesh.as_ref().map(|m| json!({
            "vertices": m.vertices, "triangles": m.triangles, "stride": m.stride,
        })),
        "report": {
            "method": report.get("method").cloned().unwrap_or(Value::Null),
            "input": report.get("input").cloned().unwrap_or(Value::Null),
            "timings_s": report.get("timings_s").cloned().unwrap_or(Value::Null),
        },
        "defaults": {
            "light": relight::DEFAULT_LIGHT,
            "shininess": RelightParams::default().shininess,
        },
        "rti": f.rti.as_ref().map(|l| rti_manifest(l, &written.rti_ranges)),
        "gloss": f.gloss.as_ref().map(|(s, r)| {
            let top = |v: &[f32]| {
                finite_max(v.iter().zip(&f.mask).filter(|(_, &m)| m).map(|(x, _)| *x))
                    .filter(|&m| m > 0.0)
                    .unwrap_or(1.0)
            };
            json!({ "strength_max": top(s), "roughness_max": top(r) })
        }),
        "notes": notes,
    })
}

/// What the page needs to relight an RTI fit: the basis, the planes' layout and code ranges,
/// and for RBF its model (σ, lights, mean and components as `basis.npy` holds them).
fn rti_manifest(l: &rti::RtiLayer, ranges: &[(f32, f32)]) -> Value {
    json!({
        "basis": l.basis.name(),
        "terms": l.basis.terms(),
        "fitted_channels": l.fitted_channels,
        "coefficient_planes": l.coefficient_planes,
        "chroma": l.chroma,
        "planes": l.planes(),
        "lo": ranges.iter().map(|r| r.0).collect::<Vec<_>>(),
        "span": ranges.iter().map(|r| r.1).collect::<Vec<_>>(),
        "rbf": l.rbf.as_ref().map(|m| json!({
            "sigma": m.sigma,
            "lights": m.lights,
            "channels": m.channels,
            "mean": m.mean,
            "planes": m.planes,
            "min_weight": crate::solve::rti::rbf::MIN_WEIGHT,
        })),
    })
}

/// Swaps the staged view in: the old view folder goes, the new one takes its place, then
/// index.html (written beside and renamed). Returns the index's path.
fn swap_in(dir: &Path, staging: &Path, html: &str) -> Result<PathBuf> {
    let target = dir.join("view");
    if target.exists() {
        let old = dir.join(format!(".view.old-{}", std::process::id()));
        std::fs::rename(&target, &old).map_err(|e| Error::io(&target, e))?;
        let _ = std::fs::remove_dir_all(&old);
    }
    std::fs::rename(staging, &target).map_err(|e| Error::io(&target, e))?;
    let index = dir.join("index.html");
    let tmp = dir.join(format!(".index.html.tmp-{}", std::process::id()));
    std::fs::write(&tmp, html).map_err(|e| Error::io(&tmp, e))?;
    std::fs::rename(&tmp, &index).map_err(|e| Error::io(&index, e))?;
    Ok(index)
}
