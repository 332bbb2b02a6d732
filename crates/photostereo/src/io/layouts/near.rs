//! io for real rigs (CONVENTIONS.md, "Near lights and perspective cameras"): the near-light
//! layout (`K.txt`, `light_positions.txt`, `light_axes.txt`, `light_anisotropy.txt`,
//! `light_intensities.txt`, `mean_distance.txt` or `--distance`) and the parser of the `.lp`
//! light files of the RTI tools ([`crate::io::layouts::rti_folders`] pairs them with images). Every inconsistency is an error naming the file (and line) and what was
//! expected.

use crate::base::error::{param, param_set, Error, Result};
use crate::io::layouts::CaptureFiles;
use crate::io::light_files::{parse_intensity_rows, parse_rows};
use crate::model::lightmodel::{Camera, NearLights};
use crate::model::lights::Lights;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Whether `dir` holds a near-light capture (it has `light_positions.txt`).
pub fn is_near_layout(dir: &Path) -> bool {
    dir.join("light_positions.txt").is_file()
}

/// Parses `K.txt`: three rows `fx 0 cx / 0 fy cy / 0 0 1` (pixels). Refuses skew, a last row
/// other than `0 0 1` and a K that is not invertible (non-positive focal lengths).
pub fn parse_camera(text: &str, path: &Path) -> Result<Camera> {
    let rows = parse_rows(text, path, &[3], Some(3))?;
    if rows.len() != 3 {
        return Err(Error::file(
            path,
            format!(
                "{} row(s): expected the 3×3 intrinsics fx 0 cx / 0 fy cy / 0 0 1",
                rows.len()
            ),
        ));
    }
    let (l0, r0) = (&rows[0].0, &rows[0].1);
    let (l1, r1) = (&rows[1].0, &rows[1].1);
    let (l2, r2) = (&rows[2].0, &rows[2].1);
    if r2[0] != 0.0 || r2[1] != 0.0 || r2[2] != 1.0 {
        return Err(Error::parse(
            path,
            *l2,
            format!("last row {r2:?}: expected 0 0 1"),
        ));
    }
    if r0[1] != 0.0 {
        return Err(Error::parse(
            path,
            *l0,
            format!("skew {}: expected 0 (square pixels without skew)", r0[1]),
        ));
    }
    if r1[0] != 0.0 {
        return Err(Error::parse(
            path,
            *l1,
            format!("K[1][0] = {}: expected 0", r1[0]),
        ));
    }
    if !(r0[0] > 0.0 && r1[1] > 0.0) {
        return Err(Error::file(
            path,
            format!(
                "focal lengths fx = {}, fy = {}: K is not invertible (expected positive values in pixels)",
                r0[0], r1[1]
            ),
        ));
    }
    Camera::new(r0[0], r1[1], r0[2], r1[2]).map_err(|e| Error::file(path, e.to_string()))
}

/// Reads `K.txt` ([`parse_camera`]).
pub fn read_camera(path: &Path) -> Result<Camera> {
    parse_camera(&crate::io::limits::read_text(path)?, path)
}

/// Parses `mean_distance.txt`: one positive number, millimetres.
pub fn parse_distance(text: &str, path: &Path) -> Result<f64> {
    let rows = parse_rows(text, path, &[1], Some(1))?;
    match rows.as_slice() {
        [(line, v)] => {
            if v[0] > 0.0 {
                Ok(v[0])
            } else {
                Err(Error::parse(
                    path,
                    *line,
                    format!("distance {}: expected a positive distance in mm", v[0]),
                ))
            }
        }
        _ => Err(Error::file(
            path,
            format!(
                "{} value(s): expected one number, the object's mean distance in mm",
                rows.len()
            ),
        )),
    }
}

