//! Reading a run's output folder (CONVENTIONS.md, "The output folder of a run") for the viewer.
//! Only `normals.npy` is required; every other map is optional and its layer is left out of the
//! page when missing.

use crate::base::error::{Error, Result};
use crate::io::groundtruth::read_normal_map;
use crate::io::imageio::read_mask;
use crate::solve::metrics::angular_error_deg;
use std::path::{Path, PathBuf};

/// The maps of one output folder, full frame, row-major.
#[derive(Clone, Debug)]
pub struct RunFolder {
    pub dir: PathBuf,
    pub width: usize,
    pub height: usize,
    /// Unit normals, (0, 0, 0) outside the mask.
    pub normals: Vec<[f32; 3]>,
    /// Pixels with a normal.
    pub mask: Vec<bool>,
    /// Albedo, `H·W·albedo_channels` (all ones when the folder has none).
    pub albedo: Vec<f32>,
    pub albedo_channels: usize,
    pub has_albedo: bool,
    /// Height toward the camera (NaN outside).
    pub depth: Option<Vec<f32>>,
    /// The non-Lambertian statistic.
    pub residual: Option<Vec<f32>>,
    /// `light_status.npy`: light count and `N·H·W` statuses.
    pub status: Option<(usize, Vec<u8>)>,
    /// `unreliable_mask.png`.
    pub unreliable: Option<Vec<bool>>,
    /// `highlight.png` (recursive method).
    pub highlight: Option<Vec<bool>>,
    /// `fewer_than_three.png` (recursive method).
    pub fewer_than_three: Option<Vec<bool>>,
    /// Angular error against ground truth, degrees (NaN where there is none).
    pub error_deg: Option<Vec<f32>>,
    /// Where the ground truth came from.
    pub ground_truth: Option<PathBuf>,
    /// The RTI fit written beside the maps (`rti.json`, by `run --rti` or `rti`).
    pub rti: Option<super::rti::RtiLayer>,
    /// `specular_strength.npy` and `roughness.npy` (`run --reflectance lobe|auto`), both or
    /// neither.
    pub gloss: Option<(Vec<f32>, Vec<f32>)>,
    /// `report.json`, when present and valid.
    pub report: Option<serde_json::Value>,
    /// Remarks for the user (maps skipped and why).
    pub notes: Vec<String>,
}

fn npy_err(path: &Path, e: impl std::fmt::Display) -> Error {
    Error::file(path, format!("reading .npy failed: {e}"))
}

fn read_bool_png(path: &Path, w: usize, h: usize, notes: &mut Vec<String>) -> Option<Vec<bool>> {
    if !path.is_file() {
        return None;
    }
    match read_mask(path) {
        Ok((hh, ww, m)) if (ww, hh) == (w, h) => Some(m),
        Ok((hh, ww, _)) => {
            notes.push(format!(
                "{}: {ww}×{hh}, expected {w}×{h}; skipped",
                path.display()
            ));
            None
        }
        Err(e) => {
            notes.push(format!("{e}; skipped"));
            None
        }
    }
}

/// `normals.npy` (H, W, 3): the width, height and unit normals ((0, 0, 0) where a normal is not
/// finite or has no length). The folder is not a run's without it.
fn read_normals(dir: &Path) -> Result<(usize, usize, Vec<[f32; 3]>)> {
    let np = dir.join("normals.npy");
    if !np.is_file() && dir.join(super::rti::MODEL_JSON).is_file() {
        return Err(Error::file(
            dir,
            "an output folder of `photostereo rti`: a relightable image without normals, which \
             the viewer's layers (and the RTI layer's enhancements) need; open the .ptm/.rti in \
             RTIViewer or relight/ in OpenLIME, or run `photostereo run CAPTURE --rti BASIS -o \
             OUT` and view OUT to see the RTI layer beside the normals",
        ));
    }
    if !np.is_file() {
        return Err(Error::file(
            dir,
            "not an output folder of `photostereo run`: normals.npy is missing",
        ));
    }
    let arr: ndarray::Array3<f32> = ndarray_npy::read_npy(&np).map_err(|e| npy_err(&np, e))?;
    let (height, width, c) = arr.dim();
    if c != 3 || width == 0 || height == 0 {
        return Err(Error::file(
            &np,
            format!("shape ({height}, {width}, {c}): expected (H, W, 3)"),
        ));
    }
    let normals: Vec<[f32; 3]> = arr
        .as_standard_layout()
        .as_slice()
        .expect("standard layout")
        .chunks_exact(3)
        .map(|v| {
            let n = [v[0], v[1], v[2]];
            let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
            if n.iter().all(|x| x.is_finite()) && len > 1e-6 {
                n.map(|x| x / len)
            } else {
                [0.0; 3]
            }
        })
        .collect();
    Ok((width, height, normals))
}

