//! The paper's evaluation of methods on one capture (Argyriou & Petrou, Tables 1–2 and
//! Figs. 7–12): every method run on the same capture, loaded once; the mean angular error per
//! method when ground truth is given (a Table 1 row), the mean raw intensity of the pairs each
//! method classified as highlights (a Table 2 row, [`crate::method::indicators`]), `compare.json`, and
//! one figure: per method its normal map, its depth shaded under a raking light, its shadow
//! map for one light and its count of highlight lights per pixel (and its error map with
//! ground truth), with labels and colour bars.
//!
//! Each method runs exactly as `photostereo run --method M` does with the same parameters
//! ([`reconstruct_with_truth`], then [`Reconstruction::evaluate`]), so the rows equal four
//! separate runs.

use crate::app::pipeline::{write_reconstruction, LightSubset, RunOptions};
use crate::base::error::{Error, Result};
use crate::base::progress::Progress;
use crate::io::export::{write_json, OutputFolder, OutputKind};
use crate::io::figure::{colormap, Canvas};
use crate::io::groundtruth::read_normal_map;
use crate::io::layouts::CaptureFiles;
use crate::io::maps::{
    colour_bar, even_ticks, hstack, nice_ceil, nice_steps, shaded_depth_panel, tick_label, titled,
    Grid, View, RAKING_LIGHT,
};
use crate::method::engine::{reconstruct_with_truth, Method, Params, Reconstruction};
use crate::method::indicators::{raw_scale, status_intensities, StatusIntensities};
use crate::method::report::{InputSummary, Report};
use crate::model::capture::Capture;
use crate::solve::lambert::status;
use serde_json::{json, Value};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// The file name of the figure.
pub const FIGURE: &str = "compare.png";

/// What a comparison runs and writes.
#[derive(Clone, Debug)]
pub struct CompareOptions {
    /// Parameters shared by every method (each run replaces `method`).
    pub params: Params,
    /// The methods, in table order (default: all four).
    pub methods: Vec<Method>,
    /// Ground-truth normal map: adds the Table 1 row and error maps.
    pub ground_truth: Option<PathBuf>,
    /// Use only these lights.
    pub light_subset: Option<LightSubset>,
    /// The light (0-based, after the subset) whose shadow maps the figure shows; default the
    /// light farthest from the viewing direction (largest slant), whose shadows are largest.
    pub figure_light: Option<usize>,
    /// Also write each method's full output folder (as `run` writes it) into `DIR/<method>/`.
    pub save_runs: bool,
    /// Longest side of a panel in the figure, pixels (the object's bounding box is reduced by
    /// an integer factor to fit).
    pub panel_size: usize,
}

impl Default for CompareOptions {
    fn default() -> Self {
        CompareOptions {
            params: Params::default(),
            methods: Method::ALL.to_vec(),
            ground_truth: None,
            light_subset: None,
            figure_light: None,
            save_runs: false,
            panel_size: 360,
        }
    }
}

/// One method's results.
#[derive(Clone, Debug)]
pub struct MethodResult {
    pub method: Method,
    /// The method's full report, as `run` writes it (error figures included with ground truth).
    pub report: Report,
    /// The highlight / shadow indicator.
    pub indicators: StatusIntensities,
}

/// The result of a comparison.
#[derive(Clone, Debug)]
pub struct Comparison {
    /// What was compared, for titles (the capture's folder or list-file name).
    pub name: String,
    pub input: InputSummary,
    /// The light the figure's shadow maps show (0-based).
    pub figure_light: usize,
    pub results: Vec<MethodResult>,
    /// `compare.json`'s content.
    pub json: Value,
}

impl Comparison {
    /// The Table 1 row: mean angular error per method, degrees (None without ground truth).
    pub fn table1(&self) -> Vec<(Method, Option<f64>)> {
        self.results
            .iter()
            .map(|r| (r.method, r.report.error.as_ref().map(|e| e.mean_deg)))
            .collect()
    }