/// The rig of a near-light folder as its files state it.
#[derive(Clone, Debug, PartialEq)]
pub struct NearLayout {
    pub camera: Camera,
    /// LED positions, mm, camera frame.
    pub positions: Vec<[f64; 3]>,
    pub axes: Option<Vec<[f64; 3]>>,
    pub anisotropy: Option<Vec<f64>>,
    /// Radiance along each axis at 1 mm, RGB (1 when the file is absent).
    pub intensities: Vec<[f64; 3]>,
    /// The object's mean distance, mm.
    pub distance: f64,
}

/// Parses the near-light files from their texts (`None` = file absent); `names` are the paths
/// used in messages, in the order K, positions, axes, anisotropy, intensities, distance.
/// `distance` (the `--distance` flag) overrides the file; without both the scale is unknown.
#[allow(clippy::too_many_arguments)]
pub fn parse_near_layout(
    camera: Option<&str>,
    positions: &str,
    axes: Option<&str>,
    anisotropy: Option<&str>,
    intensities: Option<&str>,
    mean_distance: Option<&str>,
    distance: Option<f64>,
    names: [&Path; 6],
) -> Result<NearLayout> {
    let Some(camera) = camera else {
        return Err(Error::file(
            names[0],
            "missing: a near-light capture needs the camera intrinsics K.txt (fx 0 cx / 0 fy cy / 0 0 1)",
        ));
    };
    let camera = parse_camera(camera, names[0])?;
    let rows = parse_rows(positions, names[1], &[3], None)?;
    if rows.len() < 3 {
        return Err(Error::file(
            names[1],
            format!(
                "{} light position(s): expected at least three rows x y z in mm",
                rows.len()
            ),
        ));
    }
    let pos: Vec<[f64; 3]> = rows.iter().map(|(_, r)| [r[0], r[1], r[2]]).collect();
    let n = pos.len();
    let axes = match axes {
        Some(t) => {
            let rows = parse_rows(t, names[2], &[3], Some(n))?;
            if rows.len() != n {
                return Err(Error::file(
                    names[2],
                    format!(
                        "{} axes for {n} light positions: expected one per light",
                        rows.len()
                    ),
                ));
            }
            Some(rows.iter().map(|(_, r)| [r[0], r[1], r[2]]).collect())
        }
        None => None,
    };
    let anisotropy = match anisotropy {
        Some(t) => {
            let rows = parse_rows(t, names[3], &[1], Some(n))?;
            if rows.len() != n {
                return Err(Error::file(
                    names[3],
                    format!(
                        "{} anisotropy values for {n} light positions: expected one per light",
                        rows.len()
                    ),
                ));
            }
            for (line, r) in &rows {
                if r[0] < 0.0 {
                    return Err(Error::parse(
                        names[3],
                        *line,
                        format!("μ = {}: expected μ ≥ 0", r[0]),
                    ));
                }
            }
            Some(rows.iter().map(|(_, r)| r[0]).collect())
        }
        None => None,
    };
    let intensities = match intensities {
        Some(t) => {
            let rows = parse_intensity_rows(t, names[4], Some(n))?;
            if rows.len() != n {
                return Err(Error::file(
                    names[4],
                    format!(
                        "{} intensity rows for {n} light positions: expected one per light",
                        rows.len()
                    ),
                ));
            }
            rows
        }
        None => vec![[1.0; 3]; n],
    };
    let distance = match (distance, mean_distance) {
        (Some(d), _) => {
            if !(d.is_finite() && d > 0.0) {
                return Err(Error::parameter(
                    "distance",
                    format!("{d}: expected the object's mean distance in mm, positive"),
                ));
            }
            d
        }
        (None, Some(t)) => parse_distance(t, names[5])?,
        (None, None) => {
            return Err(Error::file(
                names[5],
                format!(
                    "missing: near lights need the object's mean distance in mm (this file or {}); without it the lights cannot be placed",
                    param_set("distance", "")
                ),
            ))
        }
    };
    Ok(NearLayout {
        camera,
        positions: pos,
        axes,
        anisotropy,
        intensities,
        distance,
    })
}

