//! The reconstruction's parameters as one table: for every field of [`Params`] its name, type,
//! domain, unit, meaning, stage and the methods that use it, with typed access by name.
//!
//! The front ends are driven by this table rather than by copies of it: the command line makes
//! its algorithm flags from it, the Python package its keywords, `defaults()` and its `Params`
//! object, and `docs/parameters.md` is generated from it; tests in both front ends fail when
//! one of them lacks a parameter or disagrees on a default. The defaults themselves are the
//! [`Default`] impls of the parameter structs (each with the principle it follows on its
//! field); the table reads them ([`Parameter::default`]).
//!
//! Names are the library's spelling, which is also Python's keyword (`relative_noise`); the
//! command line spells them as flags (`--relative-noise`). Errors name parameters the same way
//! ([`Error::Parameter`]).
//!
//! ```
//! use photostereo::method::params::{Value, PARAMETERS};
//! use photostereo::Params;
//!
//! let mut p = Params::default();
//! p.set("confidence", Value::Float(0.99)).unwrap();
//! p.set_text("relative_noise", "measured").unwrap();
//! assert_eq!(p.get("confidence"), Some(Value::Float(0.99)));
//! let e = p.set("max_iterations", Value::Int(0)).unwrap_err();
//! assert!(e.to_string().starts_with("max_iterations 0: expected"));
//! assert!(PARAMETERS.iter().any(|q| q.name == "surface_prior"));
//! ```

use crate::base::error::{Error, Result};
use crate::method::engine::{Method, Params};

/// The stage of a reconstruction a parameter shapes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stage {
    /// The run as a whole: the method, which stages run, the memory budget, the lights.
    Run,
    /// The χ² test of non-Lambertian pixels and the attribution of faults to lights.
    Detection,
    /// The recursive method's loop: shadows from the surface, highlights, convergence.
    Recursive,
    /// Normals to depth, for the recursive method's surfaces and the exported depth.
    Integration,
}

impl Stage {
    /// Every stage, in the order tables list them.
    pub const ALL: &'static [Stage] = &[
        Stage::Run,
        Stage::Detection,
        Stage::Recursive,
        Stage::Integration,
    ];

    /// The stage's name: the key of its object in `report.json`'s `parameters` (none for
    /// `run`, whose parameters sit at the top) and of Python's `Params` attribute.
    pub fn name(self) -> &'static str {
        match self {
            Stage::Run => "run",
            Stage::Detection => "detection",
            Stage::Recursive => "recursive",
            Stage::Integration => "integration",
        }
    }

    /// What the stage does, in a line.
    pub fn doc(self) -> &'static str {
        match self {
            Stage::Run => "The method, which stages run, the memory budget and the lights.",
            Stage::Detection => {
                "The chi-square test of non-Lambertian pixels and the attribution of faults to lights."
            }
            Stage::Recursive => {
                "The recursive method: shadows from the integrated surface, highlights, convergence."
            }
            Stage::Integration => {
                "Normals to depth, for the recursive method's surfaces and the exported depth."
            }
        }
    }
}

/// One end of a number's domain.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Bound {
    /// No bound on this side (numbers are always finite).
    Unbounded,
    /// The value itself is allowed.
    Closed(f64),
    /// Values up to, not including, this one.
    Open(f64),
}

/// The domain of a number: finite, between two bounds.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Range {
    pub min: Bound,
    pub max: Bound,
}

impl Range {
    const fn new(min: Bound, max: Bound) -> Range {
        Range { min, max }
    }

    /// Whether `v` is finite and within the bounds.
    pub fn contains(&self, v: f64) -> bool {
        v.is_finite()
            && match self.min {
                Bound::Unbounded => true,
                Bound::Closed(m) => v >= m,
                Bound::Open(m) => v > m,
            }
            && match self.max {
                Bound::Unbounded => true,
                Bound::Closed(m) => v <= m,
                Bound::Open(m) => v < m,
            }
    }

    /// The domain in words: `[0, 1]`, `(0.5, 1)`, `≥ 0`, `> 0`.
    pub fn describe(&self) -> String {
        match (self.min, self.max) {
            (Bound::Unbounded, Bound::Unbounded) => "finite".into(),
            (Bound::Closed(a), Bound::Unbounded) => format!("≥ {a}"),
            (Bound::Open(a), Bound::Unbounded) => format!("> {a}"),
            (Bound::Unbounded, Bound::Closed(b)) => format!("≤ {b}"),
            (Bound::Unbounded, Bound::Open(b)) => format!("< {b}"),
            (min, max) => {
                let (l, a) = match min {
                    Bound::Closed(a) => ('[', a),
                    Bound::Open(a) => ('(', a),
                    Bound::Unbounded => unreachable!(),
                };
                let (r, b) = match max {
                    Bound::Closed(b) => (']', b),
                    Bound::Open(b) => (')', b),
                    Bound::Unbounded => unreachable!(),
                };
                format!("{l}{a}, {b}{r}")
            }
        }
    }
}

/// A parameter's value as the front ends hand it over: Python's `None`, `bool`, `int`,
/// `float` and `str`, or the command line's text ([`Params::set_text`]).
#[derive(Clone, Debug, PartialEq)]
pub enum Value {
    /// No value: the "measured", "estimated" or "auto" choice of an optional parameter.
    None,
    Bool(bool),
    Int(i64),
    Float(f64),
    Text(String),
}

