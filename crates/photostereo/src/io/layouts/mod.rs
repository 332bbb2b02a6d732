//! Capture layouts on disk (CONVENTIONS.md, "Capture layouts"): where the images, lights and
//! mask of a capture are — the DiLiGenT folder, the list file, explicit image lists, the
//! near-light folder and `.lp` files ([`near`]), sphere captures for calibration ([`sphere`]) —
//! and their decoding, in parallel, into one [`Capture`](crate::model::capture::Capture) held whole or in tiles ([`load`]).

pub mod load;
pub use load::LoadOptions;
pub mod near;
mod photometric;
pub mod rti_folders;
pub mod sphere;

use crate::base::error::{param, param_set, Error, Result};
use crate::model::lights::Lights;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// Where a capture's files are: the images, their lights and an optional mask.
#[derive(Clone, Debug)]
pub struct CaptureFiles {
    /// Image files in light order.
    pub images: Vec<PathBuf>,
    /// Light directions (and intensities), one per image.
    pub lights: Lights,
    /// Optional mask image (non-zero = object).
    pub mask: Option<PathBuf>,
    /// Remarks made while resolving the layout.
    pub notes: Vec<String>,
    /// How the images are made linear (response, exposure, ambient frame): the layout's
    /// `ambient.*` file, the rest from the files unless set.
    pub photometry: crate::io::photometry::Photometry,
}

impl CaptureFiles {
    /// Every input layout, as the command line and the Python package take it: one folder
    /// (the DiLiGenT layout; `lights` replaces its directions, `intensities` its intensities),
    /// one `.txt` list file (with `lights`), or image files (with `lights`). `mask` replaces the
    /// layout's own mask.
    pub fn from_inputs(
        inputs: &[PathBuf],
        lights: Option<&Path>,
        intensities: Option<&Path>,
        mask: Option<&Path>,
    ) -> Result<Self> {
        let is_list = |p: &Path| {
            p.extension()
                .and_then(|e| e.to_str())
                .is_some_and(|e| e.eq_ignore_ascii_case("txt"))
        };
        let mut files = match inputs {
            [] => {
                return Err(Error::invalid(
                    "no input: expected a capture folder, a list file or image files",
                ))
            }
            // Near lights (CONVENTIONS.md): the folder's own LED positions, unless `lights`.
            [dir]
                if dir.is_dir()
                    && lights.is_none()
                    && crate::io::layouts::near::is_near_layout(dir) =>
            {
                if let Some(p) = intensities {
                    return Err(Error::file(
                        p,
                        format!(
                            "{} is a near-light capture: its LEDs' radiance is read from \
                             light_intensities.txt in that folder, so {} does not apply \
                             (edit that file instead)",
                            dir.display(),
                            param("intensities")
                        ),
                    ));
                }
                crate::io::layouts::near::near_capture_files(dir, None)?
            }
            [lp] if lp.extension().is_some_and(|e| e.eq_ignore_ascii_case("lp")) => {
                if let Some(l) = lights {
                    return Err(Error::file(
                        l,
                        format!(
                            "{} carries its own light directions, so {} does not apply \
                             (give one or the other)",
                            lp.display(),
                            param("lights")
                        ),
                    ));
                }
                let f = crate::io::layouts::rti_folders::lp_capture_files(lp)?;
                match intensities {
                    Some(p) => f.with_intensities_file(p)?,
                    None => f,
                }
            }
            [dome]
                if dome.is_file()
                    && dome
                        .extension()
                        .is_some_and(|e| e.eq_ignore_ascii_case("dome")) =>
            {
                let dir = dome.parent().unwrap_or(Path::new("."));
                rti_capture(dome, dir, lights, intensities, None)?
            }
            [dir]
                if dir.is_dir()
                    && lights.is_none()
                    && !dir.join("light_directions.txt").exists()
                    && crate::io::layouts::rti_folders::find_light_file(dir)?.is_some() =>
            {
                let found = crate::io::layouts::rti_folders::find_light_file(dir)?;
                let file = found.expect("checked by the guard");
                rti_capture(&file, dir, lights, intensities, None)?
            }
            [dir] if dir.is_dir() => {
                let mut f = CaptureFiles::diligent_with_lights(dir, lights)?;
                if intensities.is_none() && !dir.join("light_intensities.txt").exists() {
                    f.notes.push(format!(
                        "no light_intensities.txt in {}: every light is taken as equally bright; \
                         if the lights' brightness differs, the normals are biased (give the \
                         intensities in that file, or a file of them as `intensities`)",
                        dir.display()
                    ));
                }
                let f = crate::io::layouts::near::attach_camera(f, dir, None)?;
                match intensities {
                    Some(p) => f.with_intensities_file(p)?,
                    None => f,
                }
            }
            [list] if is_list(list) => {
                if !list.is_file() {
                    return Err(Error::file(list, "no such list file"));
                }
                let Some(l) = lights else {
                    return Err(Error::file(
                        list,
                        format!(
                            "a list file needs the light directions ({})",
                            param_set("lights", "")
                        ),
                    ));
                };
                let f = CaptureFiles::list_file(list, l)?;
                match intensities {
                    Some(p) => f.with_intensities_file(p)?,
                    None => f,
                }
            }
            [single] if !single.exists() => {
                return Err(Error::file(
                    single,
                    "no such file or folder (expected a capture folder, a list file or image files)",
                ));
            }
            images => {
                if let Some(dir) = images.iter().find(|p| p.is_dir()) {
                    return Err(Error::file(
                        dir,
                        "a folder among several inputs; give one DiLiGenT-layout folder, one list file, or image files",
                    ));
                }
                for p in images {
                    if !p.is_file() {
                        return Err(Error::file(p, "no such image file"));
                    }
                }
                let Some(l) = lights else {
                    return Err(Error::invalid(format!(
                        "image files given explicitly need the light directions ({}, one direction per image)",
                        param_set("lights", "")
                    )));
                };
                CaptureFiles::explicit(images.to_vec(), l, intensities, None)?
            }
        };
        if let Some(m) = mask {
            files.mask = Some(m.to_path_buf());
        }
        Ok(files)
    }

