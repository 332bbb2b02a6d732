//! Reading normal maps that follow the conventions: `.npy` (H, W, 3) float, DiLiGenT's
//! `Normal_gt.mat`, or a normal-map image (16-bit PNG encoded as (n + 1) / 2 · 65535; 8-bit and
//! float images are accepted too, floats taken as the components themselves).

use crate::error::{Error, Result};
use crate::imageio::read_image;
use std::path::Path;

/// A normal map: `height * width` vectors, row-major; (0, 0, 0) marks pixels without data.
#[derive(Clone, Debug, PartialEq)]
pub struct NormalMap {
    pub width: usize,
    pub height: usize,
    pub normals: Vec<[f32; 3]>,
}

/// Reads a normal map by its extension (`.npy`, `.mat`, or an image).
pub fn read_normal_map(path: &Path) -> Result<NormalMap> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase();
    match ext.as_str() {
        "npy" => read_npy(path),
        "mat" => read_mat_normals(path),
        _ => read_image_normals(path),
    }
}

fn read_npy(path: &Path) -> Result<NormalMap> {
    let arr: ndarray::Array3<f32> = match ndarray_npy::read_npy::<_, ndarray::Array3<f32>>(path) {
        Ok(a) => a,
        Err(_) => {
            let a: ndarray::Array3<f64> = ndarray_npy::read_npy(path).map_err(|e| {
                Error::file(
                    path,
                    format!("expected a float32 or float64 array of shape (H, W, 3): {e}"),
                )
            })?;
            a.mapv(|v| v as f32)
        }
    };
    let (h, w, c) = arr.dim();
    if c != 3 {
        return Err(Error::file(
            path,
            format!("shape ({h}, {w}, {c}): expected (H, W, 3)"),
        ));
    }
    let normals = arr
        .as_standard_layout()
        .as_slice()
        .expect("standard layout")
        .chunks_exact(3)
        .map(|v| clean([v[0], v[1], v[2]]))
        .collect();
    Ok(NormalMap {
        width: w,
        height: h,
        normals,
    })
}

fn read_mat_normals(path: &Path) -> Result<NormalMap> {
    let a = crate::matfile::read_mat(path, Some("Normal_gt"))
        .or_else(|_| crate::matfile::read_mat(path, None))?;
    if a.dims.len() != 3 || a.dims[2] != 3 {
        return Err(Error::file(
            path,
            format!(
                "variable '{}' has dimensions {:?}: expected (H, W, 3)",
                a.name, a.dims
            ),
        ));
    }
    let (h, w) = (a.dims[0], a.dims[1]);
    let mut normals = vec![[0f32; 3]; h * w];
    for r in 0..h {
        for c in 0..w {
            let at = |k: usize| a.data[r + h * (c + w * k)] as f32;
            normals[r * w + c] = clean([at(0), at(1), at(2)]);
        }
    }
    Ok(NormalMap {
        width: w,
        height: h,
        normals,
    })
}

fn read_image_normals(path: &Path) -> Result<NormalMap> {
    let img = read_image(path)?;
    if img.channels != 3 {
        return Err(Error::file(path, "a normal-map image must be RGB"));
    }
    let float = img.bit_depth == 32;
    let normals = img
        .data
        .chunks_exact(3)
        .map(|v| {
            if float {
                clean([v[0], v[1], v[2]])
            } else if v.iter().all(|&x| x == 0.0) {
                [0.0; 3]
            } else {
                clean([v[0] * 2.0 - 1.0, v[1] * 2.0 - 1.0, v[2] * 2.0 - 1.0])
            }
        })
        .collect();
    Ok(NormalMap {
        width: img.width,
        height: img.height,
        normals,
    })
}

/// Non-finite vectors become (0, 0, 0), i.e. "no data".
fn clean(v: [f32; 3]) -> [f32; 3] {
    if v.iter().all(|x| x.is_finite()) {
        v
    } else {
        [0.0; 3]
    }
}