impl Value {
    /// The value as `report.json` holds it.
    pub fn to_json(&self) -> serde_json::Value {
        match self {
            Value::None => serde_json::Value::Null,
            Value::Bool(b) => (*b).into(),
            Value::Int(i) => (*i).into(),
            Value::Float(f) => (*f).into(),
            Value::Text(t) => t.as_str().into(),
        }
    }

    /// The value as a message shows it.
    fn shown(&self) -> String {
        match self {
            Value::None => "(none)".into(),
            Value::Bool(b) => b.to_string(),
            Value::Int(i) => i.to_string(),
            Value::Float(f) => f.to_string(),
            Value::Text(t) => format!("'{t}'"),
        }
    }
}

type Get<T> = fn(&Params) -> T;
type Set<T> = fn(&mut Params, T);

/// A parameter's type, its domain, and the typed access to its field of [`Params`].
#[derive(Clone, Copy)]
pub enum Kind {
    /// true or false.
    Switch { get: Get<bool>, set: Set<bool> },
    /// A whole number in `min..=max`.
    Count {
        min: usize,
        max: usize,
        get: Get<usize>,
        set: Set<usize>,
    },
    /// A finite number in `range`.
    Number {
        range: Range,
        get: Get<f64>,
        set: Set<f64>,
    },
    /// A finite number in `range`, or none: the library's own choice, named `none`
    /// ("measured", "estimated").
    OptionalNumber {
        range: Range,
        none: &'static str,
        get: Get<Option<f64>>,
        set: Set<Option<f64>>,
    },
    /// One of the names `names()` lists.
    Choice {
        names: fn() -> Vec<&'static str>,
        get: Get<&'static str>,
        set: fn(&mut Params, &str) -> Result<()>,
    },
    /// A positive byte count (`4G`, `500M`: powers of 1024), or none: the default budget,
    /// named `none`.
    Bytes {
        none: &'static str,
        get: Get<Option<u64>>,
        set: Set<Option<u64>>,
    },
}

impl std::fmt::Debug for Kind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.type_name())
    }
}

impl Kind {
    /// The type in a word: `bool`, `int`, `float`, `float or none`, `choice`, `bytes`.
    pub fn type_name(&self) -> &'static str {
        match self {
            Kind::Switch { .. } => "bool",
            Kind::Count { .. } => "int",
            Kind::Number { .. } => "float",
            Kind::OptionalNumber { .. } => "float or none",
            Kind::Choice { .. } => "choice",
            Kind::Bytes { .. } => "bytes",
        }
    }

    /// The names a choice accepts (empty for the other kinds).
    pub fn choices(&self) -> Vec<&'static str> {
        match self {
            Kind::Choice { names, .. } => names(),
            _ => Vec::new(),
        }
    }

    /// The word for "none" of an optional parameter.
    pub fn none_word(&self) -> Option<&'static str> {
        match self {
            Kind::OptionalNumber { none, .. } | Kind::Bytes { none, .. } => Some(none),
            _ => None,
        }
    }
}

/// One row of the table.
#[derive(Clone, Copy, Debug)]
pub struct Parameter {
    /// The library's name: Python's keyword, the command line's flag with `-` for `_`.
    pub name: &'static str,
    /// The stage it shapes.
    pub stage: Stage,
    /// Its type, domain and field.
    pub kind: Kind,
    /// The unit of a number (empty when it has none).
    pub unit: &'static str,
    /// What it does, in a sentence or two.
    pub doc: &'static str,
    /// The methods whose results it changes.
    pub methods: &'static [Method],
    /// Where `report.json`'s `parameters` records it (`detection.confidence`).
    pub report_key: &'static str,
}

impl Parameter {
    /// The value in `params`.
    pub fn get(&self, params: &Params) -> Value {
        match self.kind {
            Kind::Switch { get, .. } => Value::Bool(get(params)),
            Kind::Count { get, .. } => Value::Int(get(params) as i64),
            Kind::Number { get, .. } => Value::Float(get(params)),
            Kind::OptionalNumber { get, .. } => get(params).map_or(Value::None, Value::Float),
            Kind::Choice { get, .. } => Value::Text(get(params).into()),
            Kind::Bytes { get, .. } => get(params).map_or(Value::None, |b| Value::Int(b as i64)),
        }
    }

    /// The default value: the one `Params::default()` holds.
    pub fn default(&self) -> Value {
        self.get(&Params::default())
    }

    /// The domain in words ("a number in [0, 1]", "one of l2, coleman-jain, …").
    pub fn expected(&self) -> String {
        match self.kind {
            Kind::Switch { .. } => "true or false".into(),
            Kind::Count { min, max, .. } if max == usize::MAX => format!("an integer ≥ {min}"),
            Kind::Count { min, max, .. } => format!("an integer in [{min}, {max}]"),
            Kind::Number { range, .. } => format!("a number {}", in_range(&range)),
            Kind::OptionalNumber { range, none, .. } => {
                format!("a number {}, or {none}", in_range(&range))
            }
            Kind::Choice { names, .. } => format!("one of {}", names().join(", ")),
            Kind::Bytes { none, .. } => {
                format!("a size in bytes such as 4G or 500M (powers of 1024), or {none}")
            }
        }
    }