    /// [`CaptureFiles::from_inputs`] with the options of one capture folder seen through a
    /// camera: `distance` (the object's mean distance, mm) replaces its `mean_distance.txt` and
    /// `camera` its `K.txt`; on a folder of distant lights they add a camera, so that the depth
    /// is integrated through it in mm.
    pub fn from_inputs_with(
        inputs: &[PathBuf],
        lights: Option<&Path>,
        intensities: Option<&Path>,
        mask: Option<&Path>,
        distance: Option<f64>,
        camera: Option<crate::model::lightmodel::Camera>,
    ) -> Result<Self> {
        use crate::io::layouts::near::{
            attach_camera_with, is_near_layout, near_capture_files_with,
        };
        if distance.is_none() && camera.is_none() {
            return Self::from_inputs(inputs, lights, intensities, mask);
        }
        if let Some((file, dir)) = rti_light_file(inputs, lights)? {
            let mut files =
                rti_capture(&file, &dir, lights, intensities, Some((distance, camera)))?;
            if let Some(m) = mask {
                files.mask = Some(m.to_path_buf());
            }
            return Ok(files);
        }
        let dir = match inputs {
            [dir] if dir.is_dir() => dir,
            _ => {
                let given = match (distance, camera) {
                    (Some(_), None) => param("distance"),
                    (None, Some(_)) => param("camera"),
                    _ => format!("{} and {}", param("distance"), param("camera")),
                };
                return Err(Error::invalid(format!(
                    "{given}: apply to one capture folder holding light_positions.txt (near lights) or light_directions.txt (distant lights), or to a relight .dome or RTI .lp capture"
                )));
            }
        };
        let mut files = if is_near_layout(dir) {
            near_capture_files_with(dir, distance, camera)?
        } else {
            let mut f = Self::diligent_with_lights(dir, lights)?;
            if let Some(p) = intensities {
                f = f.with_intensities_file(p)?;
            }
            attach_camera_with(f, dir, distance, camera)?
        };
        if let Some(m) = mask {
            files.mask = Some(m.to_path_buf());
        }
        Ok(files)
    }