impl NearLayout {
    /// The capture's lights: the distant approximation at the object's centre (directions,
    /// and intensities E_k times the brightness there, by which the images are divided) with the
    /// near model attached. Errors name `positions` (the light file) and the light.
    pub fn lights(&self, positions: &Path) -> Result<Lights> {
        let model = NearLights::new(
            self.camera,
            self.positions.clone(),
            self.axes.clone(),
            self.anisotropy.clone(),
            self.distance,
        )
        .map_err(|e| match e {
            // A parameter at fault (the distance) is named as the front end spells it.
            Error::Parameter { .. } => e,
            other => Error::file(positions, other.to_string()),
        })?;
        let centre = model.centre_brightness().to_vec();
        let lights = Lights::new(&model.centre_directions())?.with_intensities(
            self.intensities
                .iter()
                .zip(&centre)
                .map(|(e, b)| [e[0] * b, e[1] * b, e[2] * b])
                .collect(),
        )?;
        Ok(Lights {
            near: Some(Arc::new(model)),
            ..lights
        })
    }
}

/// The lights of a capture given as arrays rather than files (the Python package's keywords,
/// named in errors): distant `directions`, or near `positions` (mm) with `camera` and
/// `distance`, optional `axes` and `anisotropy`; `intensities` are the lights' (the LEDs'
/// radiance along their axes at 1 mm). Distant lights with `camera` and `distance` are seen
/// through that camera (the depth in mm).
#[derive(Clone, Debug, Default)]
pub struct LightArrays {
    pub directions: Option<Vec<[f64; 3]>>,
    pub intensities: Option<Vec<[f64; 3]>>,
    pub positions: Option<Vec<[f64; 3]>>,
    pub camera: Option<Camera>,
    pub distance: Option<f64>,
    pub axes: Option<Vec<[f64; 3]>>,
    pub anisotropy: Option<Vec<f64>>,
}

impl LightArrays {
    /// The lights, or an error naming the parameter at fault.
    pub fn lights(self) -> Result<Lights> {
        use crate::base::error::{param, param_set};
        if let Some(d) = self.distance.filter(|d| !(d.is_finite() && *d > 0.0)) {
            return Err(Error::parameter(
                "distance",
                format!("{d}: expected the object's mean distance in mm, finite and positive"),
            ));
        }
        match (self.positions, self.directions) {
            (Some(_), Some(_)) => Err(Error::invalid(format!(
                "{} and {}: give directions (distant lights) or LED positions (near lights), not both",
                param("lights"),
                param("light_positions")
            ))),
            (Some(positions), None) => {
                let n = positions.len();
                let camera = self.camera.ok_or_else(|| {
                    Error::invalid(format!(
                        "{}: near lights need the camera intrinsics (a 3x3 K or a K.txt path)",
                        param("camera")
                    ))
                })?;
                let distance = self.distance.ok_or_else(|| {
                    Error::invalid(format!(
                        "{}: near lights need the object's mean distance in mm; without it the lights cannot be placed",
                        param("distance")
                    ))
                })?;
                for (name, len) in [
                    ("light_axes", self.axes.as_ref().map(Vec::len)),
                    ("light_anisotropy", self.anisotropy.as_ref().map(Vec::len)),
                    ("intensities", self.intensities.as_ref().map(Vec::len)),
                ] {
                    if let Some(len) = len.filter(|&l| l != n) {
                        return Err(Error::invalid(format!(
                            "{}: {len} values for {n} light positions: expected one per light",
                            param(name)
                        )));
                    }
                }
                let layout = NearLayout {
                    camera,
                    positions,
                    axes: self.axes,
                    anisotropy: self.anisotropy,
                    intensities: self.intensities.unwrap_or_else(|| vec![[1.0; 3]; n]),
                    distance,
                };
                layout.lights(Path::new("light_positions"))
            }
            (None, Some(directions)) => {
                if self.axes.is_some() || self.anisotropy.is_some() {
                    return Err(Error::invalid(format!(
                        "{} and {} describe near lights: they need {}",
                        param("light_axes"),
                        param("light_anisotropy"),
                        param("light_positions")
                    )));
                }
                if let Some(k) = directions.iter().position(|d| d.iter().any(|v| !v.is_finite())) {
                    return Err(Error::invalid(format!(
                        "{}: light {} has a non-finite direction {:?}",
                        param("lights"),
                        k + 1,
                        directions[k]
                    )));
                }
                let mut lights = Lights::new(&directions)?;
                if let Some(e) = self.intensities {
                    lights = lights.with_intensities(e)?;
                }
                lights.camera = match (self.camera, self.distance) {
                    (Some(c), Some(d)) => Some((c, d)),
                    (None, None) => None,
                    (Some(_), None) => {
                        return Err(Error::invalid(format!(
                            "{}: distant lights seen through a camera need {} (the object's mean distance in mm) too",
                            param("camera"),
                            param_set("distance", "")
                        )))
                    }
                    (None, Some(_)) => {
                        return Err(Error::invalid(format!(
                            "{}: needs {} (a 3x3 K or a K.txt path), or {} for near lights",
                            param("distance"),
                            param_set("camera", ""),
                            param_set("light_positions", "")
                        )))
                    }
                };
                Ok(lights)
            }
            (None, None) => Err(Error::invalid(format!(
                "{}: an image array needs (N, 3) light directions, or {} (N, 3) in mm with {} and {} for near lights",
                param("lights"),
                param("light_positions"),
                param("camera"),
                param("distance")
            ))),
        }
    }
}