    /// The value as text, as [`Parameter::parse`] reads it back (the command line's form).
    pub fn format(&self, value: &Value) -> String {
        match (value, self.kind.none_word()) {
            (Value::None, Some(none)) => none.into(),
            (Value::Text(t), _) => t.clone(),
            (Value::Bool(b), _) => b.to_string(),
            (Value::Int(i), _) => i.to_string(),
            (Value::Float(f), _) => f.to_string(),
            (Value::None, None) => String::new(),
        }
    }

    /// Reads a value from text: `true`/`false`, a number, a name, a size (`4G`), or the none
    /// word of an optional parameter (`measured`).
    pub fn parse(&self, text: &str) -> Result<Value> {
        let t = text.trim();
        let bad = || self.refuse(&Value::Text(text.into()));
        if self.kind.none_word() == Some(t) {
            return Ok(Value::None);
        }
        match self.kind {
            Kind::Switch { .. } => match t {
                "true" => Ok(Value::Bool(true)),
                "false" => Ok(Value::Bool(false)),
                _ => Err(bad()),
            },
            Kind::Count { .. } => t.parse().map(Value::Int).map_err(|_| bad()),
            Kind::Number { .. } | Kind::OptionalNumber { .. } => {
                t.parse().map(Value::Float).map_err(|_| bad())
            }
            Kind::Choice { .. } | Kind::Bytes { .. } => Ok(Value::Text(t.into())),
        }
    }

    /// The error for a value outside the domain, naming the parameter.
    fn refuse(&self, value: &Value) -> Error {
        let unit = if self.unit.is_empty() {
            String::new()
        } else {
            format!(" ({})", self.unit)
        };
        Error::parameter(
            self.name,
            format!("{}: expected {}{unit}", value.shown(), self.expected()),
        )
    }

    /// Sets the parameter in `params` to `value`, checked against its type and domain; an
    /// integer is accepted for a number, and the none word of an optional parameter
    /// (`measured`) for no value. Errors name the parameter and say what was expected.
    pub fn set(&self, params: &mut Params, value: Value) -> Result<()> {
        // The none word of an optional parameter is its "no value", in any front end.
        let value = match value {
            Value::Text(t) if self.kind.none_word() == Some(t.as_str()) => Value::None,
            v => v,
        };
        let number = |v: &Value| match v {
            Value::Float(f) => Some(*f),
            Value::Int(i) => Some(*i as f64),
            _ => None,
        };
        match self.kind {
            Kind::Switch { set, .. } => match value {
                Value::Bool(b) => set(params, b),
                v => return Err(self.refuse(&v)),
            },
            Kind::Count { min, max, set, .. } => match value {
                Value::Int(i) if i >= 0 && (i as u64) >= min as u64 && (i as u64) <= max as u64 => {
                    set(params, i as usize)
                }
                v => return Err(self.refuse(&v)),
            },
            Kind::Number { range, set, .. } => match number(&value) {
                Some(f) if range.contains(f) => set(params, f),
                _ => return Err(self.refuse(&value)),
            },
            Kind::OptionalNumber { range, set, .. } => match (&value, number(&value)) {
                (Value::None, _) => set(params, None),
                (_, Some(f)) if range.contains(f) => set(params, Some(f)),
                _ => return Err(self.refuse(&value)),
            },
            Kind::Choice { set, .. } => match &value {
                Value::Text(t) => set(params, t)?,
                v => return Err(self.refuse(v)),
            },
            Kind::Bytes { set, .. } => match &value {
                Value::None => set(params, None),
                Value::Int(i) if *i > 0 => set(params, Some(*i as u64)),
                Value::Text(t) => match crate::base::machine::parse_bytes(t) {
                    Some(b) if b > 0 => set(params, Some(b)),
                    _ => return Err(self.refuse(&value)),
                },
                v => return Err(self.refuse(v)),
            },
        }
        Ok(())
    }
}

fn in_range(range: &Range) -> String {
    match (range.min, range.max) {
        (Bound::Unbounded, Bound::Unbounded) => "(finite)".into(),
        (_, Bound::Unbounded) | (Bound::Unbounded, _) => range.describe(),
        _ => format!("in {}", range.describe()),
    }
}

/// The parameter named `name`.
pub fn parameter(name: &str) -> Option<&'static Parameter> {
    PARAMETERS.iter().find(|p| p.name == name)
}

/// The parameters of one stage, in table order.
pub fn of_stage(stage: Stage) -> impl Iterator<Item = &'static Parameter> {
    PARAMETERS.iter().filter(move |p| p.stage == stage)
}

fn unknown(name: &str) -> Error {
    let close: Vec<&str> = PARAMETERS
        .iter()
        .map(|p| p.name)
        .filter(|n| n.contains(name) || name.contains(n) || shared_prefix(n, name) >= 4)
        .collect();
    Error::invalid(format!(
        "unknown parameter '{name}'{}",
        if close.is_empty() {
            String::new()
        } else {
            format!(" (did you mean {}?)", close.join(", "))
        }
    ))
}

fn shared_prefix(a: &str, b: &str) -> usize {
    a.chars().zip(b.chars()).take_while(|(x, y)| x == y).count()
}