    /// The DiLiGenT layout: a folder with the images, `filenames.txt` (optional),
    /// `light_directions.txt`, `light_intensities.txt` (optional) and `mask.png` (optional).
    pub fn diligent(dir: &Path) -> Result<Self> {
        Self::diligent_with_lights(dir, None)
    }

    /// The DiLiGenT layout with the light directions read from `lights` instead of the folder's
    /// `light_directions.txt` (the folder's intensities are still used when present).
    pub fn diligent_with_lights(dir: &Path, lights: Option<&Path>) -> Result<Self> {
        if !dir.is_dir() {
            return Err(Error::file(
                dir,
                "not a folder (expected the DiLiGenT layout)",
            ));
        }
        let lights_path = lights
            .map(Path::to_path_buf)
            .unwrap_or_else(|| dir.join("light_directions.txt"));
        if !lights_path.exists() {
            return Err(Error::file(
                &lights_path,
                format!(
                    "missing: the DiLiGenT layout needs light_directions.txt (or pass {})",
                    param_set("lights", "")
                ),
            ));
        }
        let lights = crate::io::light_files::read_directions(&lights_path)?;
        let names = dir.join("filenames.txt");
        let images = folder_images(dir)?;
        let source = if names.exists() {
            format!("listed in {}", names.display())
        } else {
            format!("in {}", dir.display())
        };
        check_light_count(images.len(), &source, &lights, &lights_path)?;
        let intens = dir.join("light_intensities.txt");
        let lights = if intens.exists() {
            attach_intensities(lights, &intens, images.len(), &source)?
        } else {
            lights
        };
        let mask = dir.join("mask.png");
        let mut files = CaptureFiles {
            images,
            lights,
            mask: mask.exists().then_some(mask),
            notes: Vec::new(),
            photometry: folder_frames(dir)?,
        };
        files.note_renormalised();
        Ok(files)
    }

    /// The list-file layout: a text file with the image count, the image paths and the mask path
    /// (see [`read_list_file`]); lights from a separate file.
    pub fn list_file(list: &Path, lights_path: &Path) -> Result<Self> {
        let listed = read_list_file(list)?;
        let lights = crate::io::light_files::read_directions(lights_path)?;
        check_light_count(
            listed.images.len(),
            &format!("listed in {}", list.display()),
            &lights,
            lights_path,
        )?;
        let mut files = CaptureFiles {
            images: listed.images,
            lights,
            mask: listed.mask,
            notes: listed.notes,
            photometry: Default::default(),
        };
        files.note_renormalised();
        Ok(files)
    }

    /// Explicit image paths with a light file and optional intensities and mask.
    pub fn explicit(
        images: Vec<PathBuf>,
        lights_path: &Path,
        intensities: Option<&Path>,
        mask: Option<PathBuf>,
    ) -> Result<Self> {
        let mut lights = crate::io::light_files::read_directions(lights_path)?;
        let source = "given on the command line";
        check_light_count(images.len(), source, &lights, lights_path)?;
        if let Some(p) = intensities {
            lights = attach_intensities(lights, p, images.len(), source)?;
        }
        let mut files = CaptureFiles {
            images,
            lights,
            mask,
            notes: Vec::new(),
            photometry: Default::default(),
        };
        files.note_renormalised();
        Ok(files)
    }

    /// Replaces the lights' intensities with those of `path` (e.g. `--intensities`); the row
    /// count must match the images and lights, and a mismatch names the file and both counts.
    pub fn with_intensities_file(mut self, path: &Path) -> Result<Self> {
        self.lights = attach_intensities(self.lights, path, self.images.len(), "in the capture")?;
        Ok(self)
    }

    fn note_renormalised(&mut self) {
        if self.lights.renormalised > 0 {
            self.notes.push(format!(
                "{} light direction(s) were not unit length and were normalised",
                self.lights.renormalised
            ));
        }
    }