/// [`read_near_layout`] with `camera` in place of `K.txt` (not read).
fn read_near_layout_with_camera(
    dir: &Path,
    distance: Option<f64>,
    camera: Camera,
    images: Option<usize>,
) -> Result<NearLayout> {
    let mut layout = read_near_layout_files(dir, distance, Some("1 0 0\n0 1 0\n0 0 1\n"), images)?;
    layout.camera = camera;
    Ok(layout)
}

/// Reads the near-light files of `dir` ([`parse_near_layout`]).
pub fn read_near_layout(dir: &Path, distance: Option<f64>) -> Result<NearLayout> {
    read_near_layout_files(dir, distance, None, None)
}

/// [`read_near_layout`]; `camera_text` replaces the content of `K.txt` when given. With the
/// capture's image count `images`, a `light_positions.txt` of another length is refused first,
/// so that the file at fault is named rather than the per-light files that agree with it.
fn read_near_layout_files(
    dir: &Path,
    distance: Option<f64>,
    camera_text: Option<&str>,
    images: Option<usize>,
) -> Result<NearLayout> {
    let names = [
        dir.join("K.txt"),
        dir.join("light_positions.txt"),
        dir.join("light_axes.txt"),
        dir.join("light_anisotropy.txt"),
        dir.join("light_intensities.txt"),
        dir.join("mean_distance.txt"),
    ];
    let read = |p: &Path| -> Result<Option<String>> {
        if p.is_file() {
            crate::io::limits::read_text(p).map(Some)
        } else {
            Ok(None)
        }
    };
    let positions = read(&names[1])?
        .ok_or_else(|| Error::file(&names[1], "missing: expected N rows x y z in mm"))?;
    if let Some(n) = images {
        let rows = parse_rows(&positions, &names[1], &[3], None)?.len();
        if rows != n {
            return Err(Error::file(
                &names[1],
                format!("{rows} light position(s) for {n} image(s): expected one light per image"),
            ));
        }
    }
    let k_text = match camera_text {
        Some(t) => Some(t.to_string()),
        None => read(&names[0])?,
    };
    parse_near_layout(
        k_text.as_deref(),
        &positions,
        read(&names[2])?.as_deref(),
        read(&names[3])?.as_deref(),
        read(&names[4])?.as_deref(),
        read(&names[5])?.as_deref(),
        distance,
        [
            &names[0], &names[1], &names[2], &names[3], &names[4], &names[5],
        ],
    )
}

