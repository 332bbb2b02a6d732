//! Export for OpenLIME's BRDF layer (`type: 'brdf'`): its `kd` (diffuse colour) and `normals`
//! channels as 8-bit PNG images, the layer's configuration and a minimal page.
//!
//! OpenLIME's conventions, as its BRDF shader reads them:
//! - normals: RGB = (n + 1) / 2 · 255, 8 bits, in a frame with **x to the right, y up** (the
//!   light's y grows toward the top of the screen, like the normal map's green channel) and z
//!   toward the viewer — photostereo's camera frame, so no axis is flipped. A pixel whose decoded
//!   vector is shorter than 0.5 is "no normal" and drawn transparent: outside the mask the map
//!   holds (128, 128, 128).
//! - kd: the albedo divided by the viewer's white (the 99.5th percentile inside the mask),
//!   clamped to 1 and sRGB-encoded; the configuration says `colorspaces.kd = "sRGB"` so that
//!   OpenLIME linearises it. Black outside the mask.
//! - layout `image`: one image per channel, row 0 at the top.

use super::folder::RunFolder;
use super::relight::{albedo_white, srgb_encode};
use crate::base::error::{Error, Result};
use crate::io::export::{OutputFolder, OutputKind};
use crate::io::imageio::write_png8;
use serde_json::json;
use std::path::{Path, PathBuf};

/// What [`export_openlime`] wrote.
#[derive(Clone, Debug, serde::Serialize)]
pub struct OpenLimeSummary {
    pub dir: PathBuf,
    pub files: Vec<String>,
    pub width: usize,
    pub height: usize,
}

/// The 8-bit normal map in OpenLIME's encoding.
pub fn normals_rgb8(normals: &[[f32; 3]]) -> Vec<u8> {
    normals
        .iter()
        .flat_map(|n| {
            if *n == [0.0; 3] {
                [128u8; 3]
            } else {
                n.map(|v| (((v + 1.0) * 0.5).clamp(0.0, 1.0) * 255.0).round() as u8)
            }
        })
        .collect()
}

/// The 8-bit sRGB diffuse colour map.
pub fn kd_rgb8(f: &RunFolder) -> Vec<u8> {
    let white = albedo_white(&f.albedo, f.albedo_channels, &f.mask);
    let ch = f.albedo_channels;
    (0..f.width * f.height)
        .flat_map(|i| {
            let a = &f.albedo[i * ch..i * ch + ch];
            let inside = f.mask[i];
            (0..3).map(move |k| {
                let v = a[if ch >= 3 { k } else { 0 }];
                if !inside || !v.is_finite() {
                    0
                } else {
                    (srgb_encode(v / white) * 255.0).round() as u8
                }
            })
        })
        .collect()
}

/// The BRDF layer's configuration (the options of `new OpenLIME.Layer(...)`).
pub fn layer_config(width: usize, height: usize) -> serde_json::Value {
    json!({
        "type": "brdf",
        "layout": "image",
        "channels": { "kd": "kd.png", "normals": "normals.png" },
        "colorspaces": { "kd": "sRGB", "ks": "linear" },
        "width": width,
        "height": height,
        "normals": {
            "encoding": "rgb = (n + 1) / 2 * 255, 8-bit",
            "frame": "x right, y up (toward the image top), z toward the viewer",
            "null": "(128, 128, 128) outside the object",
        },
    })
}

const PAGE: &str = r#"<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<title>@TITLE@ — OpenLIME BRDF</title>
<!-- Written by `photostereo export-openlime`. This page needs OpenLIME's files beside it:
     copy openlime.min.js, skin/skin.svg and css/skin.css from an OpenLIME release into this
     folder (they are not bundled). Browsers refuse to load the images of a page opened from the
     file system, so serve the folder, e.g. `photostereo view --serve --no-write THIS_FOLDER`. -->
<link rel="stylesheet" href="css/skin.css">
<style>html, body { margin: 0; height: 100%; background: #111; } .openlime { width: 100%; height: 100%; }</style>
</head>
<body>
<div class="openlime"></div>
<script src="openlime.min.js"></script>
<script>
const config = @CONFIG@;
const lime = new OpenLIME.Viewer('.openlime');
const layer = new OpenLIME.Layer({
  type: config.type,
  layout: config.layout,
  channels: config.channels,
  colorspaces: config.colorspaces,
});
lime.addLayer('brdf', layer);
OpenLIME.Skin.setUrl('skin/skin.svg');
const ui = new OpenLIME.UIBasic(lime, { showLightDirections: true });
</script>
</body>
</html>
"#;

/// Writes `kd.png`, `normals.png`, `brdf.json` and `index.html` into the folder `out`, staged
/// and renamed into place; an existing `out` is refused unless `force`, and `force` replaces
/// only an earlier OpenLIME export, never the run folder or a folder holding it
/// ([`check_output`](crate::io::export::check_output)).
pub fn export_openlime(f: &RunFolder, out: &Path, force: bool) -> Result<OpenLimeSummary> {
    let folder = OutputFolder::create_for(out, force, OutputKind::OpenLime, &[f.dir.as_path()])?;
    let (w, h) = (f.width, f.height);
    write_png8(&folder.file("kd.png"), w, h, 3, &kd_rgb8(f))?;
    write_png8(
        &folder.file("normals.png"),
        w,
        h,
        3,
        &normals_rgb8(&f.normals),
    )?;
    let config = layer_config(w, h);
    crate::io::export::write_json(&folder.file("brdf.json"), &config)?;
    let title = std::fs::canonicalize(&f.dir)
        .ok()
        .and_then(|p| p.file_name().map(|n| n.to_string_lossy().to_string()))
        .unwrap_or_else(|| "photostereo".into())
        .replace('&', "&amp;")
        .replace('<', "&lt;");
    let cfg = serde_json::to_string_pretty(&config)
        .map_err(|e| Error::invalid(e.to_string()))?
        .replace("</", "<\\/");
    let page = PAGE.replace("@TITLE@", &title).replace("@CONFIG@", &cfg);
    let index = folder.file("index.html");
    std::fs::write(&index, page).map_err(|e| Error::io(&index, e))?;
    folder.commit()?;
    Ok(OpenLimeSummary {
        dir: out.to_path_buf(),
        files: ["kd.png", "normals.png", "brdf.json", "index.html"]
            .map(String::from)
            .to_vec(),
        width: w,
        height: h,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn normal_encoding_is_openlimes() {
        let v = normals_rgb8(&[[0.0, 0.0, 1.0], [0.0; 3], [-1.0, 1.0, 0.0]]);
        assert_eq!(v, vec![128, 128, 255, 128, 128, 128, 0, 255, 128]);
        // The null normal decodes shorter than 0.5, OpenLIME's test for "no normal".
        let d: f32 = (0..3).map(|_| (2.0 * 128.0 / 255.0 - 1.0f32).powi(2)).sum();
        assert!(d.sqrt() < 0.5);
    }
}