    /// The note a capture without a mask gets: its whole frame is taken as the object, which is
    /// rarely meant (background pixels get normals and join the integration).
    pub fn whole_frame_note(&self, width: usize, height: usize) -> Option<String> {
        self.mask.is_none().then(|| {
            format!(
                "no mask: the whole {width}×{height} frame is used as the object \
                 (no mask.png in the capture folder, no mask line in a list file, no mask given)"
            )
        })
    }
}

/// The image extensions a capture folder's images are found by (lower case; compared without
/// case): PNG, TIFF, OpenEXR, JPEG and camera RAW (DNG and the TIFF-based vendor formats of
/// [`crate::io::raw`]; RAF and CR3 are found to be refused with advice).
const IMAGE_EXTENSIONS: [&str; 15] = [
    "png", "tif", "tiff", "exr", "jpg", "jpeg", "dng", "cr2", "nef", "arw", "pef", "orf", "rw2",
    "raf", "cr3",
];

/// The RTI light file (`.lp` or `.dome`) that `inputs` name, and the folder of its images: the
/// file itself, or the one an RTI capture folder holds (without `light_directions.txt`,
/// `light_positions.txt` or `lights`). `None` for any other input.
fn rti_light_file(inputs: &[PathBuf], lights: Option<&Path>) -> Result<Option<(PathBuf, PathBuf)>> {
    let has_ext = |p: &Path, ext: &str| p.extension().is_some_and(|e| e.eq_ignore_ascii_case(ext));
    match inputs {
        [file] if file.is_file() && (has_ext(file, "dome") || has_ext(file, "lp")) => {
            let dir = file.parent().unwrap_or(Path::new("."));
            Ok(Some((file.clone(), dir.to_path_buf())))
        }
        [dir]
            if dir.is_dir()
                && lights.is_none()
                && !dir.join("light_directions.txt").exists()
                && !crate::io::layouts::near::is_near_layout(dir) =>
        {
            let found = crate::io::layouts::rti_folders::find_light_file(dir)?;
            Ok(found.map(|f| (f, dir.clone())))
        }
        _ => Ok(None),
    }
}

/// The capture of an RTI tool's light file (`.lp` or `.dome`) whose images lie in `dir`
/// (a `.dome` names none), with `intensities` replacing the file's own. `seen`, when given,
/// holds the `distance` (mm) and `camera` options: a dome's LED positions become near lights
/// through the camera (else `dir`'s `K.txt`), and an `.lp` file's distant lights are seen
/// through it.
fn rti_capture(
    file: &Path,
    dir: &Path,
    lights: Option<&Path>,
    intensities: Option<&Path>,
    seen: Option<(Option<f64>, Option<crate::model::lightmodel::Camera>)>,
) -> Result<CaptureFiles> {
    if let Some(l) = lights {
        return Err(Error::file(
            l,
            format!(
                "{} carries its own light directions, so {} does not apply (give one or the \
                 other)",
                file.display(),
                param("lights")
            ),
        ));
    }
    let is_lp = file
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("lp"));
    let (distance, camera) = seen.unwrap_or((None, None));
    let f = if is_lp {
        let f = crate::io::layouts::rti_folders::lp_capture_files(file)?;
        match seen {
            Some(_) => crate::io::layouts::near::attach_camera_with(f, dir, distance, camera)?,
            None => f,
        }
    } else {
        crate::io::layouts::rti_folders::dome_capture_files_with(file, dir, distance, camera)?
    };
    match intensities {
        Some(p) => f.with_intensities_file(p),
        None => Ok(f),
    }
}

/// A capture folder's calibration frames: `ambient.*` (the scene with every controlled light
/// off), `dark.*` (the lens capped) and `flat.*` (a uniform white target), each when present.
pub(crate) fn folder_frames(dir: &Path) -> Result<crate::io::photometry::Photometry> {
    Ok(crate::io::photometry::Photometry {
        ambient: named_frame(dir, "ambient")?,
        dark: named_frame(dir, "dark")?,
        flat: named_frame(dir, "flat")?,
        ..Default::default()
    })
}