/// `albedo.npy` (H, W, 1 or 3): the values, channels and whether the folder has it (all ones,
/// with a note, when it does not).
fn read_albedo(
    dir: &Path,
    width: usize,
    height: usize,
    notes: &mut Vec<String>,
) -> Result<(Vec<f32>, usize, bool)> {
    let ap = dir.join("albedo.npy");
    if !ap.is_file() {
        notes.push("no albedo.npy: relighting with a uniform albedo".into());
        return Ok((vec![1.0; width * height], 1, false));
    }
    let a: ndarray::Array3<f32> = ndarray_npy::read_npy(&ap).map_err(|e| npy_err(&ap, e))?;
    let (h, w, ch) = a.dim();
    if (h, w) != (height, width) || !(ch == 1 || ch == 3) {
        return Err(Error::file(
            &ap,
            format!("shape ({h}, {w}, {ch}): expected ({height}, {width}, 1 or 3)"),
        ));
    }
    Ok((a.into_raw_vec_and_offset().0, ch, true))
}

/// The (H, W) map `name` of the folder, `None` when it has none.
fn read_map(dir: &Path, name: &str, width: usize, height: usize) -> Result<Option<Vec<f32>>> {
    let p = dir.join(name);
    if !p.is_file() {
        return Ok(None);
    }
    let a: ndarray::Array2<f32> = ndarray_npy::read_npy(&p).map_err(|e| npy_err(&p, e))?;
    if a.dim() != (height, width) {
        return Err(Error::file(
            &p,
            format!("shape {:?}: expected ({height}, {width})", a.dim()),
        ));
    }
    Ok(Some(a.as_standard_layout().iter().copied().collect()))
}

/// `light_status.npy` (N, H, W): the light count and the statuses, `None` when absent.
fn read_status(dir: &Path, width: usize, height: usize) -> Result<Option<(usize, Vec<u8>)>> {
    let sp = dir.join("light_status.npy");
    if !sp.is_file() {
        return Ok(None);
    }
    let a: ndarray::Array3<u8> = ndarray_npy::read_npy(&sp).map_err(|e| npy_err(&sp, e))?;
    let (n, h, w) = a.dim();
    if (h, w) != (height, width) {
        return Err(Error::file(
            &sp,
            format!("shape ({n}, {h}, {w}): expected (N, {height}, {width})"),
        ));
    }
    Ok(Some((n, a.as_standard_layout().iter().copied().collect())))
}

/// The ground truth `p` named in a run's report: as written, then (when relative) relative to
/// `dir` and to its parent; a note when none of these is a file.
fn find_ground_truth(dir: &Path, p: PathBuf, notes: &mut Vec<String>) -> Option<PathBuf> {
    let mut tries = vec![p.clone()];
    if p.is_relative() {
        tries.push(dir.join(&p));
        if let Some(parent) = dir.parent() {
            tries.push(parent.join(&p));
        }
    }
    let found = tries.into_iter().find(|t| t.is_file());
    if found.is_none() {
        notes.push(format!(
            "the ground truth named in report.json ({}) was not found; \
             no error layer (give the ground truth, `gt`)",
            p.display()
        ));
    }
    found
}