    /// The Table 2 row: mean raw intensity of the highlight pairs per method on the paper's
    /// 0–255 scale, grey (None where a method classified no highlight).
    pub fn table2(&self) -> Vec<(Method, Option<f64>)> {
        self.results
            .iter()
            .map(|r| {
                (
                    r.method,
                    r.indicators
                        .highlights
                        .mean_intensity_255
                        .as_ref()
                        .map(|m| m.grey),
                )
            })
            .collect()
    }
}

/// What the figure keeps of one method's reconstruction.
struct Kept {
    normals: Vec<[f32; 3]>,
    depth: Option<Vec<f32>>,
    shadow: Vec<bool>,
    highlights: Vec<f32>,
    error: Option<Vec<f32>>,
}

/// Loads a capture (and the light subset) once, runs every method, writes `compare.json`,
/// `compare.png` (and the runs with `save_runs`) into `output` atomically.
pub fn compare(
    files: &CaptureFiles,
    options: &CompareOptions,
    output: &Path,
    force: bool,
    name: &str,
    progress: &dyn Progress,
) -> Result<Comparison> {
    options.params.validate()?;
    if options.methods.is_empty() {
        return Err(Error::invalid("compare needs at least one method"));
    }
    let folder = OutputFolder::create(output, force, OutputKind::Compare)?;
    let start = Instant::now();
    let truth = match &options.ground_truth {
        Some(p) => Some(read_normal_map(p)?),
        None => None,
    };
    let t = Instant::now();
    let mut capture = files.load(progress)?;
    let mut subset = None;
    if let Some(s) = &options.light_subset {
        let keep = s.resolve(&capture.lights)?;
        capture = capture.select_lights(&keep)?;
        subset = Some(keep);
    }
    // With `refine_lights`, the lights (the chosen subset's) refined from the readings, once
    // for every method that runs on this capture.
    crate::method::engine::prepare(&mut capture, &options.params)?;
    let load_seconds = t.elapsed().as_secs_f64();
    if let (Some(t), Some(path)) = (&truth, &options.ground_truth) {
        if (t.width, t.height) != (capture.width, capture.height) {
            return Err(Error::file(
                path,
                format!(
                    "ground truth is {}×{} but the capture is {}×{}",
                    t.width, t.height, capture.width, capture.height
                ),
            ));
        }
    }
    let truth_normals = truth.as_ref().map(|t| t.normals.as_slice());
    let mut comparison = compare_capture(
        &capture,
        truth_normals,
        options,
        name,
        progress,
        &mut |rec| {
            if options.save_runs {
                let dir = folder.file(rec.report.method.as_str());
                std::fs::create_dir(&dir).map_err(|e| Error::io(&dir, e))?;
                let run_options = RunOptions {
                    params: options.params.clone(),
                    ground_truth: options.ground_truth.clone(),
                    error_map: truth.is_some(),
                    error_map_max_deg: None,
                    light_subset: options.light_subset.clone(),
                    obj_any_size: false,
                    return_freed_memory_when_tiled: false,
                    rti: None,
                };
                write_reconstruction(rec, &dir, &run_options)?;
                write_json(&dir.join("report.json"), &rec.report)?;
            }
            Ok(())
        },
        folder.path(),
    )?;
    let j = &mut comparison.json;
    j["capture"]["sources"] = json!(files
        .images
        .iter()
        .map(|p| p.display().to_string())
        .collect::<Vec<_>>());
    j["capture"]["notes"] = json!(capture.notes);
    if let Some(p) = &options.ground_truth {
        j["ground_truth"] = json!(p.display().to_string());
    }
    if let Some(keep) = subset {
        j["light_subset"] = json!(keep.iter().map(|k| k + 1).collect::<Vec<_>>());
    }
    j["timings_s"] = json!({
        "load": load_seconds,
        "total": start.elapsed().as_secs_f64(),
    });
    write_json(&folder.file("compare.json"), &comparison.json)?;
    folder.commit()?;
    Ok(comparison)
}

/// The light farthest from the viewing direction (smallest z component; first on ties).
pub fn most_raking_light(capture: &Capture) -> usize {
    let d = &capture.lights.directions;
    (0..d.len())
        .min_by(|&a, &b| d[a][2].total_cmp(&d[b][2]))
        .unwrap_or(0)
}