/// A camera from its 3×3 intrinsics `k` (rows `fx 0 cx / 0 fy cy / 0 0 1`, pixels), checked as
/// [`parse_camera`] checks `K.txt`; errors name the parameter `camera`.
pub fn camera_from_matrix(k: [[f64; 3]; 3]) -> Result<Camera> {
    if k.iter().flatten().any(|v| !v.is_finite()) {
        return Err(Error::parameter(
            "camera",
            format!("{k:?}: expected finite values"),
        ));
    }
    if k[2] != [0.0, 0.0, 1.0] {
        return Err(Error::parameter(
            "camera",
            format!("last row {:?}: expected 0 0 1", k[2]),
        ));
    }
    if k[0][1] != 0.0 || k[1][0] != 0.0 {
        return Err(Error::parameter(
            "camera",
            format!(
                "K[0][1] = {}, K[1][0] = {}: expected 0 (square pixels without skew)",
                k[0][1], k[1][0]
            ),
        ));
    }
    if !(k[0][0] > 0.0 && k[1][1] > 0.0) {
        return Err(Error::parameter(
            "camera",
            format!(
                "focal lengths fx = {}, fy = {}: K is not invertible (expected positive values in pixels)",
                k[0][0], k[1][1]
            ),
        ));
    }
    Camera::new(k[0][0], k[1][1], k[0][2], k[1][2])
}

/// The capture files of a near-light folder: the DiLiGenT layout's images and mask with the
/// near lights (`light_directions.txt` is not read). `distance` overrides `mean_distance.txt`.
pub fn near_capture_files(dir: &Path, distance: Option<f64>) -> Result<CaptureFiles> {
    near_capture_files_with(dir, distance, None)
}

/// [`near_capture_files`] with `camera`, when given, in place of the folder's `K.txt` (which
/// may then be absent).
pub fn near_capture_files_with(
    dir: &Path,
    distance: Option<f64>,
    camera: Option<Camera>,
) -> Result<CaptureFiles> {
    let images = crate::io::layouts::folder_images(dir)?;
    let layout = match camera {
        None => read_near_layout_files(dir, distance, None, Some(images.len()))?,
        Some(camera) => read_near_layout_with_camera(dir, distance, camera, Some(images.len()))?,
    };
    let positions = dir.join("light_positions.txt");
    let lights = layout.lights(&positions)?;
    if images.len() != lights.len() {
        return Err(Error::file(
            &positions,
            format!(
                "{} light position(s) for {} image(s): expected one light per image",
                lights.len(),
                images.len()
            ),
        ));
    }
    let mask = dir.join("mask.png");
    Ok(CaptureFiles {
        images,
        lights,
        mask: mask.is_file().then_some(mask),
        notes: vec![format!(
            "near lights: {} LEDs, mean distance {} mm, fx {} fy {} cx {} cy {}",
            layout.positions.len(),
            layout.distance,
            layout.camera.fx,
            layout.camera.fy,
            layout.camera.cx,
            layout.camera.cy
        )],
        photometry: super::folder_frames(dir)?,
    })
}

/// Distant lights seen through a lens: when `dir` holds `K.txt` (and no LED positions),
/// attaches the camera and the mean distance (`distance`, else `mean_distance.txt`; refused
/// without either) to `files`, so that the depth is integrated through the camera in mm.
/// Without `K.txt`, `files` is returned unchanged (and `distance` refused).
pub fn attach_camera(
    files: CaptureFiles,
    dir: &Path,
    distance: Option<f64>,
) -> Result<CaptureFiles> {
    attach_camera_with(files, dir, distance, None)
}