impl Params {
    /// Sets the parameter `name` (the table's name) to `value`, checked against its type and
    /// domain; errors name the parameter.
    pub fn set(&mut self, name: &str, value: Value) -> Result<()> {
        parameter(name)
            .ok_or_else(|| unknown(name))?
            .set(self, value)
    }

    /// Sets the parameter `name` from text (`0.99`, `measured`, `4G`, `true`).
    pub fn set_text(&mut self, name: &str, text: &str) -> Result<()> {
        let p = parameter(name).ok_or_else(|| unknown(name))?;
        let value = p.parse(text)?;
        p.set(self, value)
    }

    /// The value of the parameter `name`, or `None` when there is no such parameter.
    pub fn get(&self, name: &str) -> Option<Value> {
        parameter(name).map(|p| p.get(self))
    }
}

fn f32_field(v: f32) -> f64 {
    crate::base::number::f32_as_given(v)
}

const ALL: &[Method] = Method::ALL;
const ATTRIBUTING: &[Method] = &[Method::BarskyPetrou, Method::Recursive];
const RECURSIVE: &[Method] = &[Method::Recursive];
const WITHOUT_OWN_TEST: &[Method] = &[Method::L2, Method::ColemanJain];
const TRUSTING_THE_TEST: &[Method] = &[Method::L2, Method::ColemanJain, Method::Recursive];

const UNIT_INTERVAL: Range = Range::new(Bound::Closed(0.0), Bound::Closed(1.0));
const OPEN_UNIT_INTERVAL: Range = Range::new(Bound::Open(0.0), Bound::Open(1.0));
const NON_NEGATIVE: Range = Range::new(Bound::Closed(0.0), Bound::Unbounded);
const POSITIVE: Range = Range::new(Bound::Open(0.0), Bound::Unbounded);

