//! Capture folders written by RTI tools: an `.lp` light file (RTIBuilder, relight: a count
//! line, then `filename x y z` per image) or a relight `.dome` file (JSON: the dome's LED
//! directions or positions), with the images beside it (JPEG as often as not).
//!
//! RTI tools pair an `.lp` file's lines with the images by order only: the names it records
//! are often those of another machine or an earlier export (`C:\…\IMG_0001.JPG` beside
//! `img_0001.jpg`). The names are used when every one of them is found; otherwise line k is
//! paired with the k-th image of the folder in sorted order, and a note says so.
//!
//! The `.dome` file (relight's dome configuration, JSON; lengths in cm, x to the image's right,
//! y to its top, z up toward the camera, the origin at the centre of the imaged area) holds
//! `directions` (unit vectors toward the LEDs, `{"x", "y", "z"}` objects), `positionsSphere`
//! (the directions placed on a sphere of `domeDiameter` raised by `verticalOffset`) and
//! `positions3d` (measured positions), with `lightConfiguration` naming which applies
//! (`directional`, `spherical`, `lights3d`), and `ledAdjust` (per-LED `{"r", "g", "b"}` factors
//! that pixel values are multiplied by).
//!
//! LED positions are read as near point lights when the capture is seen through a known camera
//! (`K.txt` in the folder or given, and the distance D in mm from the camera to the imaged
//! plane, `mean_distance.txt` or given): the camera is taken to look straight down the dome's
//! z axis at its origin, so a position p (cm, dome frame) lies at 10·p − (0, 0, D) mm in the
//! camera frame of the near-light layout (CONVENTIONS.md: camera centre at the origin, x right,
//! y up, z toward the viewer), and the near-light model is solved with D as the object's mean
//! distance. Without a camera they are read as distant lights in the direction of the origin,
//! and a note states the largest angle by which that direction is off at the edge of the
//! imaged area (`imageWidth`). A dome that holds directions only stays distant when a camera
//! is given; the camera then serves the perspective integration, and a note says so.

use super::{folder_images, CaptureFiles};
use crate::base::error::{Error, Result};
use crate::io::layouts::near::{folder_camera, parse_lp, NearLayout};
use crate::model::lightmodel::Camera;
use crate::model::lights::Lights;
use std::path::{Path, PathBuf};

/// The capture files of an `.lp` file: its images (by name, else by sorted order, see the
/// module's comment) and distant directions.
pub fn lp_capture_files(path: &Path) -> Result<CaptureFiles> {
    let (listed, lights) = parse_lp(&crate::io::limits::read_text(path)?, path)?;
    let mut notes = vec![format!("lights and images from {}", path.display())];
    let images = match by_name(path, &listed) {
        Some(found) => found,
        None => {
            let (dir, images) = by_order(path, listed.len())?;
            let first = listed.iter().find(|p| !p.is_file()).unwrap_or(&listed[0]);
            notes.push(format!(
                "{} names images that are not beside it ({} the first): its {} lines are paired \
                 with the {} images of {} in sorted order, as RTI tools pair them (line 1 with {}, \
                 line {} with {})",
                path.display(),
                display_name(first),
                listed.len(),
                images.len(),
                dir.display(),
                display_name(&images[0]),
                images.len(),
                display_name(&images[images.len() - 1]),
            ));
            images
        }
    };
    Ok(CaptureFiles {
        images,
        lights,
        mask: None,
        notes,
        photometry: Default::default(),
    })
}

/// The listed images, each found by its file name (the part after the last `/` or `\`,
/// compared without case) in the `.lp` file's folder or the folders an RTI project keeps its
/// images in; `None` unless every one is found.
fn by_name(lp: &Path, listed: &[PathBuf]) -> Option<Vec<PathBuf>> {
    if listed.iter().all(|p| p.is_file()) {
        return Some(listed.to_vec());
    }
    for dir in image_folders(lp) {
        let Ok(files) = folder_images(&dir) else {
            continue;
        };
        let found: Option<Vec<PathBuf>> = listed
            .iter()
            .map(|p| {
                let name = base_name(p);
                files
                    .iter()
                    .find(|f| display_name(f).eq_ignore_ascii_case(&name))
                    .cloned()
            })
            .collect();
        if found.is_some() {
            return found;
        }
    }
    None
}

