//! The capture-loading flags of `run`, `rti` and `compare` that make the images linear: `--response`, `--ambient`,
//! `--dark`, `--flat`, `--ignore-exposure` (the library's [`Photometry`]; names and meanings from its
//! [`photometry::CAPTURE_OPTIONS`]).

use clap::Args;
use photostereo::io::layouts::CaptureFiles;
use photostereo::io::photometry::{self, Frames, Photometry, ResponseChoice};
use std::path::PathBuf;

#[derive(Args, Debug, Clone)]
pub struct PhotometryArgs {
    #[arg(long, value_parser = parse_response, help = photometry::RESPONSE_DOC)]
    pub response: Option<ResponseChoice>,
    #[arg(long, help = photometry::AMBIENT_DOC)]
    pub ambient: Option<PathBuf>,
    #[arg(long, help = photometry::DARK_DOC)]
    pub dark: Option<PathBuf>,
    #[arg(long, help = photometry::FLAT_DOC)]
    pub flat: Option<PathBuf>,
    #[arg(long, help = photometry::IGNORE_EXPOSURE_DOC)]
    pub ignore_exposure: bool,
}

fn parse_response(s: &str) -> Result<ResponseChoice, String> {
    s.parse()
        .map_err(|e: photostereo::Error| e.spelled(&crate::params::spell))
}

impl PhotometryArgs {
    /// Sets the capture's photometry from the flags; the folder's own ambient, dark and flat
    /// frames stay unless a flag replaces them.
    pub fn apply(&self, files: &mut CaptureFiles) -> anyhow::Result<()> {
        let frames = Frames {
            ambient: self.ambient.as_deref(),
            dark: self.dark.as_deref(),
            flat: self.flat.as_deref(),
        };
        let given = Photometry::from_options(None, frames, self.ignore_exposure)?;
        files.photometry = Photometry {
            response: self.response,
            ..given
        }
        .over(&files.photometry);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use clap::CommandFactory;

    /// Every capture-reading option of the library is a flag of `run`, `rti` and `compare`,
    /// with the library's meaning.
    #[test]
    fn the_flags_are_the_librarys_options() {
        let cmd = crate::Cli::command();
        for name in ["run", "rti", "compare"] {
            let sub = cmd.find_subcommand(name).unwrap();
            for o in photostereo::io::photometry::CAPTURE_OPTIONS {
                let long = o.name.replace('_', "-");
                let arg = sub
                    .get_arguments()
                    .find(|a| a.get_long() == Some(long.as_str()))
                    .unwrap_or_else(|| panic!("{name} has no --{long}"));
                assert_eq!(arg.get_help().unwrap().to_string(), o.doc);
            }
        }
    }
}