/// Runs every method on a capture in memory and draws the figure into `dir/compare.png`;
/// `each` sees every reconstruction (evaluated when `truth` is given) before it is dropped.
pub fn compare_capture(
    capture: &Capture,
    truth: Option<&[[f32; 3]]>,
    options: &CompareOptions,
    name: &str,
    progress: &dyn Progress,
    each: &mut dyn FnMut(&Reconstruction) -> Result<()>,
    dir: &Path,
) -> Result<Comparison> {
    let n = capture.n_lights();
    let k = match options.figure_light {
        Some(k) if k < n => k,
        Some(k) => {
            return Err(Error::Parameter {
                name: "light",
                message: format!("{}: the capture has {n} lights", k + 1),
            })
        }
        None => most_raking_light(capture),
    };
    let mut results = Vec::new();
    let mut kept = Vec::new();
    for &method in &options.methods {
        let params = Params {
            method,
            ..options.params.clone()
        };
        let mut rec = reconstruct_with_truth(capture, &params, truth, progress)?;
        if let Some(t) = truth {
            let t0 = Instant::now();
            rec.evaluate(t)?;
            rec.report.time("evaluate", t0);
        }
        let indicators = status_intensities(capture, &rec.light_status);
        each(&rec)?;
        kept.push(Kept {
            normals: rec.normals.clone(),
            depth: rec.depth().map(<[f32]>::to_vec),
            shadow: rec
                .light_status
                .plane(k)
                .iter()
                .map(|&s| s == status::SHADOW)
                .collect(),
            highlights: rec.light_status.counts(Some(status::HIGHLIGHT)),
            error: rec.error_map.clone(),
        });
        results.push(MethodResult {
            method,
            report: rec.report,
            indicators,
        });
    }
    let input = InputSummary::of(capture);
    let figure = draw(capture, truth, k, name, &results, &kept, options.panel_size);
    figure.save(&dir.join(FIGURE))?;
    let json = comparison_json(name, &input, k, capture, &results);
    Ok(Comparison {
        name: name.into(),
        input,
        figure_light: k,
        results,
        json,
    })
}

fn comparison_json(
    name: &str,
    input: &InputSummary,
    k: usize,
    capture: &Capture,
    results: &[MethodResult],
) -> Value {
    let l = capture.lights.directions[k];
    let table1: serde_json::Map<String, Value> = results
        .iter()
        .map(|r| {
            (
                r.method.name().to_string(),
                json!(r.report.error.as_ref().map(|e| e.mean_deg)),
            )
        })
        .collect();
    let table2: serde_json::Map<String, Value> = results
        .iter()
        .map(|r| {
            (
                r.method.name().to_string(),
                json!(r
                    .indicators
                    .highlights
                    .mean_intensity_255
                    .as_ref()
                    .map(|m| m.grey)),
            )
        })
        .collect();
    json!({
        "tool": "photostereo",
        "version": env!("CARGO_PKG_VERSION"),
        "capture": {"name": name, "input": input},
        "table1_mean_angular_error_deg": table1,
        "table2_mean_highlight_intensity_255": table2,
        "definitions": {
            "table1": "mean angular error (degrees) of the normals over the mask pixels with non-zero ground truth; null without ground truth",
            "table2": "mean raw image intensity (sample × light intensity, grey = mean of the channels) over the pixel–light pairs the method classified as highlights, × 255; null where it classified none",
        },
        "figure": FIGURE,
        "figure_light": {
            "index": k + 1,
            "direction": l,
            "slant_deg": l[2].clamp(-1.0, 1.0).acos().to_degrees(),
        },
        "raking_light": RAKING_LIGHT,
        "methods": results.iter().map(|r| json!({
            "method": r.method.name(),
            "error": r.report.error,
            "highlights": r.indicators.highlights,
            "shadows": r.indicators.shadows,
            "report": r.report,
        })).collect::<Vec<_>>(),
        "all_pairs": results.first().map(|r| json!(r.indicators.all_pairs)),
    })
}