/// The folder (among [`image_folders`]) holding as many images as the `.lp` file has lines, and
/// those images in sorted order. An error names the file, its line count and each folder's
/// image count when none matches.
fn by_order(lp: &Path, lines: usize) -> Result<(PathBuf, Vec<PathBuf>)> {
    let mut seen = Vec::new();
    for dir in image_folders(lp) {
        let images = folder_images(&dir)?;
        if images.len() == lines {
            return Ok((dir, images));
        }
        seen.push(format!("{} in {}", images.len(), dir.display()));
    }
    Err(Error::file(
        lp,
        format!(
            "{lines} light line(s) name images that are not there, and no folder holds \
             {lines} images to pair them with by order (found {}): an .lp file needs one line \
             per image",
            seen.join(", ")
        ),
    ))
}

/// Where an RTI project keeps its images, relative to its light file: the file's own folder
/// (relight), then RTIBuilder's `jpeg-exports` beside the `assembly-files` folder, then the
/// parent folder.
fn image_folders(lp: &Path) -> Vec<PathBuf> {
    let dir = lp
        .parent()
        .filter(|d| !d.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let mut v = vec![dir.to_path_buf()];
    if let Some(parent) = dir.parent() {
        let parent = if parent.as_os_str().is_empty() {
            Path::new("..").to_path_buf()
        } else {
            parent.to_path_buf()
        };
        v.push(parent.join("jpeg-exports"));
        v.push(parent);
    }
    v.into_iter().filter(|d| d.is_dir()).collect()
}

/// A listed path's file name, whichever separator its machine used.
fn base_name(p: &Path) -> String {
    let s = p.to_string_lossy();
    s.rsplit(['/', '\\']).next().unwrap_or(&s).to_string()
}

fn display_name(p: &Path) -> String {
    p.file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| p.display().to_string())
}

/// The lights a relight `.dome` file describes, with notes (see the module's comment).
pub struct Dome {
    /// The distant lights (directions toward the LEDs from the origin).
    pub lights: Lights,
    /// The notes of the distant reading.
    pub notes: Vec<String>,
    /// The LED positions, cm, dome frame (x right, y up, z toward the camera, origin at the
    /// centre of the imaged area); `None` for a dome of directions only.
    pub positions: Option<Vec<[f64; 3]>>,
    /// Each LED's brightness relative to the others (the inverse of `ledAdjust`; 1 without it).
    pub brightness: Vec<[f64; 3]>,
}

