//! Writing a run's output folder (CONVENTIONS.md, "The output folder of a run"). Files are
//! written into a staging folder beside the target, which is renamed into place by
//! [`OutputFolder::commit`]; dropping an uncommitted folder removes the staging folder, so an
//! interrupted or failed run never leaves half-written output behind.

use crate::error::{Error, Result};
use crate::imageio::{write_exr_rgb, write_png16};
use std::path::{Path, PathBuf};

/// A staging folder that becomes the output folder on [`commit`](OutputFolder::commit).
#[derive(Debug)]
pub struct OutputFolder {
    target: PathBuf,
    staging: PathBuf,
    force: bool,
    committed: bool,
}

impl OutputFolder {
    /// Prepares writing to `target`. Refuses an existing target unless `force`.
    pub fn create(target: &Path, force: bool) -> Result<Self> {
        if target.exists() && !force {
            return Err(Error::OutputExists {
                path: target.to_path_buf(),
            });
        }
        let name = target
            .file_name()
            .ok_or_else(|| Error::file(target, "not a valid output folder name"))?
            .to_string_lossy()
            .to_string();
        let parent = match target.parent() {
            Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
            _ => PathBuf::from("."),
        };
        if !parent.is_dir() {
            return Err(Error::file(
                &parent,
                "the output folder's parent does not exist",
            ));
        }
        let staging = parent.join(format!(".{name}.tmp-{}", std::process::id()));
        if staging.exists() {
            std::fs::remove_dir_all(&staging).map_err(|e| Error::io(&staging, e))?;
        }
        std::fs::create_dir(&staging).map_err(|e| Error::io(&staging, e))?;
        Ok(OutputFolder {
            target: target.to_path_buf(),
            staging,
            force,
            committed: false,
        })
    }

    /// Where files are written until commit.
    pub fn path(&self) -> &Path {
        &self.staging
    }

    /// The final folder.
    pub fn target(&self) -> &Path {
        &self.target
    }

    /// A file path inside the staging folder.
    pub fn file(&self, name: &str) -> PathBuf {
        self.staging.join(name)
    }

    /// Moves the staging folder into place, replacing an existing target when allowed.
    pub fn commit(mut self) -> Result<PathBuf> {
        if self.target.exists() {
            if !self.force {
                return Err(Error::OutputExists {
                    path: self.target.clone(),
                });
            }
            let old = self.staging.with_file_name(format!(
                ".{}.old-{}",
                self.target
                    .file_name()
                    .unwrap_or_default()
                    .to_string_lossy(),
                std::process::id()
            ));
            std::fs::rename(&self.target, &old).map_err(|e| Error::io(&self.target, e))?;
            std::fs::rename(&self.staging, &self.target).map_err(|e| Error::io(&self.target, e))?;
            let _ = if old.is_dir() {
                std::fs::remove_dir_all(&old)
            } else {
                std::fs::remove_file(&old)
            };
        } else {
            std::fs::rename(&self.staging, &self.target).map_err(|e| Error::io(&self.target, e))?;
        }
        self.committed = true;
        Ok(self.target.clone())
    }
}

impl Drop for OutputFolder {
    fn drop(&mut self) {
        if !self.committed {
            let _ = std::fs::remove_dir_all(&self.staging);
        }
    }
}

/// Writes `normals.npy` (float32 (H, W, 3)), `normals.png` (16-bit RGB, (n + 1) / 2 · 65535,
/// black outside the mask) and `normals.exr` into `dir`. `normals` is `height * width` row-major;
/// zero vectors mark pixels outside the mask.
pub fn write_normals(dir: &Path, width: usize, height: usize, normals: &[[f32; 3]]) -> Result<()> {
    let flat: Vec<f32> = normals.iter().flatten().copied().collect();
    write_npy_f32(&dir.join("normals.npy"), &[height, width, 3], &flat)?;
    let png: Vec<u16> = normals
        .iter()
        .flat_map(|n| {
            if *n == [0.0; 3] {
                [0u16; 3]
            } else {
                n.map(|v| (((v + 1.0) * 0.5).clamp(0.0, 1.0) * 65535.0).round() as u16)
            }
        })
        .collect();
    write_png16(&dir.join("normals.png"), width, height, 3, &png)?;
    write_exr_rgb(&dir.join("normals.exr"), width, height, &flat)
}