/// Every parameter of [`Params`], by stage.
pub const PARAMETERS: &[Parameter] = &[
    // --- the run -------------------------------------------------------------------------
    Parameter {
        name: "method",
        stage: Stage::Run,
        kind: Kind::Choice {
            names: || Method::ALL.iter().map(|m| m.name()).collect(),
            get: |p| p.method.name(),
            set: |p, v| {
                p.method = v.parse()?;
                Ok(())
            },
        },
        unit: "",
        doc: "The estimation method: least squares over all lights (l2), Coleman & Jain, Barsky & \
              Petrou, or the recursive method of Argyriou & Petrou.",
        methods: ALL,
        report_key: "method",
    },
    Parameter {
        name: "detect",
        stage: Stage::Run,
        kind: Kind::Switch {
            get: |p| p.detect,
            set: |p, v| p.detect = v,
        },
        unit: "",
        doc: "Run the chi-square test for its maps (residual, unreliable pixels, light statuses) \
              with the methods that do not need it; it needs four lights or more.",
        methods: WITHOUT_OWN_TEST,
        report_key: "detect",
    },
    Parameter {
        name: "integrate",
        stage: Stage::Run,
        kind: Kind::Switch {
            get: |p| p.integrate,
            set: |p, v| p.integrate = v,
        },
        unit: "",
        doc: "Integrate the final normals into depth and curl (and the meshes of a run).",
        methods: ALL,
        report_key: "integrate",
    },
    Parameter {
        name: "memory_limit",
        stage: Stage::Run,
        kind: Kind::Bytes {
            none: "auto",
            get: |p| p.memory_limit,
            set: |p, v| p.memory_limit = v,
        },
        unit: "bytes",
        doc: "The memory budget (auto: half of the memory available). Samples that do not fit as \
              32-bit floats are held in tiles at the input's precision, in memory or in a spill \
              file, with the same results; a budget too small for the full-frame stages is \
              refused with the smallest one that works.",
        methods: ALL,
        report_key: "memory_limit",
    },
    Parameter {
        name: "refine_lights",
        stage: Stage::Run,
        kind: Kind::Switch {
            get: |p| p.refine_lights,
            set: |p, v| p.refine_lights = v,
        },
        unit: "",
        doc: "Refine the light directions and intensities from the readings before estimating \
              (six or more distant lights); every method then uses the refined lights.",
        methods: ALL,
        report_key: "refine_lights",
    },
    Parameter {
        name: "occluding_contour",
        stage: Stage::Run,
        kind: Kind::Switch {
            get: |p| p.occluding_contour,
            set: |p, v| p.occluding_contour = v,
        },
        unit: "",
        doc: "Give the mask's edge pixels the silhouette's normal (n_z from the square-root law \
              of a smooth surface at its occluding contour, fitted to the pixels inside) where \
              those pixels say the edge is a silhouette the lens blurred: their n_z rises \
              inward, they lean outward, and the edge pixels' albedo is a mixture. \
              Orthographic cameras.",
        methods: ALL,
        report_key: "occluding_contour",
    },
    // --- detection -----------------------------------------------------------------------
    Parameter {
        name: "sigma",
        stage: Stage::Detection,
        kind: Kind::OptionalNumber {
            range: POSITIVE,
            none: "estimated",
            get: |p| p.detection.sigma,
            set: |p, v| p.detection.sigma = v,
        },
        unit: "full scale 1",
        doc: "Image noise per channel (estimated: from the images, or from the residuals with \
              noise_estimate residuals).",
        methods: ALL,
        report_key: "detection.sigma",
    },
    Parameter {
        name: "relative_noise",
        stage: Stage::Detection,
        kind: Kind::OptionalNumber {
            range: NON_NEGATIVE,
            none: "measured",
            get: |p| p.detection.relative_noise,
            set: |p, v| p.detection.relative_noise = v,
        },
        unit: "share of the intensity",
        doc: "Model error kappa as a share of a pixel's mean intensity: the noise at a pixel is \
              sqrt(sigma^2 + (kappa * level)^2). measured: the light-to-light part of the \
              capture's misfit (0.01 with fewer than five lights or near lights).",
        methods: ALL,
        report_key: "detection.relative_noise",
    },
    Parameter {
        name: "confidence",
        stage: Stage::Detection,
        kind: Kind::Number {
            range: Range::new(Bound::Open(0.5), Bound::Open(1.0)),
            get: |p| p.detection.confidence,
            set: |p, v| p.detection.confidence = v,
        },
        unit: "",
        doc:
            "Confidence of the chi-square test of non-Lambertian pixels (0.95: the paper's 2 sigma \
              for four lights).",
        methods: ALL,
        report_key: "detection.confidence",
    },
    Parameter {
        name: "min_kept_share",
        stage: Stage::Detection,
        kind: Kind::Number {
            range: UNIT_INTERVAL,
            get: |p| p.detection.min_kept_share,
            set: |p, v| p.detection.min_kept_share = v,
        },
        unit: "share of the lights",
        doc: "The attribution keeps at least this share of the lights, and never fewer than three.",
        methods: ATTRIBUTING,
        report_key: "detection.min_kept_share",
    },
    Parameter {
        name: "batch_alpha",
        stage: Stage::Detection,
        kind: Kind::Number {
            range: OPEN_UNIT_INTERVAL,
            get: |p| p.detection.batch_alpha,
            set: |p, v| p.detection.batch_alpha = v,
        },
        unit: "",
        doc: "Family-wise error rate for removing, in one step, several lights that read at the \
              shadow level while the fit predicts clearly more.",
        methods: ATTRIBUTING,
        report_key: "detection.batch_alpha",
    },
    Parameter {
        name: "shadow_sigmas",
        stage: Stage::Detection,
        kind: Kind::Number {
            range: NON_NEGATIVE,
            get: |p| p.detection.shadow_sigmas,
            set: |p, v| p.detection.shadow_sigmas = v,
        },
        unit: "noise sigmas",
        doc: "A reading is at the shadow level below floor + shadow_sigmas * sigma_p + \
              shadow_ratio * (the pixel's mean level); only such readings are labelled shadows.",
        methods: ALL,
        report_key: "detection.shadow_sigmas",
    },
    Parameter {
        name: "shadow_ratio",
        stage: Stage::Detection,
        kind: Kind::Number {
            range: NON_NEGATIVE,
            get: |p| p.detection.shadow_ratio,
            set: |p, v| p.detection.shadow_ratio = v,
        },
        unit: "share of the mean level",
        doc: "See shadow_sigmas.",
        methods: ALL,
        report_key: "detection.shadow_ratio",
    },
    Parameter {
        name: "attribute",
        stage: Stage::Detection,
        kind: Kind::Switch {
            get: |p| p.detection.attribute,
            set: |p, v| p.detection.attribute = v,
        },
        unit: "",
        doc:
            "Attribute the test's failures to lights in the recursive method's detection; without \
              it only the test runs. The other methods decide this themselves.",
        methods: RECURSIVE,
        report_key: "detection.attribute",
    },
    Parameter {
        name: "noise_estimate",
        stage: Stage::Detection,
        kind: Kind::Choice {
            names: || {
                crate::solve::detect::NoiseEstimate::ALL
                    .iter()
                    .map(|n| n.name())
                    .collect()
            },
            get: |p| p.detection.noise_estimate.name(),
            set: |p, v| {
                p.detection.noise_estimate = v.parse()?;
                Ok(())
            },
        },
        unit: "",
        doc: "Where the noise floor comes from when sigma is not given: the images' sensor noise \
              (images) or the least-squares residuals (residuals, which counts model error as \
              noise and needs the samples whole in memory).",
        methods: ALL,
        report_key: "detection.noise_estimate",
    },
    Parameter {
        name: "noise_refinements",
        stage: Stage::Detection,
        kind: Kind::Count {
            min: 0,
            max: crate::solve::detect::MAX_NOISE_REFINEMENTS,
            get: |p| p.detection.noise_refinements,
            set: |p, v| p.detection.noise_refinements = v,
        },
        unit: "",
        doc: "Rounds of noise re-estimation from the lights each pixel kept (noise_estimate \
              residuals only).",
        methods: ALL,
        report_key: "detection.noise_refinements",
    },
    Parameter {
        name: "light_noise",
        stage: Stage::Detection,
        kind: Kind::Switch {
            get: |p| p.detection.light_noise,
            set: |p, v| p.detection.light_noise = v,
        },
        unit: "",
        doc: "Measure a noise factor per light (distant lights): a light whose readings disagree \
              with the others' fit more than the typical light's gets its own larger kappa.",
        methods: ALL,
        report_key: "detection.light_noise",
    },
    // --- the recursive method ------------------------------------------------------------
    Parameter {
        name: "max_iterations",
        stage: Stage::Recursive,
        kind: Kind::Count {
            min: 1,
            max: crate::method::recursive::MAX_ITERATIONS,
            get: |p| p.recursive.max_iterations,
            set: |p, v| p.recursive.max_iterations = v,
        },
        unit: "",
        doc: "Iteration limit of the recursion (the paper gives none).",
        methods: RECURSIVE,
        report_key: "recursive.max_iterations",
    },
    Parameter {
        name: "change_tolerance",
        stage: Stage::Recursive,
        kind: Kind::Number {
            range: UNIT_INTERVAL,
            get: |p| p.recursive.change_tolerance,
            set: |p, v| p.recursive.change_tolerance = v,
        },
        unit: "share of the mask pixels",
        doc: "Stop when the usable-light sets change at fewer than this share of the pixels.",
        methods: RECURSIVE,
        report_key: "recursive.change_tolerance",
    },
    Parameter {
        name: "fallback",
        stage: Stage::Recursive,
        kind: Kind::Choice {
            names: || {
                crate::method::recursive::Fallback::ALL
                    .iter()
                    .map(|f| f.name())
                    .collect()
            },
            get: |p| p.recursive.fallback.name(),
            set: |p, v| {
                p.recursive.fallback = v.parse()?;
                Ok(())
            },
        },
        unit: "",
        doc: "Completion of pixels with fewer than three usable lights: their albedo with the two \
              usable lights, else the integrated surface's normal (neighbours), or the paper's \
              brightest remaining lights (brightest).",
        methods: RECURSIVE,
        report_key: "recursive.fallback",
    },
    Parameter {
        name: "consensus_radius",
        stage: Stage::Recursive,
        kind: Kind::Count {
            min: 0,
            max: crate::method::recursive::MAX_CONSENSUS_RADIUS,
            get: |p| p.recursive.consensus_radius,
            set: |p, v| p.recursive.consensus_radius = v,
        },
        unit: "pixels",
        doc: "Radius of the spatial consensus of the usable lights: a pixel takes the majority of \
              its (2r+1)^2 neighbourhood's removals where its readings pass the test with them; 0 \
              = the paper's per-pixel decisions.",
        methods: RECURSIVE,
        report_key: "recursive.consensus_radius",
    },
    Parameter {
        name: "surface_prior",
        stage: Stage::Recursive,
        kind: Kind::Number {
            range: Range::new(Bound::Closed(0.0), Bound::Closed(90.0)),
            get: |p| p.recursive.surface_prior_deg,
            set: |p, v| p.recursive.surface_prior_deg = v,
        },
        unit: "degrees",
        doc: "Angular standard deviation of the integrated surface's normal as a prior on each \
              pixel's normal in the final estimate; 0 = the usable lights' least squares alone.",
        methods: RECURSIVE,
        report_key: "recursive.surface_prior_deg",
    },
    Parameter {
        name: "reflectance",
        stage: Stage::Recursive,
        kind: Kind::Choice {
            names: || {
                crate::solve::gloss::Reflectance::ALL
                    .iter()
                    .map(|r| r.name())
                    .collect()
            },
            get: |p| p.recursive.reflectance.name(),
            set: |p, v| {
                p.recursive.reflectance = v.parse()?;
                Ok(())
            },
        },
        unit: "",
        doc: "Reflectance model of the final estimate with distant lights: at pixels with a \
              highlight, the normal fitted jointly with a specular lobe where the chi-square \
              evidence says the lobe is significant (auto), wherever the fit finds a lobe \
              (lobe), or from the lights left after dropping the highlight (lambert); \
              material: one lobe shape and diffuse falloff per material (albedo colour \
              cluster), fitted from all its pixels and kept where its pooled evidence (BIC) \
              says so, Lambert elsewhere.",
        methods: RECURSIVE,
        report_key: "recursive.reflectance",
    },
    Parameter {
        name: "attached_tolerance",
        stage: Stage::Recursive,
        kind: Kind::Number {
            range: Range::new(Bound::Open(-1.0), Bound::Open(1.0)),
            get: |p| p.recursive.shadows.attached_tolerance,
            set: |p, v| p.recursive.shadows.attached_tolerance = v,
        },
        unit: "cosine",
        doc: "A pixel of the surface is in attached shadow when n.l is at most this cosine.",
        methods: RECURSIVE,
        report_key: "recursive.attached_tolerance",
    },
    Parameter {
        name: "cast_tolerance",
        stage: Stage::Recursive,
        kind: Kind::Number {
            range: NON_NEGATIVE,
            get: |p| p.recursive.shadows.cast_tolerance_px,
            set: |p, v| p.recursive.shadows.cast_tolerance_px = v,
        },
        unit: "pixels of height",
        doc: "A pixel of the surface is in cast shadow when it lies below the horizon toward the \
              light by more than this height.",
        methods: RECURSIVE,
        report_key: "recursive.cast_tolerance_px",
    },
    // --- integration ---------------------------------------------------------------------
    Parameter {
        name: "integrator",
        stage: Stage::Integration,
        kind: Kind::Choice {
            names: || {
                crate::geometry::integrate::IntegratorKind::ALL
                    .iter()
                    .map(|k| k.name())
                    .collect()
            },
            get: |p| p.integration.method.name(),
            set: |p, v| {
                p.integration.method = v.parse()?;
                Ok(())
            },
        },
        unit: "",
        doc: "The integrator: bilateral (keeps depth jumps, any mask; writes \
              discontinuities.npy/.png), poisson (any mask and weights), dct and fft (the full \
              rectangle), paths (averaged path integration).",
        methods: ALL,
        report_key: "integration.method",
    },
    Parameter {
        name: "max_slope",
        stage: Stage::Integration,
        kind: Kind::Number {
            range: POSITIVE,
            get: |p| f32_field(p.integration.max_slope),
            set: |p, v| p.integration.max_slope = v as f32,
        },
        unit: "pixels per pixel",
        doc: "Cap on the depth gradient |dz/dx|, |dz/dy| when integrating.",
        methods: ALL,
        report_key: "integration.max_slope",
    },
    Parameter {
        name: "unreliable_weight",
        stage: Stage::Integration,
        kind: Kind::Number {
            range: UNIT_INTERVAL,
            get: |p| f32_field(p.integration.unreliable_weight),
            set: |p, v| p.integration.unreliable_weight = v as f32,
        },
        unit: "",
        doc: "Integration weight of unreliable pixels relative to reliable ones (0: fill them \
              from their neighbours).",
        methods: TRUSTING_THE_TEST,
        report_key: "integration.unreliable_weight",
    },
];

