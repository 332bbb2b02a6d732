//! The 3D view's mesh: the depth map sampled every `stride` pixels (at most [`MESH_SIDE`] samples
//! along the longer side), in the frame of `mesh.ply` (x = col, y = −row, z = depth), with the
//! normal map's normal and the albedo (divided by the page's white) at each vertex. Triangles join
//! neighbouring samples as in `mesh.ply`: two per full 2×2 block, one when exactly three are valid.
//!
//! Written as `view/mesh.js`: `PSV.mesh("<vertices>,<triangles>,<stride>", base64(zlib(...)))`,
//! the payload being positions (3 × f32 per vertex), normals (3 × f32), albedo (3 × f32) and
//! triangle indices (3 × u32), little-endian, one block after the other.

use super::folder::RunFolder;
use super::pyramid::write_js_payload;
use crate::base::error::Result;
use std::path::Path;

/// Most samples along the longer side of the image.
pub const MESH_SIDE: usize = 512;

/// Summary of the written mesh.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MeshInfo {
    pub vertices: usize,
    pub triangles: usize,
    pub stride: usize,
}

/// Writes the mesh of `f` (which must have a depth map) to `path`.
pub fn write_mesh(path: &Path, f: &RunFolder, white: f32) -> Result<Option<(MeshInfo, u64)>> {
    let Some(depth) = &f.depth else {
        return Ok(None);
    };
    let (w, h) = (f.width, f.height);
    let stride = w.max(h).div_ceil(MESH_SIDE).max(1);
    let (gw, gh) = (w.div_ceil(stride), h.div_ceil(stride));
    let mut index = vec![u32::MAX; gw * gh];
    let (mut pos, mut nor, mut alb) = (Vec::new(), Vec::new(), Vec::new());
    let ch = f.albedo_channels;
    for gr in 0..gh {
        for gc in 0..gw {
            let (r, c) = (gr * stride, gc * stride);
            let i = r * w + c;
            let z = depth[i];
            if !z.is_finite() || !f.mask[i] {
                continue;
            }
            index[gr * gw + gc] = (pos.len() / 3) as u32;
            pos.extend_from_slice(&[c as f32, -(r as f32), z]);
            nor.extend_from_slice(&f.normals[i]);
            let a = &f.albedo[i * ch..i * ch + ch];
            for k in 0..3 {
                let v = a[if ch >= 3 { k } else { 0 }];
                alb.push(if v.is_finite() {
                    v.max(0.0) / white
                } else {
                    0.0
                });
            }
        }
    }
    let vertices = pos.len() / 3;
    if vertices == 0 {
        return Ok(None);
    }
    let mut tri: Vec<u32> = Vec::new();
    let none = u32::MAX;
    for gr in 0..gh.saturating_sub(1) {
        for gc in 0..gw.saturating_sub(1) {
            let i = gr * gw + gc;
            let (a, b, c, d) = (index[i], index[i + 1], index[i + gw], index[i + gw + 1]);
            match (a != none, b != none, c != none, d != none) {
                (true, true, true, true) => tri.extend_from_slice(&[a, c, b, b, c, d]),
                (true, true, true, false) => tri.extend_from_slice(&[a, c, b]),
                (true, true, false, true) => tri.extend_from_slice(&[a, d, b]),
                (true, false, true, true) => tri.extend_from_slice(&[a, c, d]),
                (false, true, true, true) => tri.extend_from_slice(&[b, c, d]),
                _ => {}
            }
        }
    }
    let mut bytes = Vec::with_capacity(vertices * 36 + tri.len() * 4);
    for v in pos.iter().chain(&nor).chain(&alb) {
        bytes.extend_from_slice(&v.to_le_bytes());
    }
    for t in &tri {
        bytes.extend_from_slice(&t.to_le_bytes());
    }
    let info = MeshInfo {
        vertices,
        triangles: tri.len() / 3,
        stride,
    };
    let key = format!("{},{},{}", info.vertices, info.triangles, info.stride);
    let size = write_js_payload(path, "mesh", &key, &bytes)?;
    Ok(Some((info, size)))
}