/// A capture folder's frame `STEM.png`, `STEM.jpg`, … if it has one; two are refused.
fn named_frame(dir: &Path, stem: &str) -> Result<Option<PathBuf>> {
    let found: Vec<PathBuf> = IMAGE_EXTENSIONS
        .iter()
        .map(|e| dir.join(format!("{stem}.{e}")))
        .filter(|p| p.is_file())
        .collect();
    match found.as_slice() {
        [] => Ok(None),
        [one] => Ok(Some(one.clone())),
        [a, b, ..] => Err(Error::file(
            dir,
            format!(
                "two {stem} frames, {} and {}: keep one",
                a.display(),
                b.display()
            ),
        )),
    }
}

/// The images of a capture folder: the names listed in `filenames.txt` (one per line, blank
/// lines skipped) when it exists, else every PNG, JPEG, TIFF, OpenEXR or camera RAW file of the folder but
/// the mask, the ground truth and the calibration frames (`mask*`, `Normal_gt*`, `ambient.*`,
/// `dark.*`, `flat.*`),
/// sorted by name.
pub(crate) fn folder_images(dir: &Path) -> Result<Vec<PathBuf>> {
    let names = dir.join("filenames.txt");
    if names.is_file() {
        return Ok(crate::io::limits::read_text(&names)?
            .lines()
            .map(str::trim)
            .filter(|l| !l.is_empty())
            .map(|l| dir.join(l))
            .collect());
    }
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|e| Error::io(dir, e))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            let name = p.file_name().and_then(|n| n.to_str()).unwrap_or("");
            let ext = p
                .extension()
                .and_then(|e| e.to_str())
                .unwrap_or("")
                .to_ascii_lowercase();
            IMAGE_EXTENSIONS.contains(&ext.as_str())
                && !name.starts_with("mask")
                && !name.starts_with("ambient.")
                && !name.starts_with("dark.")
                && !name.starts_with("flat.")
                && !name.starts_with("Normal_gt")
        })
        .collect();
    v.sort();
    Ok(v)
}

/// The images and mask named by a list file (CONVENTIONS.md, layout 2).
#[derive(Clone, Debug)]
pub struct ListFile {
    pub images: Vec<PathBuf>,
    pub mask: Option<PathBuf>,
    /// How the paths were resolved, when it matters.
    pub notes: Vec<String>,
}

/// Reads a list file: a first line with the image count, then one image path per line, then an
/// optional mask path; blank lines and `#` comments are skipped. Paths are taken relative to the
/// list file's folder and, failing that, to its parent (the shared `psmImages` lists name
/// `psmImages/<object>/<file>`); a note says when the parent was used.
pub fn read_list_file(list: &Path) -> Result<ListFile> {
    parse_list_file(&crate::io::limits::read_text(list)?, list)
}