/// The angular error of `normals` against the ground truth in file `p`, degrees (NaN where
/// either has no normal); an error when the ground truth's size differs.
fn error_map(normals: &[[f32; 3]], p: &Path, width: usize, height: usize) -> Result<Vec<f32>> {
    let gt = read_normal_map(p)?;
    if (gt.width, gt.height) != (width, height) {
        return Err(Error::file(
            p,
            format!(
                "ground truth is {}×{}: expected {width}×{height}",
                gt.width, gt.height
            ),
        ));
    }
    Ok(normals
        .iter()
        .zip(&gt.normals)
        .map(|(n, g)| {
            if *n == [0.0; 3] || *g == [0.0; 3] {
                f32::NAN
            } else {
                angular_error_deg(*n, *g) as f32
            }
        })
        .collect())
}

impl RunFolder {
    /// Reads `dir`. `ground_truth` overrides the ground-truth file named in `report.json`
    /// (which is tried as written, then relative to `dir` and to its parent).
    pub fn read(dir: &Path, ground_truth: Option<&Path>) -> Result<RunFolder> {
        let (width, height, normals) = read_normals(dir)?;
        let mask: Vec<bool> = normals.iter().map(|n| *n != [0.0; 3]).collect();
        let mut notes = Vec::new();
        let (albedo, albedo_channels, has_albedo) = read_albedo(dir, width, height, &mut notes)?;
        let depth = read_map(dir, "depth.npy", width, height)?;
        let residual = read_map(dir, "residual.npy", width, height)?;
        let status = read_status(dir, width, height)?;
        let unreliable = read_bool_png(&dir.join("unreliable_mask.png"), width, height, &mut notes);
        let highlight = read_bool_png(&dir.join("highlight.png"), width, height, &mut notes);
        let fewer_than_three =
            read_bool_png(&dir.join("fewer_than_three.png"), width, height, &mut notes);

        let rti = super::rti::RtiLayer::read(dir, width, height)?;
        let gloss = match (
            read_map(dir, "specular_strength.npy", width, height)?,
            read_map(dir, "roughness.npy", width, height)?,
        ) {
            (Some(s), Some(r)) => Some((s, r)),
            (None, None) => None,
            _ => {
                notes.push(
                    "only one of specular_strength.npy and roughness.npy: no gloss layer".into(),
                );
                None
            }
        };
        let report: Option<serde_json::Value> = std::fs::read_to_string(dir.join("report.json"))
            .ok()
            .and_then(|t| serde_json::from_str(&t).ok());

        // Ground truth: given, or the one the run was scored against.
        let gt_path = match ground_truth {
            Some(p) => Some(p.to_path_buf()),
            None => report
                .as_ref()
                .and_then(|r| r["parameters"]["ground_truth"].as_str())
                .map(PathBuf::from)
                .and_then(|p| find_ground_truth(dir, p, &mut notes)),
        };
        let mut error_deg = None;
        let mut ground_truth_used = None;
        if let Some(p) = gt_path {
            error_deg = Some(error_map(&normals, &p, width, height)?);
            ground_truth_used = Some(p);
        }
        Ok(RunFolder {
            dir: dir.to_path_buf(),
            width,
            height,
            normals,
            mask,
            albedo,
            albedo_channels,
            has_albedo,
            depth,
            residual,
            status,
            unreliable,
            highlight,
            fewer_than_three,
            error_deg,
            ground_truth: ground_truth_used,
            rti,
            gloss,
            report,
            notes,
        })
    }

    /// Lights with a status other than "used" at pixel `i` (0 outside the mask or without
    /// `light_status.npy`).
    pub fn unusable_count(&self, i: usize) -> usize {
        match &self.status {
            Some((n, s)) if self.mask[i] => {
                let hw = self.width * self.height;
                (0..*n)
                    .filter(|k| !matches!(s[k * hw + i], 0 | 255))
                    .count()
            }
            _ => 0,
        }
    }
}
