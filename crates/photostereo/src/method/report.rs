//! `report.json`: what was run, on what, how long each stage took, and the error figures.

use crate::solve::metrics::ErrorStats;
use serde::Serialize;
use serde_json::{Map, Value};
use std::time::Instant;

/// The machine-readable summary of a run.
#[derive(Clone, Debug, Serialize)]
pub struct Report {
    pub tool: String,
    pub version: String,
    /// The estimation method's name.
    pub method: String,
    /// Every parameter that influenced the result, by name.
    pub parameters: Map<String, Value>,
    /// Size and kind of the input.
    pub input: InputSummary,
    /// Wall-clock seconds per stage, in order.
    pub timings_s: Map<String, Value>,
    /// Error figures against ground truth, when given.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<ErrorStats>,
    /// Remarks (normalised lights, resolved paths, fallbacks…).
    pub notes: Vec<String>,
    /// Stage-specific results (iterations, counts…).
    #[serde(flatten)]
    pub extra: Map<String, Value>,
}

/// Size and kind of the input of a run.
#[derive(Clone, Debug, Default, Serialize)]
pub struct InputSummary {
    /// The input files read, in order: a capture's images, or the normal map of `integrate`.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub files: Vec<String>,
    /// The mask file, when one was read.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mask_file: Option<String>,
    /// True when the whole frame was taken as the object (no mask given, or one without
    /// background).
    #[serde(skip_serializing_if = "is_false")]
    pub whole_frame_mask: bool,
    pub width: usize,
    pub height: usize,
    /// Channels per image (omitted where the input is no capture, as for `integrate`).
    #[serde(skip_serializing_if = "is_zero")]
    pub channels: usize,
    /// Bits per sample of the images (omitted where the input is no capture).
    #[serde(skip_serializing_if = "is_zero")]
    pub bit_depth: u8,
    /// Number of lights (omitted where the input is no capture).
    #[serde(skip_serializing_if = "is_zero")]
    pub lights: usize,
    pub mask_pixels: usize,
    /// Light directions that were not unit length (omitted where the input is no capture).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lights_renormalised: Option<usize>,
    /// Condition number of the light matrix (omitted where the input is no capture).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub light_condition_number: Option<f64>,
    /// The lights' refinement from the readings, when applied: refined directions, gains, the
    /// angle each light moved and the pixels' misfit before and after.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub light_refinement: Option<crate::model::lights::LightRefinement>,
}

fn is_zero<T: Default + PartialEq>(v: &T) -> bool {
    *v == T::default()
}

fn is_false(v: &bool) -> bool {
    !*v
}

impl InputSummary {
    /// The summary of a loaded capture.
    pub fn of(capture: &crate::model::capture::Capture) -> Self {
        InputSummary {
            files: capture
                .sources
                .iter()
                .map(|p| p.display().to_string())
                .collect(),
            mask_file: None,
            whole_frame_mask: capture.n_pixels() == capture.width * capture.height,
            width: capture.width,
            height: capture.height,
            channels: capture.channels,
            bit_depth: capture.bit_depth,
            lights: capture.n_lights(),
            mask_pixels: capture.n_pixels(),
            lights_renormalised: Some(capture.lights.renormalised),
            light_condition_number: Some(capture.lights.condition_number()),
            light_refinement: capture.light_refinement.clone(),
        }
    }
}

impl Report {
    /// An empty report for `method`.
    pub fn new(method: &str) -> Self {
        Report {
            tool: "photostereo".into(),
            version: env!("CARGO_PKG_VERSION").into(),
            method: method.into(),
            parameters: Map::new(),
            input: InputSummary::default(),
            timings_s: Map::new(),
            error: None,
            notes: Vec::new(),
            extra: Map::new(),
        }
    }

    /// Records a stage's duration since `start` (seconds) and returns a new start instant.
    pub fn time(&mut self, stage: &str, start: Instant) -> Instant {
        let s = start.elapsed().as_secs_f64();
        let prev = self
            .timings_s
            .get(stage)
            .and_then(Value::as_f64)
            .unwrap_or(0.0);
        self.timings_s.insert(stage.into(), Value::from(prev + s));
        Instant::now()
    }

    /// Sets a parameter.
    pub fn param(&mut self, name: &str, value: impl Into<Value>) {
        self.parameters.insert(name.into(), value.into());
    }
}