/// Writes `albedo.npy` (float32 (H, W, C)) and `albedo.png` (16-bit, scaled so that the 99.5th
/// percentile of the mask's values maps to white).
pub fn write_albedo(
    dir: &Path,
    width: usize,
    height: usize,
    channels: usize,
    albedo: &[f32],
    mask: &[bool],
) -> Result<()> {
    write_npy_f32(&dir.join("albedo.npy"), &[height, width, channels], albedo)?;
    let mut inside: Vec<f32> = albedo
        .chunks_exact(channels)
        .zip(mask)
        .filter(|(_, &m)| m)
        .flat_map(|(v, _)| v.iter().copied())
        .filter(|v| v.is_finite())
        .collect();
    let top = if inside.is_empty() {
        1.0
    } else {
        let k = ((inside.len() as f64 * 0.995) as usize).min(inside.len() - 1);
        let (_, v, _) = inside.select_nth_unstable_by(k, |a, b| a.total_cmp(b));
        if *v > 0.0 {
            *v
        } else {
            1.0
        }
    };
    let png: Vec<u16> = albedo
        .iter()
        .map(|v| ((v / top).clamp(0.0, 1.0) * 65535.0).round() as u16)
        .collect();
    write_png16(&dir.join("albedo.png"), width, height, channels, &png)
}

/// Writes a float32 `.npy` array of the given shape (C order).
pub fn write_npy_f32(path: &Path, shape: &[usize], data: &[f32]) -> Result<()> {
    let arr = ndarray::ArrayD::from_shape_vec(ndarray::IxDyn(shape), data.to_vec())
        .map_err(|e| Error::invalid(format!("array shape {shape:?}: {e}")))?;
    ndarray_npy::write_npy(path, &arr)
        .map_err(|e| Error::file(path, format!("writing .npy failed: {e}")))
}

/// Writes a uint8 `.npy` array of the given shape (C order).
pub fn write_npy_u8(path: &Path, shape: &[usize], data: &[u8]) -> Result<()> {
    let arr = ndarray::ArrayD::from_shape_vec(ndarray::IxDyn(shape), data.to_vec())
        .map_err(|e| Error::invalid(format!("array shape {shape:?}: {e}")))?;
    ndarray_npy::write_npy(path, &arr)
        .map_err(|e| Error::file(path, format!("writing .npy failed: {e}")))
}

/// Writes a bool `.npy` array of the given shape (C order).
pub fn write_npy_bool(path: &Path, shape: &[usize], data: &[bool]) -> Result<()> {
    let arr = ndarray::ArrayD::from_shape_vec(ndarray::IxDyn(shape), data.to_vec())
        .map_err(|e| Error::invalid(format!("array shape {shape:?}: {e}")))?;
    ndarray_npy::write_npy(path, &arr)
        .map_err(|e| Error::file(path, format!("writing .npy failed: {e}")))
}

/// Writes `value` as pretty JSON.
pub fn write_json<T: serde::Serialize>(path: &Path, value: &T) -> Result<()> {
    let text = serde_json::to_string_pretty(value)
        .map_err(|e| Error::invalid(format!("serialising {}: {e}", path.display())))?;
    std::fs::write(path, text + "\n").map_err(|e| Error::io(path, e))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn staging_is_removed_unless_committed_and_force_is_required() {
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("out");
        {
            let f = OutputFolder::create(&target, false).unwrap();
            std::fs::write(f.file("a.txt"), "x").unwrap();
        }
        assert!(!target.exists());
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
        let f = OutputFolder::create(&target, false).unwrap();
        std::fs::write(f.file("a.txt"), "x").unwrap();
        f.commit().unwrap();
        assert!(target.join("a.txt").exists());
        assert!(matches!(
            OutputFolder::create(&target, false),
            Err(Error::OutputExists { .. })
        ));
        let f = OutputFolder::create(&target, true).unwrap();
        std::fs::write(f.file("b.txt"), "y").unwrap();
        f.commit().unwrap();
        assert!(target.join("b.txt").exists() && !target.join("a.txt").exists());
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    }
}
