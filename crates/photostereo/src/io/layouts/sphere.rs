//! The layouts of a mirror- or matte-sphere capture for calibration: a list file, a folder of
//! images (natural name order), or image paths; decoded into [`SphereImages`].

use crate::base::error::{Error, Result};
use crate::base::number::natural_cmp;
use crate::base::progress::Progress;
use crate::calibrate::SphereImages;
use crate::io::imageio::{read_image, read_mask};
use crate::model::image::Image;
use rayon::prelude::*;
use std::path::{Path, PathBuf};
/// Where the images of a sphere capture are, with an optional mask.
#[derive(Clone, Debug, Default)]
pub struct SphereFiles {
    /// The images, in light order.
    pub images: Vec<PathBuf>,
    /// The sphere's mask (non-zero = sphere), when the layout names one.
    pub mask: Option<PathBuf>,
    /// Remarks made while resolving the layout.
    pub notes: Vec<String>,
}

impl SphereFiles {
    /// Resolves a capture given as one list file (`.txt`: the image count, the image paths
    /// relative to the list's folder or, failing that, its parent, then an optional mask path),
    /// one folder (its images in natural name order, `filenames.txt` when present, and
    /// `mask.png` or a file named `*mask*` as the mask), or image paths.
    pub fn resolve(inputs: &[PathBuf]) -> Result<Self> {
        match inputs {
            [] => Err(Error::invalid("no sphere capture given")),
            [one] if one.is_dir() => Self::folder(one),
            [one]
                if one
                    .extension()
                    .and_then(|e| e.to_str())
                    .is_some_and(|e| e.eq_ignore_ascii_case("txt")) =>
            {
                Self::list_file(one)
            }
            many => {
                for p in many {
                    if !p.is_file() {
                        return Err(Error::file(p, "no such image file"));
                    }
                }
                Ok(SphereFiles {
                    images: many.to_vec(),
                    mask: None,
                    notes: Vec::new(),
                })
            }
        }
    }

    /// The list-file layout (see [`SphereFiles::resolve`] and [`crate::io::layouts::read_list_file`]).
    pub fn list_file(list: &Path) -> Result<Self> {
        let listed = crate::io::layouts::read_list_file(list)?;
        Ok(SphereFiles {
            images: listed.images,
            mask: listed.mask,
            notes: listed.notes,
        })
    }

    /// The folder layout (see [`SphereFiles::resolve`]).
    pub fn folder(dir: &Path) -> Result<Self> {
        let names = dir.join("filenames.txt");
        let mut mask = None;
        let images: Vec<PathBuf> = if names.exists() {
            let text = crate::io::limits::read_text(&names)?;
            text.lines()
                .map(str::trim)
                .filter(|l| !l.is_empty())
                .map(|l| dir.join(l))
                .collect()
        } else {
            let mut v = Vec::new();
            for e in std::fs::read_dir(dir).map_err(|e| Error::io(dir, e))? {
                let p = e.map_err(|e| Error::io(dir, e))?.path();
                let name = p
                    .file_name()
                    .and_then(|n| n.to_str())
                    .unwrap_or("")
                    .to_ascii_lowercase();
                let ext = p
                    .extension()
                    .and_then(|e| e.to_str())
                    .unwrap_or("")
                    .to_ascii_lowercase();
                if !matches!(ext.as_str(), "png" | "tif" | "tiff" | "exr") {
                    continue;
                }
                if name.contains("mask") {
                    mask = Some(p);
                } else if !name.starts_with("normal_gt") {
                    v.push(p);
                }
            }
            v.sort_by(|a, b| natural_cmp(&a.to_string_lossy(), &b.to_string_lossy()));
            v
        };
        let m = dir.join("mask.png");
        if m.exists() {
            mask = Some(m);
        }
        if images.is_empty() {
            return Err(Error::file(dir, "no image (PNG, TIFF, EXR) in the folder"));
        }
        Ok(SphereFiles {
            images,
            mask,
            notes: Vec::new(),
        })
    }

    /// Decodes the images (in parallel) and the mask. All images must share size and channels.
    pub fn load(&self, progress: &dyn Progress) -> Result<SphereImages> {
        progress.begin("loading", self.images.len() as u64);
        let images: Vec<Result<Image>> = self
            .images
            .par_iter()
            .map(|p| {
                let r = read_image(p);
                progress.advance(1);
                r
            })
            .collect();
        progress.end();
        let images: Vec<Image> = images.into_iter().collect::<Result<_>>()?;
        let first = &images[0];
        for (img, p) in images.iter().zip(&self.images) {
            if (img.width, img.height, img.channels) != (first.width, first.height, first.channels)
            {
                return Err(Error::file(
                    p,
                    format!(
                        "image is {}×{}×{} but {} is {}×{}×{}: all images must share size and channels",
                        img.width,
                        img.height,
                        img.channels,
                        self.images[0].display(),
                        first.width,
                        first.height,
                        first.channels
                    ),
                ));
            }
        }
        let mask = match &self.mask {
            Some(p) => {
                let (h, w, m) = read_mask(p)?;
                if (w, h) != (first.width, first.height) {
                    return Err(Error::file(
                        p,
                        format!(
                            "mask is {w}×{h} but the images are {}×{}",
                            first.width, first.height
                        ),
                    ));
                }
                Some(m)
            }
            None => None,
        };
        Ok(SphereImages {
            images,
            mask,
            mask_name: self.mask.as_ref().map(|p| p.display().to_string()),
        })
    }
}