/// Parses a `.dome` file's JSON text.
pub fn parse_dome(text: &str, path: &Path) -> Result<Dome> {
    let v: serde_json::Value = serde_json::from_str(text)
        .map_err(|e| Error::file(path, format!("not a relight .dome file (JSON): {e}")))?;
    let num = |key: &str| {
        v.get(key)
            .and_then(serde_json::Value::as_f64)
            .unwrap_or(0.0)
    };
    let config = v
        .get("lightConfiguration")
        .and_then(serde_json::Value::as_str)
        .unwrap_or("directional");
    let key = match config {
        "directional" => "directions",
        "spherical" => "positionsSphere",
        "lights3d" => "positions3d",
        other => {
            return Err(Error::file(
                path,
                format!(
                    "lightConfiguration '{}': expected directional, spherical or lights3d",
                    other.escape_debug()
                ),
            ))
        }
    };
    let mut points = vectors(&v, key, ["x", "y", "z"], path)?;
    let mut key = key;
    // A spherical dome saved before its positions were: they follow from the directions.
    if points.is_empty() && config == "spherical" {
        key = "directions";
        let r = num("domeDiameter") / 2.0;
        points = vectors_of(&v, key, path)?
            .into_iter()
            .map(|d| [d[0] * r, d[1] * r, d[2] * r + num("verticalOffset")])
            .collect();
    }
    if points.is_empty() {
        return Err(Error::file(
            path,
            format!("lightConfiguration {config} but no {key}: expected one {{\"x\", \"y\", \"z\"}} per LED"),
        ));
    }
    let mut notes = Vec::new();
    if key != "directions" {
        let half = num("imageWidth") / 2.0;
        let off = points
            .iter()
            .map(|p| {
                let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
                (half / r.max(1e-12)).atan().to_degrees()
            })
            .fold(0.0, f64::max);
        notes.push(format!(
            "{}: LED positions ({key}) read as distant lights toward the centre of the imaged \
             area{}",
            path.display(),
            if half > 0.0 {
                format!(
                    "; at the edge of its {} cm width the true direction differs by up to \
                     {off:.1}°",
                    2.0 * half
                )
            } else {
                String::new()
            }
        ));
    }
    for (k, p) in points.iter().enumerate() {
        if p[2] <= 0.0 {
            return Err(Error::file(
                path,
                format!(
                    "{key}[{k}] = {p:?}: an LED at or below the object's plane (z is up, toward \
                     the camera)"
                ),
            ));
        }
    }
    let mut lights = Lights::new(&points).map_err(|e| Error::file(path, e.to_string()))?;
    let mut brightness = vec![[1.0; 3]; points.len()];
    let adjust = vectors(&v, "ledAdjust", ["r", "g", "b"], path)?;
    if !adjust.is_empty() {
        if adjust.len() != points.len() {
            return Err(Error::file(
                path,
                format!(
                    "{} ledAdjust entries for {} LEDs: expected one per LED",
                    adjust.len(),
                    points.len()
                ),
            ));
        }
        // Pixel values are multiplied by ledAdjust: the LED's brightness is its inverse.
        let mut int = Vec::with_capacity(adjust.len());
        for (k, a) in adjust.iter().enumerate() {
            if !a.iter().all(|x| *x > 0.0 && x.is_finite()) {
                return Err(Error::file(
                    path,
                    format!("ledAdjust[{k}] = {a:?}: expected positive factors"),
                ));
            }
            int.push([1.0 / a[0], 1.0 / a[1], 1.0 / a[2]]);
        }
        lights = lights
            .with_intensities(int.clone())
            .map_err(|e| Error::file(path, e.to_string()))?;
        brightness = int;
    }
    Ok(Dome {
        lights,
        notes,
        positions: (key != "directions").then_some(points),
        brightness,
    })
}

fn vectors_of(v: &serde_json::Value, key: &str, path: &Path) -> Result<Vec<[f64; 3]>> {
    vectors(v, key, ["x", "y", "z"], path)
}

/// The array `key` of objects with the three numeric `fields` (empty when absent).
fn vectors(
    v: &serde_json::Value,
    key: &str,
    fields: [&str; 3],
    path: &Path,
) -> Result<Vec<[f64; 3]>> {
    let Some(arr) = v.get(key) else {
        return Ok(Vec::new());
    };
    let arr = arr
        .as_array()
        .ok_or_else(|| Error::file(path, format!("{key}: expected an array of objects")))?;
    arr.iter()
        .enumerate()
        .map(|(k, o)| {
            let mut out = [0.0; 3];
            for (slot, f) in out.iter_mut().zip(fields) {
                *slot = o
                    .get(f)
                    .and_then(serde_json::Value::as_f64)
                    .filter(|x| x.is_finite())
                    .ok_or_else(|| {
                        Error::file(
                            path,
                            format!("{key}[{k}]: expected a finite number \"{f}\""),
                        )
                    })?;
            }
            Ok(out)
        })
        .collect()
}