#[cfg(test)]
mod tests {
    use super::*;

    /// The value of `key` ("detection.confidence") in report.json's `parameters` of `params`.
    fn reported(params: &Params, key: &str) -> Option<serde_json::Value> {
        let json = params.to_json();
        let mut v = &json;
        for part in key.split('.') {
            v = v.get(part)?;
        }
        Some(v.clone())
    }

    #[test]
    fn names_are_unique_and_every_stage_has_parameters() {
        let mut names: Vec<&str> = PARAMETERS.iter().map(|p| p.name).collect();
        names.sort();
        let n = names.len();
        names.dedup();
        assert_eq!(names.len(), n, "duplicate names");
        for &s in Stage::ALL {
            assert!(of_stage(s).count() > 0, "{s:?}");
        }
    }

    /// The table's defaults are the `Default` impls' (it reads them), each within its own
    /// domain, and report.json records each parameter under its key with that value.
    #[test]
    fn defaults_are_valid_and_reported_under_their_keys() {
        let d = Params::default();
        d.validate().unwrap();
        for p in PARAMETERS {
            let mut q = Params::default();
            p.set(&mut q, p.default())
                .unwrap_or_else(|e| panic!("{}: default refused: {e}", p.name));
            q.validate().unwrap();
            if let Some(v) = reported(&d, p.report_key) {
                assert_eq!(v, p.default().to_json(), "{}", p.name);
            } else {
                // Recorded only when changed (the shadow tolerances).
                assert_eq!(p.stage, Stage::Recursive, "{} is not reported", p.name);
            }
        }
    }

