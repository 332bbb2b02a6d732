//! The page: `assets/viewer.html` with its style sheet, script, shaders and the manifest of the
//! view inlined, so that `index.html` is one file needing nothing but `view/` beside it.

use crate::base::error::{Error, Result};
use serde_json::Value;

const HTML: &str = include_str!("assets/viewer.html");
const CSS: &str = include_str!("assets/viewer.css");
const JS: &str = include_str!("assets/viewer.js");
const IMAGE_VERT: &str = include_str!("assets/image.vert");
const IMAGE_FRAG: &str = include_str!("assets/image.frag");
const MESH_VERT: &str = include_str!("assets/mesh.vert");
const MESH_FRAG: &str = include_str!("assets/mesh.frag");

/// JSON safe inside a `<script>` element.
fn script_json(v: &Value) -> Result<String> {
    let s = serde_json::to_string(v).map_err(|e| Error::invalid(format!("manifest: {e}")))?;
    Ok(s.replace("</", "<\\/"))
}

/// The page for a view with `manifest`.
pub fn render(manifest: &Value) -> Result<String> {
    let shaders = serde_json::json!({
        "imageVert": IMAGE_VERT,
        "imageFrag": IMAGE_FRAG,
        "meshVert": MESH_VERT,
        "meshFrag": MESH_FRAG,
    });
    let title = manifest["title"]
        .as_str()
        .unwrap_or("photostereo")
        .replace('&', "&amp;")
        .replace('<', "&lt;");
    Ok(HTML
        .replace("@TITLE@", &title)
        .replace("/*@CSS@*/", CSS)
        .replace("/*@MANIFEST@*/", &script_json(manifest)?)
        .replace("/*@SHADERS@*/", &script_json(&shaders)?)
        .replace("/*@JS@*/", &JS.replace("</", "<\\/")))
}

/// The page's assets, for checks (no remote resource, no `</script>` inside the script).
pub fn assets() -> [(&'static str, &'static str); 7] {
    [
        ("viewer.html", HTML),
        ("viewer.css", CSS),
        ("viewer.js", JS),
        ("image.vert", IMAGE_VERT),
        ("image.frag", IMAGE_FRAG),
        ("mesh.vert", MESH_VERT),
        ("mesh.frag", MESH_FRAG),
    ]
}