/// Percentile `q` of the finite values (0 when none).
fn percentile(values: impl Iterator<Item = f32>, q: f64) -> f32 {
    let mut v: Vec<f32> = values.filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return 0.0;
    }
    let i = ((v.len() - 1) as f64 * q).round() as usize;
    *v.select_nth_unstable_by(i, |a, b| a.total_cmp(b)).1
}

/// The input image under light k with automatic exposure: raw values scaled so that the
/// 99th percentile inside the mask is white.
fn input_panel(view: &View, capture: &Capture, k: usize) -> (Canvas, f32) {
    let (n, c) = (capture.n_lights(), capture.channels);
    let scale = raw_scale(capture, k);
    let mut raw = vec![[0f32; 3]; capture.width * capture.height];
    let _ = capture.for_each_tile(|_, tile| {
        for (p, &pix) in tile.pixels.iter().enumerate() {
            let s = &tile.samples[(p * n + k) * c..(p * n + k + 1) * c];
            raw[pix as usize] = if c == 1 {
                [s[0] * scale[0] as f32; 3]
            } else {
                [
                    s[0] * scale[0] as f32,
                    s[1] * scale[1] as f32,
                    s[2] * scale[2] as f32,
                ]
            };
        }
        Ok(())
    });
    let white = percentile(
        capture
            .pixels
            .iter()
            .map(|&i| raw[i as usize].iter().sum::<f32>() / 3.0),
        0.99,
    )
    .max(1e-6);
    let panel = view.colour_panel(false, |i| {
        raw[i].map(|v| ((v / white).clamp(0.0, 1.0).powf(1.0 / 2.2) * 255.0).round() as u8)
    });
    (panel, white)
}

/// The comparison figure for shadow light `k`: a row of the input (and the true normals), then
/// per method its normals, shaded relief, shadow map of light `k`, highlight-light count and
/// (with ground truth) angular error, under common colour scales; legends below.
fn draw(
    capture: &Capture,
    truth: Option<&[[f32; 3]]>,
    k: usize,
    name: &str,
    results: &[MethodResult],
    kept: &[Kept],
    panel_size: usize,
) -> Canvas {
    let (w, h) = (capture.width, capture.height);
    let view = View::of_mask(&capture.mask, w, h, panel_size.max(32));
    let s = if view.size().0.max(view.size().1) >= 200 {
        2
    } else {
        1
    };
    let n = capture.n_lights();
    let hl_max = nice_ceil(
        kept.iter()
            .map(|m| percentile(m.highlights.iter().copied(), 0.99))
            .fold(1.0f32, f32::max),
    )
    .min(n as f32);
    // One error scale for every method: the median over the methods of their 95th
    // percentiles, so that one method's wild edges do not flatten the others' maps (errors
    // above it clip to yellow).
    let mut p95: Vec<f32> = kept
        .iter()
        .filter_map(|m| m.error.as_ref())
        .map(|e| percentile(e.iter().copied(), 0.95))
        .collect();
    p95.sort_by(|a, b| a.total_cmp(b));
    let err_max = (!p95.is_empty()).then(|| nice_ceil(p95[(p95.len() - 1) / 2].max(1.0)));
    let mut grid = figure_frame(capture, k, name, s, err_max.is_some());
    let (input, _) = input_panel(&view, capture, k);
    let mut top = vec![input];
    if let Some(t) = truth {
        top.push(view.normals_panel(t));
    }
    grid.rows.push((
        if truth.is_some() {
            format!("input, light {} (auto exposure) / true normals", k + 1)
        } else {
            format!("input, light {} (auto exposure)", k + 1)
        },
        top,
    ));
    for (r, m) in results.iter().zip(kept) {
        let mut panels = vec![view.normals_panel(&m.normals)];
        panels.push(match &m.depth {
            Some(d) => shaded_depth_panel(&view, d, RAKING_LIGHT),
            None => view.colour_panel(false, |_| [40, 40, 40]),
        });
        panels.push(view.binary_panel(|i| m.shadow[i]));
        panels.push(view.heat_panel(&m.highlights, hl_max));
        if let (Some(e), Some(max)) = (&m.error, err_max) {
            panels.push(view.heat_panel(e, max));
        }
        grid.rows.push((method_label(r), panels));
    }
    grid.footer.push(legends(results, hl_max, err_max, s));
    grid.render()
}