/// [`read_list_file`] on text already read from `list` (paths still resolve against its
/// folder and that folder's parent).
pub fn parse_list_file(text: &str, list: &Path) -> Result<ListFile> {
    let lines: Vec<(usize, &str)> = text
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim()))
        .filter(|(_, l)| !l.is_empty() && !l.starts_with('#'))
        .collect();
    let (first_line, first) = *lines
        .first()
        .ok_or_else(|| Error::file(list, "empty list file"))?;
    let count: usize = first.parse().map_err(|_| {
        Error::parse(
            list,
            first_line,
            format!("'{first}': expected the image count"),
        )
    })?;
    if lines.len() - 1 < count {
        return Err(Error::file(
            list,
            format!(
                "the count line (line {first_line}) announces {count} images but {} path(s) follow",
                lines.len() - 1
            ),
        ));
    }
    if lines.len() - 1 > count.saturating_add(1) {
        return Err(Error::file(
            list,
            format!(
                "the count line (line {first_line}) announces {count} images but {} path(s) follow \
                 (expected the {count} images and at most a mask)",
                lines.len() - 1
            ),
        ));
    }
    if lines.len() - 1 == count {
        // No mask line: a last "image" named like a mask means the count line counts the mask
        // as a photograph (or a photograph is missing).
        let (line, last) = lines[count];
        let name = Path::new(last)
            .file_name()
            .map(|n| n.to_string_lossy().to_ascii_lowercase())
            .unwrap_or_default();
        if name.contains("mask") {
            return Err(Error::file(
                list,
                format!(
                    "the count line (line {first_line}) announces {count} images, but image path \
                     {count}, '{last}' (line {line}), names a mask: {} photograph(s) and a mask \
                     follow; write {} on the count line, or add the missing photograph",
                    count - 1,
                    count - 1
                ),
            ));
        }
    }
    let base = match list.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let parent = match base.parent() {
        Some(p) if !p.as_os_str().is_empty() && base != Path::new(".") => p.to_path_buf(),
        _ => base.join(".."),
    };
    let bases = [base, parent];
    let mut used_parent = false;
    let mut resolve = |line: usize, rel: &str, what: &str| -> Result<PathBuf> {
        for (i, b) in bases.iter().enumerate() {
            let p = b.join(rel);
            if p.exists() {
                used_parent |= i == 1;
                return Ok(p);
            }
        }
        Err(Error::parse(
            list,
            line,
            format!("{what} '{rel}' not found relative to the list file's folder or its parent"),
        ))
    };
    let mut images = Vec::with_capacity(count);
    for (line, rel) in &lines[1..=count] {
        images.push(resolve(*line, rel, "image")?);
    }
    let mask = match lines.get(count + 1) {
        Some((line, rel)) => Some(resolve(*line, rel, "mask")?),
        None => None,
    };
    let mut notes = Vec::new();
    if used_parent {
        notes.push(format!(
            "paths in {} resolved relative to its parent folder",
            list.display()
        ));
    }
    Ok(ListFile {
        images,
        mask,
        notes,
    })
}

/// Refuses a light file whose row count differs from the image count, naming the file, where
/// the images come from (`source`) and both numbers.
fn check_light_count(images: usize, source: &str, lights: &Lights, path: &Path) -> Result<()> {
    if images != lights.len() {
        return Err(Error::file(
            path,
            format!(
                "{} light direction(s) for {images} image(s) {source}: expected one light per image",
                lights.len()
            ),
        ));
    }
    Ok(())
}

/// Reads an intensity file and attaches it, naming the file and the counts on a mismatch.
fn attach_intensities(lights: Lights, path: &Path, images: usize, source: &str) -> Result<Lights> {
    let rows = crate::io::light_files::read_intensity_rows(path, Some(lights.len()))?;
    if rows.len() != lights.len() {
        return Err(Error::file(
            path,
            format!(
                "{} intensity row(s) for {} light direction(s) and {images} image(s) {source}: expected one row per light",
                rows.len(),
                lights.len()
            ),
        ));
    }
    lights.with_intensities(rows)
}

/// Refuses a capture that lists the same image file more than once (after resolving links):
/// each light needs its own image.
pub fn check_sources(sources: &[PathBuf]) -> Result<()> {
    let mut seen: std::collections::HashMap<PathBuf, Vec<usize>> = HashMap::new();
    for (k, p) in sources.iter().enumerate() {
        let key = std::fs::canonicalize(p).unwrap_or_else(|_| p.clone());
        seen.entry(key).or_default().push(k);
    }
    let mut dups: Vec<(&PathBuf, &Vec<usize>)> = seen.iter().filter(|(_, v)| v.len() > 1).collect();
    dups.sort_by_key(|(_, v)| v[0]);
    if let Some((_, ks)) = dups.first() {
        let path = &sources[ks[0]];
        return Err(Error::file(
            path,
            format!(
                "the same image file is listed {} times (images {}){}: each light needs its own image",
                ks.len(),
                crate::solve::plausibility::list(ks.iter().map(|k| k + 1)),
                if dups.len() > 1 {
                    format!(", and {} other file(s) are repeated too", dups.len() - 1)
                } else {
                    String::new()
                }
            ),
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn repeated_files_are_refused() {
        let sources = ["a.png", "b.png", "a.png", "c.png"].map(PathBuf::from);
        let e = check_sources(&sources).unwrap_err().to_string();
        assert!(
            e.contains("a.png") && e.contains("listed 2 times") && e.contains("images 1, 3"),
            "{e}"
        );
        check_sources(&sources[..2]).unwrap();
    }
}