    /// Setting a non-default value by name changes exactly that parameter, and report.json
    /// records it under the table's key.
    #[test]
    fn set_by_name_reaches_its_field_and_the_report() {
        for p in PARAMETERS {
            let other = match p.kind {
                Kind::Switch { get, .. } => Value::Bool(!get(&Params::default())),
                Kind::Count { min, get, .. } => {
                    let d = get(&Params::default());
                    Value::Int(if d == min { min as i64 + 1 } else { min as i64 })
                }
                Kind::Number { range, get, .. } => {
                    let d = get(&Params::default());
                    let c = [0.25, 0.75, 0.9, 2.0, 0.5]
                        .into_iter()
                        .find(|&c| c != d && range.contains(c));
                    Value::Float(c.unwrap())
                }
                Kind::OptionalNumber { .. } => Value::Float(0.5),
                Kind::Choice { names, get, .. } => {
                    let d = get(&Params::default());
                    Value::Text(names().into_iter().find(|n| *n != d).unwrap().into())
                }
                Kind::Bytes { .. } => Value::Int(1 << 30),
            };
            let mut q = Params::default();
            q.set(p.name, other.clone()).unwrap();
            assert_eq!(q.get(p.name), Some(other.clone()), "{}", p.name);
            q.validate().unwrap();
            assert_eq!(
                reported(&q, p.report_key),
                Some(other.to_json()),
                "{}",
                p.name
            );
            for r in PARAMETERS.iter().filter(|r| r.name != p.name) {
                assert_eq!(r.get(&q), r.default(), "{} changed {}", p.name, r.name);
            }
        }
    }