/// [`attach_camera`] with `camera`, when given, in place of the folder's `K.txt` (which may
/// then be absent).
pub fn attach_camera_with(
    mut files: CaptureFiles,
    dir: &Path,
    distance: Option<f64>,
    camera: Option<Camera>,
) -> Result<CaptureFiles> {
    let Some((camera, d)) = folder_camera(dir, distance, camera)? else {
        return Ok(files);
    };
    files.lights.camera = Some((camera, d));
    files.notes.push(format!(
        "perspective camera for distant lights: fx {} fy {} cx {} cy {}, mean distance {d} mm",
        camera.fx, camera.fy, camera.cx, camera.cy
    ));
    Ok(files)
}

/// The camera a capture folder is seen through and the object's distance (mm): `camera`, else
/// the folder's `K.txt`; `distance`, else its `mean_distance.txt`. `None` without a camera
/// (and then `distance` is refused); a camera without a distance is refused, the file named.
pub fn folder_camera(
    dir: &Path,
    distance: Option<f64>,
    camera: Option<Camera>,
) -> Result<Option<(Camera, f64)>> {
    let k = dir.join("K.txt");
    if camera.is_none() && !k.is_file() {
        if distance.is_some() {
            return Err(Error::file(
                &k,
                format!(
                    "missing: {} needs a near-light capture (light_positions.txt) or a camera (K.txt)",
                    param("distance")
                ),
            ));
        }
        return Ok(None);
    }
    let camera = match camera {
        Some(c) => c,
        None => read_camera(&k)?,
    };
    let path = dir.join("mean_distance.txt");
    let d = match distance {
        Some(d) if d.is_finite() && d > 0.0 => d,
        Some(d) => {
            return Err(Error::parameter(
                "distance",
                format!("{d}: expected the object's mean distance in mm, positive"),
            ))
        }
        None if path.is_file() => parse_distance(&crate::io::limits::read_text(&path)?, &path)?,
        None => {
            return Err(Error::file(
                &path,
                format!(
                    "missing: a camera (K.txt) needs the object's mean distance in mm (this file or {}) to give the depth in mm",
                    param_set("distance", "")
                ),
            ))
        }
    };
    Ok(Some((camera, d)))
}