/// The capture files of a folder with a `.dome` file: the folder's images in sorted order,
/// one per LED; near lights when a camera is known (see the module's comment).
pub fn dome_capture_files(dome: &Path, dir: &Path) -> Result<CaptureFiles> {
    dome_capture_files_with(dome, dir, None, None)
}

/// [`dome_capture_files`] seen through `camera` (else the folder's `K.txt`) with the imaged
/// plane `distance` mm from the camera (else the folder's `mean_distance.txt`).
pub fn dome_capture_files_with(
    dome: &Path,
    dir: &Path,
    distance: Option<f64>,
    camera: Option<Camera>,
) -> Result<CaptureFiles> {
    let d = parse_dome(&crate::io::limits::read_text(dome)?, dome)?;
    let images = folder_images(dir)?;
    if images.len() != d.lights.len() {
        return Err(Error::file(
            dome,
            format!(
                "{} LEDs but {} images in {}: a dome capture needs one image per LED, in \
                 the LEDs' order when sorted by name",
                d.lights.len(),
                images.len(),
                dir.display()
            ),
        ));
    }
    let mut notes = vec![format!(
        "lights from {}, paired with the {} images of {} in sorted order",
        dome.display(),
        images.len(),
        dir.display()
    )];
    let lights = match (folder_camera(dir, distance, camera)?, d.positions) {
        (None, _) => {
            notes.extend(d.notes);
            d.lights
        }
        (Some((camera, plane)), Some(cm)) => {
            let layout = NearLayout {
                camera,
                positions: cm
                    .iter()
                    .map(|p| [10.0 * p[0], 10.0 * p[1], 10.0 * p[2] - plane])
                    .collect(),
                axes: None,
                anisotropy: None,
                intensities: d.brightness,
                distance: plane,
            };
            notes.push(format!(
                "near lights: {} LED positions of {} placed in the camera frame (the dome's \
                 origin on the optical axis, {plane} mm from the camera), fx {} fy {} cx {} cy {}",
                cm.len(),
                dome.display(),
                camera.fx,
                camera.fy,
                camera.cx,
                camera.cy
            ));
            layout.lights(dome)?
        }
        (Some((camera, plane)), None) => {
            notes.push(format!(
                "{} holds LED directions only: read as distant lights (near lights need LED \
                 positions, positionsSphere or positions3d); the camera serves the perspective \
                 integration, mean distance {plane} mm",
                dome.display()
            ));
            Lights {
                camera: Some((camera, plane)),
                ..d.lights
            }
        }
    };
    Ok(CaptureFiles {
        images,
        lights,
        mask: None,
        notes,
        photometry: super::folder_frames(dir)?,
    })
}

/// The light file of an RTI capture folder without `light_directions.txt`: the one `.lp` file
/// in it or in its `assembly-files` folder (RTIBuilder), else its one `.dome` file. `None`
/// when there is none; two of a kind are refused.
pub fn find_light_file(dir: &Path) -> Result<Option<PathBuf>> {
    for (sub, ext) in [(None, "lp"), (Some("assembly-files"), "lp"), (None, "dome")] {
        let d = sub.map_or(dir.to_path_buf(), |s| dir.join(s));
        let Ok(entries) = std::fs::read_dir(&d) else {
            continue;
        };
        let mut found: Vec<PathBuf> = entries
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| {
                p.is_file()
                    && p.extension()
                        .and_then(|e| e.to_str())
                        .is_some_and(|e| e.eq_ignore_ascii_case(ext))
            })
            .collect();
        found.sort();
        match found.len() {
            0 => continue,
            1 => return Ok(found.pop()),
            _ => {
                return Err(Error::file(
                    &d,
                    format!(
                        "{} .{ext} files ({}): give the one to use as the input",
                        found.len(),
                        found
                            .iter()
                            .map(|p| display_name(p))
                            .collect::<Vec<_>>()
                            .join(", ")
                    ),
                ))
            }
        }
    }
    Ok(None)
}
