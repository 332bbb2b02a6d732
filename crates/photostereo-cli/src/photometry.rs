//! The capture-loading flags of `run` that make the images linear: `--response`, `--ambient`,
//! `--ignore-exposure` (the library's [`Photometry`]).

use clap::Args;
use photostereo::io::layouts::CaptureFiles;
use photostereo::io::photometry::{Photometry, ResponseChoice};
use std::path::PathBuf;

#[derive(Args, Debug, Clone)]
pub struct PhotometryArgs {
    /// How the images' values map to light: linear, srgb, gamma:G (linear = value^G) or auto
    /// (estimated from the capture: under the right response the readings of a matte surface
    /// lie in a 3-D subspace). Default: each file's own (sRGB for JPEG and for PNG/TIFF that
    /// say so, a PNG's gAMA, an ICC profile; linear for 16-bit and float data without colour
    /// metadata; 8-bit data without any is read as linear and checked).
    #[arg(long, value_parser = parse_response)]
    pub response: Option<ResponseChoice>,
    /// A frame with every controlled light off, subtracted from every image in linear light;
    /// replaces the capture folder's ambient.* file.
    #[arg(long)]
    pub ambient: Option<PathBuf>,
    /// Use the readings as they are when the images' exposures (EXIF time, ISO, aperture)
    /// differ, instead of dividing each by its exposure.
    #[arg(long)]
    pub ignore_exposure: bool,
}

fn parse_response(s: &str) -> Result<ResponseChoice, String> {
    s.parse().map_err(|e: photostereo::Error| e.to_string())
}

impl PhotometryArgs {
    /// Sets the capture's photometry from the flags; the folder's own ambient frame stays
    /// unless --ambient replaces it.
    pub fn apply(&self, files: &mut CaptureFiles) -> anyhow::Result<()> {
        if let Some(a) = &self.ambient {
            if !a.is_file() {
                anyhow::bail!(
                    "--ambient {}: no such image file (expected a frame taken with every \
                     controlled light off)",
                    a.display()
                );
            }
        }
        files.photometry = Photometry {
            response: self.response,
            ambient: self
                .ambient
                .clone()
                .or_else(|| files.photometry.ambient.clone()),
            ignore_exposure: self.ignore_exposure,
        };
        Ok(())
    }
}