    /// Each domain of the table is the one `Params::validate` enforces: values just inside a
    /// bound pass both, values just outside fail both.
    #[test]
    fn the_table_domains_are_those_validate_enforces() {
        fn check(p: &Parameter, v: f64, inside: bool) {
            let mut q = Params::default();
            let set = p.set(&mut q, Value::Float(v));
            assert_eq!(set.is_ok(), inside, "{} = {v} through the table", p.name);
            // Bypass the table: write the field and ask validate.
            let mut raw = Params::default();
            match p.kind {
                Kind::Number { set, .. } => set(&mut raw, v),
                Kind::OptionalNumber { set, .. } => set(&mut raw, Some(v)),
                _ => unreachable!(),
            }
            let valid = raw.validate();
            assert_eq!(valid.is_ok(), inside, "{} = {v} through validate", p.name);
            if let Err(Error::Parameter { name, .. }) = valid {
                assert_eq!(name, p.name);
            } else if !inside {
                panic!("{}: validate's error does not name the parameter", p.name);
            }
        }
        for p in PARAMETERS {
            let range = match p.kind {
                Kind::Number { range, .. } | Kind::OptionalNumber { range, .. } => range,
                Kind::Count { min, max, set, .. } => {
                    for (v, inside) in [(min, true), (max, true)]
                        .into_iter()
                        .chain((min > 0).then_some((min - 1, false)))
                        .chain((max < usize::MAX).then_some((max + 1, false)))
                    {
                        let mut raw = Params::default();
                        set(&mut raw, v);
                        assert_eq!(raw.validate().is_ok(), inside, "{} = {v}", p.name);
                        let mut q = Params::default();
                        assert_eq!(p.set(&mut q, Value::Int(v as i64)).is_ok(), inside);
                    }
                    continue;
                }
                _ => continue,
            };
            check(p, f64::NAN, false);
            check(p, f64::INFINITY, false);
            for (bound, below) in [(range.min, true), (range.max, false)] {
                let (b, closed) = match bound {
                    Bound::Unbounded => continue,
                    Bound::Closed(b) => (b, true),
                    Bound::Open(b) => (b, false),
                };
                let step = 1e-6 * b.abs().max(1.0);
                let outside = if below { b - step } else { b + step };
                let inside = if below { b + step } else { b - step };
                check(p, b, closed);
                check(p, inside, true);
                check(p, outside, false);
            }
        }
    }

    #[test]
    fn text_round_trips_and_errors_name_the_parameter() {
        for p in PARAMETERS {
            let d = p.default();
            assert_eq!(p.parse(&p.format(&d)).unwrap(), d, "{}", p.name);
        }
        let mut q = Params::default();
        q.set_text("memory_limit", "4G").unwrap();
        assert_eq!(q.memory_limit, Some(4 << 30));
        q.set_text("memory_limit", "auto").unwrap();
        assert_eq!(q.memory_limit, None);
        q.set_text("relative_noise", "0.02").unwrap();
        assert_eq!(q.detection.relative_noise, Some(0.02));
        for (name, text, needle) in [
            (
                "confidence",
                "1.5",
                "confidence 1.5: expected a number in (0.5, 1)",
            ),
            ("confidence", "high", "confidence 'high': expected a number"),
            (
                "max_iterations",
                "-1",
                "max_iterations -1: expected an integer in [1, ",
            ),
            (
                "memory_limit",
                "lots",
                "memory_limit 'lots': expected a size",
            ),
            ("method", "magic", "unknown method 'magic'"),
            ("surface_prior", "-1", "[0, 90] (degrees)"),
        ] {
            let e = q.set_text(name, text).unwrap_err().to_string();
            assert!(e.contains(needle), "{e}");
        }
        let e = q
            .set("confidense", Value::Float(0.9))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("unknown parameter 'confidense' (did you mean confidence?)"),
            "{e}"
        );
        let e = q.set("detect", Value::Int(1)).unwrap_err().to_string();
        assert_eq!(e, "detect 1: expected true or false");
    }

    /// The field documentation's stated defaults agree with the table's (they are prose, so a
    /// changed default would otherwise leave them behind).
    #[test]
    fn field_docs_state_the_defaults_the_code_sets() {
        let sources = [
            include_str!("engine.rs"),
            include_str!("recursive.rs"),
            include_str!("../solve/detect/params.rs"),
            include_str!("../geometry/integrate/mod.rs"),
            include_str!("../geometry/shadows/mod.rs"),
        ];
        let mut checked = 0;
        for p in PARAMETERS {
            let field = p.report_key.rsplit('.').next().unwrap_or(p.report_key);
            if !matches!(p.default(), Value::Float(_) | Value::Int(_)) {
                continue;
            }
            for src in sources {
                let Some(at) = src.find(&format!("    pub {field}: ")) else {
                    continue;
                };
                let doc: Vec<&str> = src[..at]
                    .lines()
                    .rev()
                    .map(str::trim_start)
                    .take_while(|l| l.starts_with("///") || l.starts_with("#["))
                    .filter(|l| l.starts_with("///"))
                    .map(|l| l.trim_start_matches('/'))
                    .collect();
                let doc = doc.into_iter().rev().collect::<Vec<_>>().join(" ");
                let lower = doc.to_lowercase();
                let Some(i) = lower.find("default ") else {
                    continue;
                };
                let stated: String = doc[i + 8..]
                    .chars()
                    .take_while(|c| c.is_ascii_digit() || *c == '.')
                    .collect();
                let stated = stated.trim_end_matches('.');
                if stated.is_empty() {
                    continue;
                }
                let stated: f64 = stated.parse().unwrap();
                let actual = match p.default() {
                    Value::Float(f) => f,
                    Value::Int(i) => i as f64,
                    _ => unreachable!(),
                };
                assert_eq!(stated, actual, "{}: the doc says default {stated}", p.name);
                checked += 1;
            }
        }
        assert!(checked >= 8, "only {checked} stated defaults found");
    }
}