/// Parses an `.lp` light file of the RTI tools: a count line, then `filename x y z` per image
/// (distant directions; normalised). Image paths are relative to the file's folder.
pub fn parse_lp(text: &str, path: &Path) -> Result<(Vec<PathBuf>, Lights)> {
    let base = path.parent().unwrap_or(Path::new("."));
    let mut lines = text
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim().trim_start_matches('\u{feff}')))
        .filter(|(_, l)| !l.is_empty() && !l.starts_with('#'));
    let Some((count_line, count)) = lines.next() else {
        return Err(Error::file(
            path,
            "empty: expected a count line, then `filename x y z` per image",
        ));
    };
    let n: usize = count.parse().map_err(|_| {
        Error::parse(
            path,
            count_line,
            format!("'{}' is not an image count", count.escape_debug()),
        )
    })?;
    let mut images = Vec::new();
    let mut dirs = Vec::new();
    for (line, text) in lines {
        let mut tokens = text.split_whitespace();
        let name = tokens.next().unwrap_or("");
        let vals: Vec<&str> = tokens.collect();
        if vals.len() != 3 {
            return Err(Error::parse(
                path,
                line,
                format!(
                    "{} value(s) after the file name: expected `filename x y z`",
                    vals.len()
                ),
            ));
        }
        let mut d = [0.0; 3];
        for (o, v) in d.iter_mut().zip(&vals) {
            *o = v
                .parse::<f64>()
                .ok()
                .filter(|x| x.is_finite())
                .ok_or_else(|| {
                    Error::parse(
                        path,
                        line,
                        format!("'{}' is not a finite number", v.escape_debug()),
                    )
                })?;
        }
        if d.iter().all(|&x| x == 0.0) {
            return Err(Error::parse(path, line, "zero light direction"));
        }
        images.push(base.join(name));
        dirs.push(d);
    }
    if images.len() != n {
        return Err(Error::parse(
            path,
            count_line,
            format!("count {n} but {} image line(s) follow", images.len()),
        ));
    }
    let lights = Lights::new(&dirs).map_err(|e| Error::file(path, e.to_string()))?;
    Ok((images, lights))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn p(s: &str) -> PathBuf {
        PathBuf::from(s)
    }

    fn parse(k: &str, pos: &str, dist: Option<&str>) -> Result<NearLayout> {
        let names = [
            p("K.txt"),
            p("light_positions.txt"),
            p("a"),
            p("m"),
            p("i"),
            p("mean_distance.txt"),
        ];
        parse_near_layout(
            Some(k),
            pos,
            None,
            None,
            None,
            dist,
            None,
            [
                &names[0], &names[1], &names[2], &names[3], &names[4], &names[5],
            ],
        )
    }

    const K: &str = "768 0 127.5\n0 768 127.5\n0 0 1\n";
    const POS: &str = "75 0 0\n0 75 0\n-75 0 0\n0 -75 0\n";

    #[test]
    fn a_good_layout_reads_and_places_its_lights() {
        let l = parse(K, POS, Some("300\n")).unwrap();
        assert_eq!(l.distance, 300.0);
        let lights = l.lights(&p("light_positions.txt")).unwrap();
        let d = lights.directions[0];
        let expect = [75.0 / 309.23, 0.0, 300.0 / 309.23];
        for i in 0..3 {
            assert!((d[i] - expect[i]).abs() < 1e-4, "{d:?}");
        }
        // Intensities: the brightness at the centre, 1/r².
        assert!((lights.intensities[0][0] - 1.0 / (75.0f64 * 75.0 + 90000.0)).abs() < 1e-12);
    }

    #[test]
    fn every_inconsistency_names_its_file_and_line() {
        let e = parse(K, POS, None).unwrap_err().to_string();
        assert!(
            e.contains("mean_distance.txt") && e.contains("distance="),
            "{e}"
        );
        let e = parse(K, POS, Some("-3\n")).unwrap_err().to_string();
        assert!(
            e.contains("mean_distance.txt") && e.contains("line 1"),
            "{e}"
        );
        let e = parse("0 0 127.5\n0 768 127.5\n0 0 1\n", POS, Some("300"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("K.txt") && e.contains("not invertible"), "{e}");
        let e = parse("768 0 127.5\n0 768 127.5\n0 1 1\n", POS, Some("300"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("K.txt") && e.contains("line 3"), "{e}");
        let l = parse(K, "75 0 -400\n0 75 0\n-75 0 0\n", Some("300")).unwrap();
        let e = l.lights(&p("light_positions.txt")).unwrap_err().to_string();
        assert!(
            e.contains("light_positions.txt")
                && e.contains("light 1")
                && e.contains("behind the object"),
            "{e}"
        );
        let l = parse(K, "75 0 40\n0 75 0\n-75 0 0\n", Some("300")).unwrap();
        let e = l.lights(&p("light_positions.txt")).unwrap_err().to_string();
        assert!(e.contains("behind the camera"), "{e}");
        let e = parse(K, "75 0\n", Some("300")).unwrap_err().to_string();
        assert!(
            e.contains("light_positions.txt") && e.contains("line 1"),
            "{e}"
        );
    }

    #[test]
    fn lp_files_list_images_and_directions() {
        let (imgs, lights) = parse_lp(
            "3\na.png 0 0 1\nb.png 1 0 1\nc.png 0 1 1\n",
            Path::new("/x/f.lp"),
        )
        .unwrap();
        assert_eq!(imgs[1], p("/x/b.png"));
        assert!((lights.directions[1][0] - 0.5f64.sqrt()).abs() < 1e-12);
        let e = parse_lp("4\na.png 0 0 1\n", Path::new("f.lp"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("f.lp") && e.contains("line 1") && e.contains("count 4"),
            "{e}"
        );
        let e = parse_lp("1\na.png 0 0\n", Path::new("f.lp"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("line 2"), "{e}");
    }
}