/// The figure's title lines and column headings, before its rows.
fn figure_frame(capture: &Capture, k: usize, name: &str, s: usize, with_error: bool) -> Grid {
    let (w, h) = (capture.width, capture.height);
    let n = capture.n_lights();
    let l = capture.lights.directions[k];
    let slant = l[2].clamp(-1.0, 1.0).acos().to_degrees();
    let mut grid = Grid {
        title: vec![
            format!(
                "{name}: {n} lights, {w}x{h}, {}-bit, {} object pixels",
                capture.bit_depth,
                capture.n_pixels()
            ),
            format!(
                "shadows: light {} (slant {slant:.0}°); relief: depth lit from the upper left, 65° from the view",
                k + 1
            ),
        ],
        headings: vec![
            "normals".into(),
            "relief".into(),
            format!("shadow, light {}", k + 1),
            "highlight lights".into(),
        ],
        headings_at: 1,
        scale: s,
        ..Grid::default()
    };
    if with_error {
        grid.headings.push("angular error".into());
    }
    grid
}

/// A method's row caption: its name, mean angular error (with ground truth), and the mean
/// intensities and shares of the readings it classified as highlights and shadows.
fn method_label(r: &MethodResult) -> String {
    let hl = &r.indicators.highlights;
    let sh = &r.indicators.shadows;
    let mut label = r.method.name().to_string();
    if let Some(e) = &r.report.error {
        label += &format!(": MAE {:.2}°", e.mean_deg);
    }
    label += &match &hl.mean_intensity_255 {
        Some(m) => format!(
            "  highlights {:.1}/255 ({:.1}% of pairs)",
            m.grey,
            100.0 * hl.share_of_pairs
        ),
        None => "  no highlight classified".into(),
    };
    label += &match &sh.mean_intensity_255 {
        Some(m) => format!(
            "  shadows {:.1}/255 ({:.1}%)",
            m.grey,
            100.0 * sh.share_of_pairs
        ),
        None => "  no shadow classified".into(),
    };
    label
}

/// The figure's footer: the colour bars of the highlight count and of the error, and a key to
/// the shadow maps with the mean intensity of all object pairs.
fn legends(results: &[MethodResult], hl_max: f32, err_max: Option<f32>, s: usize) -> Canvas {
    let bar_h = 120 * s;
    let mut legends = vec![colour_bar(
        bar_h,
        hl_max,
        &even_ticks(hl_max, nice_steps(hl_max), ""),
        "highlight lights per pixel",
        s,
        &colormap,
    )];
    if let Some(max) = err_max {
        legends.push(colour_bar(
            bar_h,
            max,
            &even_ticks(max, nice_steps(max), "°"),
            "angular error",
            s,
            &colormap,
        ));
    }
    let key = {
        let lines = [
            "shadow maps: black = the method dropped light as shadow".to_string(),
            "white = lit, red = object outline".to_string(),
            "coleman-jain labels every dropped light a highlight".to_string(),
            format!(
                "mean of all object pairs: {}/255",
                results
                    .first()
                    .and_then(|r| r.indicators.all_pairs.mean_intensity_255.as_ref())
                    .map(|m| tick_label((m.grey * 10.0).round() as f32 / 10.0))
                    .unwrap_or_default()
            ),
        ];
        let mut c = Canvas::new(
            lines
                .iter()
                .map(|l| crate::io::figure::text_width(l, s))
                .max()
                .unwrap_or(1),
            lines.len() * 11 * s,
            [255; 3],
        );
        for (i, l) in lines.iter().enumerate() {
            c.text(0, i * 11 * s, l, s, [0, 0, 0]);
        }
        c
    };
    legends.push(key);
    titled(&hstack(&legends, 24 * s), "", 1)
}
