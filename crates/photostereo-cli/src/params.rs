//! The algorithm flags of `run` and `compare`, made from the library's parameter table
//! ([`photostereo::method::params::PARAMETERS`]) rather than written out: one flag per
//! parameter, `--name-with-dashes`, its help the table's doc and its default the library's.
//! A switch that is on by default is turned off with `--no-NAME`; `integrate` keeps its
//! historical spelling `--no-depth`. The values are checked by the library's table when the
//! parameters are built ([`ParamArgs::params`]), so a bad value is refused with the library's
//! message, the flag named as this program spells it ([`spell`]).

use clap::parser::ValueSource;
use clap::{Arg, ArgAction, ArgMatches, Args, Command, FromArgMatches};
use photostereo::base::error::ParamRef;
use photostereo::method::params::{parameter, Kind, Parameter, Value, PARAMETERS};
use photostereo::Params;
use std::marker::PhantomData;

/// How this program spells a parameter of the table.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Flag {
    /// The long flag without its dashes (`relative-noise`, `no-detect`).
    pub long: String,
    /// Whether giving the flag sets a switch to false (`--no-detect`).
    pub negated: bool,
}

/// The flag of parameter `p`.
pub fn flag(p: &Parameter) -> Flag {
    let dashed = p.name.replace('_', "-");
    match p.kind {
        Kind::Switch { get, .. } if get(&Params::default()) => Flag {
            long: match p.name {
                // The flag predates the table; `--no-integrate` would say the same.
                "integrate" => "no-depth".into(),
                _ => format!("no-{dashed}"),
            },
            negated: true,
        },
        _ => Flag {
            long: dashed,
            negated: false,
        },
    }
}

/// Options of this program, beyond the table, that a library message may name, with the
/// placeholder of their value when they take one.
const OPTIONS: &[(&str, &str)] = &[
    ("lights", " FILE"),
    ("intensities", " FILE"),
    ("mask", " FILE"),
    ("gt", " FILE"),
    ("distance", " MM"),
];

/// A parameter reference of a library message, spelt as this program's flag: `--confidence`,
/// `--lights FILE` where a value is asked for, `--force` for `force=true`, `--no-detect` for
/// `detect=false`, `-o` for the output.
pub fn spell(r: ParamRef<'_>) -> String {
    if r.name == "output" {
        return "-o".into();
    }
    if let Some(p) = parameter(r.name) {
        let f = flag(p);
        return match (r.value, matches!(p.kind, Kind::Switch { .. })) {
            (None | Some(""), _) => format!("--{}", f.long),
            (Some("true"), true) if !f.negated => format!("--{}", f.long),
            (Some("false"), true) if f.negated => format!("--{}", f.long),
            (Some(v), _) => format!("--{} {v}", p.name.replace('_', "-")),
        };
    }
    let long = format!("--{}", r.name.replace('_', "-"));
    match r.value {
        None | Some("true") => long,
        Some("") => {
            let placeholder = OPTIONS
                .iter()
                .find(|(n, _)| *n == r.name)
                .map_or("", |(_, v)| v);
            format!("{long}{placeholder}")
        }
        Some(v) => format!("{long} {v}"),
    }
}

/// The parameters a subcommand takes from the table: all but those it decides itself.
pub trait Selection {
    /// Parameters left out, with the reason in the implementor's documentation.
    const LEFT_OUT: &'static [&'static str];
}

/// `run` takes every parameter.
#[derive(Debug)]
pub struct Run;
impl Selection for Run {
    const LEFT_OUT: &'static [&'static str] = &[];
}

/// `compare` runs the methods of `--methods`, each with its detector maps and depth (the
/// figure and tables need them), loading the capture with the default memory budget.
#[derive(Debug)]
pub struct Compare;
impl Selection for Compare {
    const LEFT_OUT: &'static [&'static str] = &["method", "detect", "integrate", "memory_limit"];
}

/// The parameters `S` takes.
pub fn selected<S: Selection>() -> impl Iterator<Item = &'static Parameter> {
    PARAMETERS.iter().filter(|p| !S::LEFT_OUT.contains(&p.name))
}

/// The algorithm flags given on the command line: parameter names and their text.
#[derive(Debug)]
pub struct ParamArgs<S> {
    given: Vec<(&'static str, String)>,
    selection: PhantomData<S>,
}

impl<S: Selection> ParamArgs<S> {
    /// The library's parameters: the defaults with each given flag applied by the table.
    /// Errors name the parameter (the caller spells it as a flag).
    pub fn params(&self) -> photostereo::Result<Params> {
        let mut p = Params::default();
        for (name, text) in &self.given {
            p.set_text(name, text)?;
        }
        p.validate()?;
        Ok(p)
    }
}

/// The clap argument of parameter `p`.
pub fn arg(p: &'static Parameter) -> Arg {
    let f = flag(p);
    let mut help = p.doc.to_string();
    if !p.unit.is_empty() && !matches!(p.kind, Kind::Bytes { .. }) {
        help.push_str(&format!(" Unit: {}.", p.unit));
    }
    let choices = p.kind.choices();
    if !choices.is_empty() {
        help.push_str(&format!(" One of: {}.", choices.join(", ")));
    }
    let a = Arg::new(p.name).long(f.long).help(help);
    match p.kind {
        Kind::Switch { .. } => a.action(ArgAction::SetTrue),
        _ => a
            .action(ArgAction::Set)
            .value_name(value_name(p))
            .default_value(p.format(&p.default()))
            .allow_negative_numbers(true),
    }
}

fn value_name(p: &Parameter) -> String {
    match p.kind {
        Kind::Count { .. } => "N".into(),
        Kind::Bytes { .. } => "SIZE".into(),
        Kind::Choice { .. } => "NAME".into(),
        _ => "VALUE".into(),
    }
}

impl<S: Selection> Args for ParamArgs<S> {
    fn augment_args(cmd: Command) -> Command {
        selected::<S>().fold(cmd, |c, p| c.arg(arg(p)))
    }
    fn augment_args_for_update(cmd: Command) -> Command {
        Self::augment_args(cmd)
    }
}

impl<S: Selection> FromArgMatches for ParamArgs<S> {
    fn from_arg_matches(m: &ArgMatches) -> Result<Self, clap::Error> {
        let mut given = Vec::new();
        for p in selected::<S>() {
            if m.value_source(p.name) != Some(ValueSource::CommandLine) {
                continue;
            }
            let text = match p.kind {
                Kind::Switch { .. } => {
                    let on = m.get_flag(p.name);
                    let value = on != flag(p).negated;
                    p.format(&Value::Bool(value))
                }
                _ => m.get_one::<String>(p.name).cloned().unwrap_or_default(),
            };
            given.push((p.name, text));
        }
        Ok(ParamArgs {
            given,
            selection: PhantomData,
        })
    }
    fn update_from_arg_matches(&mut self, m: &ArgMatches) -> Result<(), clap::Error> {
        *self = Self::from_arg_matches(m)?;
        Ok(())
    }
}

/// The Markdown page of the parameters (`docs/parameters.md`): one table per stage, with each
/// parameter's command-line flag and Python keyword. Generated, so that it cannot drift; the
/// test below fails when the file differs.
#[cfg(test)]
pub fn markdown() -> String {
    use photostereo::method::params::Stage;
    let left_out: Vec<String> = Compare::LEFT_OUT.iter().map(|n| format!("`{n}`")).collect();
    let left_out = match left_out.split_last() {
        Some((last, [])) => last.clone(),
        Some((last, rest)) => format!("{} and {last}", rest.join(", ")),
        None => "nothing".into(),
    };
    let mut out = format!(
        "# Parameters\n\n\
         Every parameter of a reconstruction, generated from the library's table \
         (`crates/photostereo/src/method/params.rs`) by `cargo test -p photostereo-cli \
         parameters_page` (set `PHOTOSTEREO_BLESS=1` to rewrite this page). The command line's \
         `run` takes each as a flag (`compare` all but {left_out}); Python takes each as a \
         keyword of `reconstruct` and `run`, or through `photostereo.Params` (nested by stage: \
         `params.detection.confidence`). A value outside its domain is refused with a message \
         naming the flag or keyword.\n",
    );
    for &stage in Stage::ALL {
        out.push_str(&format!(
            "\n## {}\n\n{}\n\n| flag | Python | type | default | domain | unit | methods | meaning |\n|---|---|---|---|---|---|---|---|\n",
            stage.name(),
            stage.doc()
        ));
        for p in PARAMETERS.iter().filter(|p| p.stage == stage) {
            let f = flag(p);
            let default = p.default();
            let python_default = match (&default, p.kind) {
                (Value::None, _) => "None".to_string(),
                (Value::Bool(true), _) => "True".into(),
                (Value::Bool(false), _) => "False".into(),
                (Value::Text(t), _) => format!("\"{t}\""),
                (Value::Float(f), _) => format!("{f:?}"),
                (v, _) => p.format(v),
            };
            let methods: Vec<&str> = p.methods.iter().map(|m| m.name()).collect();
            let methods = if p.methods.len() == photostereo::Method::ALL.len() {
                "all".to_string()
            } else {
                methods.join(", ")
            };
            let flag_cell = if matches!(p.kind, Kind::Switch { .. }) {
                format!("`--{}`", f.long)
            } else {
                format!("`--{} {}`", f.long, value_name(p))
            };
            let cli_default = match p.kind {
                Kind::Switch { .. } => "off".to_string(),
                _ => format!("`{}`", p.format(&default)),
            };
            out.push_str(&format!(
                "| {flag_cell} | `{}={python_default}` | {} | {cli_default} | {} | {} | {methods} | {} |\n",
                p.name,
                p.kind.type_name(),
                p.expected(),
                p.unit,
                p.doc.replace('|', "\\|"),
            ));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::BTreeMap;

    /// What a front end offers for a parameter: its spelling and its default, as text.
    type Surface = BTreeMap<String, String>;

    /// Every disagreement between the table and a front end's `surface` (keyed by the table's
    /// names, `expected` giving the table's text for each): parameters missing, unknown or with
    /// another default.
    fn differences(what: &str, expected: &Surface, surface: &Surface) -> Vec<String> {
        let mut out = Vec::new();
        for (name, value) in expected {
            match surface.get(name) {
                None => out.push(format!("{what}: {name} is missing")),
                Some(v) if v != value => out.push(format!(
                    "{what}: {name} defaults to {v}, the library to {value}"
                )),
                _ => {}
            }
        }
        for name in surface.keys().filter(|n| !expected.contains_key(*n)) {
            out.push(format!("{what}: {name} is not in the library's table"));
        }
        out
    }

    /// The table as a command-line subcommand should offer it: the flag (negated or not) and
    /// the default value clap shows.
    fn expected_cli<S: Selection>() -> Surface {
        selected::<S>()
            .map(|p| {
                let f = flag(p);
                let default = match p.kind {
                    Kind::Switch { .. } => "switch".to_string(),
                    _ => p.format(&p.default()),
                };
                (p.name.to_string(), format!("--{} {default}", f.long))
            })
            .collect()
    }

    /// What a clap command offers: for each argument named after a table parameter, its flag
    /// and default (`switch` for a flag without value).
    fn cli_surface(cmd: &Command) -> Surface {
        cmd.get_arguments()
            .filter(|a| parameter(a.get_id().as_str()).is_some())
            .map(|a| {
                let default = match a.get_action() {
                    ArgAction::SetTrue => "switch".to_string(),
                    _ => a
                        .get_default_values()
                        .iter()
                        .map(|v| v.to_string_lossy().into_owned())
                        .collect::<Vec<_>>()
                        .join(","),
                };
                (
                    a.get_id().to_string(),
                    format!("--{} {default}", a.get_long().unwrap_or("")),
                )
            })
            .collect()
    }

    fn subcommand(name: &str) -> Command {
        use clap::CommandFactory;
        crate::Cli::command()
            .find_subcommand(name)
            .expect("subcommand")
            .clone()
    }

    /// The parameters' stub in `_native.pyi`: a `ParamValues` TypedDict with one typed key per
    /// parameter and its default in a comment, generated here from the table.
    fn stub_block() -> String {
        let mut out = String::from(
            "class ParamValues(TypedDict, total=False):\n    \"\"\"Every parameter of a reconstruction by its keyword, as `defaults()` gives them (generated from the library's table; `Params` nests them by stage).\"\"\"\n\n",
        );
        for p in PARAMETERS {
            let ty = match p.kind {
                Kind::Switch { .. } => "bool".to_string(),
                Kind::Count { .. } => "int".into(),
                Kind::Number { .. } => "float".into(),
                Kind::OptionalNumber { .. } => "Optional[float]".into(),
                Kind::Choice { names, .. } => format!(
                    "Literal[{}]",
                    names()
                        .iter()
                        .map(|n| format!("\"{n}\""))
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
                Kind::Bytes { .. } => "Union[int, str, None]".into(),
            };
            let d = p.default();
            let default = match &d {
                Value::None => "None".to_string(),
                Value::Bool(true) => "True".into(),
                Value::Bool(false) => "False".into(),
                Value::Text(t) => format!("\"{t}\""),
                Value::Float(f) => format!("{f:?}"),
                v => p.format(v),
            };
            out.push_str(&format!("    {}: {ty}  # default {default}\n", p.name));
        }
        out
    }

    const STUB_BEGIN: &str = "# --- parameters: generated from the library's table ---\n";
    const STUB_END: &str = "# --- end of the generated parameters ---\n";

    fn repo() -> std::path::PathBuf {
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
    }

    /// The stub's parameters, keyed by name, as `type  # default value` text.
    fn stub_surface(stub: &str) -> Surface {
        let block = stub
            .split_once(STUB_BEGIN)
            .and_then(|(_, rest)| rest.split_once(STUB_END))
            .map_or("", |(b, _)| b);
        block
            .lines()
            .filter_map(|l| {
                let l = l.strip_prefix("    ")?;
                let (name, rest) = l.split_once(": ")?;
                let default = rest.split_once("# default ")?.1;
                Some((name.to_string(), default.to_string()))
            })
            .collect()
    }

    fn expected_stub() -> Surface {
        stub_surface(&format!("{STUB_BEGIN}{}{STUB_END}", stub_block()))
    }

    /// The docs page's parameters: each table row's Python cell `name=default`.
    fn docs_surface(page: &str) -> Surface {
        page.lines()
            .filter(|l| l.starts_with("| `--"))
            .filter_map(|l| {
                let cell = l.split('|').nth(2)?.trim().trim_matches('`');
                let (name, default) = cell.split_once('=')?;
                Some((name.to_string(), default.to_string()))
            })
            .collect()
    }

    fn expected_docs() -> Surface {
        docs_surface(&markdown())
    }

    /// Writes `text` to `path` when `PHOTOSTEREO_BLESS` is set; else says whether it matches.
    fn matches_file(path: &std::path::Path, text: &str) -> bool {
        if std::env::var_os("PHOTOSTEREO_BLESS").is_some() {
            std::fs::write(path, text).unwrap();
        }
        std::fs::read_to_string(path).is_ok_and(|t| t == text)
    }

    /// The front ends against the table: `run`'s and `compare`'s flags and defaults (clap),
    /// the Python stub's keywords and defaults, and the docs page. The Python package's
    /// runtime (`defaults()`, `Params`, the keywords `reconstruct` accepts) is checked the
    /// same way by python/tests/test_parameters.py.
    #[test]
    fn every_front_end_offers_every_parameter_with_the_librarys_default() {
        // `run` reaches every parameter; `compare` leaves out only what it decides itself, so
        // a flag cannot leave the command line by joining a list of exceptions unnoticed.
        assert!(Run::LEFT_OUT.is_empty(), "{:?}", Run::LEFT_OUT);
        assert_eq!(
            Compare::LEFT_OUT,
            ["method", "detect", "integrate", "memory_limit"]
        );
        let mut problems = Vec::new();
        problems.extend(differences(
            "run",
            &expected_cli::<Run>(),
            &cli_surface(&subcommand("run")),
        ));
        problems.extend(differences(
            "compare",
            &expected_cli::<Compare>(),
            &cli_surface(&subcommand("compare")),
        ));
        let stub_path = repo().join("python/photostereo/_native.pyi");
        let stub = std::fs::read_to_string(&stub_path).unwrap();
        problems.extend(differences(
            "_native.pyi",
            &expected_stub(),
            &stub_surface(&stub),
        ));
        let page_path = repo().join("docs/parameters.md");
        let page = std::fs::read_to_string(&page_path).unwrap_or_default();
        problems.extend(differences(
            "docs/parameters.md",
            &expected_docs(),
            &docs_surface(&page),
        ));
        assert!(problems.is_empty(), "{}", problems.join("\n"));
    }

    /// The checker above on doctored copies: a flag removed from `run`, a default changed in
    /// `compare`, a keyword removed from the stub and a row from the docs are each reported.
    #[test]
    fn the_checker_reports_a_removal_from_one_front_end() {
        let run = subcommand("run");
        let doctored = run
            .get_arguments()
            .filter(|a| a.get_id() != "shadow_ratio")
            .fold(Command::new("run"), |c, a| c.arg(a.clone()));
        assert_eq!(
            differences("run", &expected_cli::<Run>(), &cli_surface(&doctored)),
            vec!["run: shadow_ratio is missing".to_string()]
        );
        let compare = subcommand("compare");
        let doctored = compare
            .get_arguments()
            .map(|a| {
                if a.get_id() == "confidence" {
                    a.clone().default_value("0.9")
                } else {
                    a.clone()
                }
            })
            .fold(Command::new("compare"), |c, a| c.arg(a));
        assert_eq!(
            differences("compare", &expected_cli::<Compare>(), &cli_surface(&doctored)),
            vec!["compare: confidence defaults to --confidence 0.9, the library to --confidence 0.95"
                .to_string()]
        );
        let stub = format!("{STUB_BEGIN}{}{STUB_END}", stub_block());
        let doctored: String = stub
            .lines()
            .filter(|l| !l.trim_start().starts_with("consensus_radius:"))
            .map(|l| format!("{l}\n"))
            .collect();
        assert_eq!(
            differences("_native.pyi", &expected_stub(), &stub_surface(&doctored)),
            vec!["_native.pyi: consensus_radius is missing".to_string()]
        );
        let page = markdown();
        let doctored: String = page
            .lines()
            .filter(|l| !l.contains("`min_kept_share="))
            .map(|l| format!("{l}\n"))
            .collect();
        assert_eq!(
            differences("docs", &expected_docs(), &docs_surface(&doctored)),
            vec!["docs: min_kept_share is missing".to_string()]
        );
    }

    /// The stub's generated block and the docs page are exactly what the table gives
    /// (`PHOTOSTEREO_BLESS=1` rewrites them).
    #[test]
    fn parameters_page_and_stub_are_generated_from_the_table() {
        let page_path = repo().join("docs/parameters.md");
        assert!(
            matches_file(&page_path, &markdown()),
            "docs/parameters.md differs from the table: PHOTOSTEREO_BLESS=1 cargo test -p photostereo-cli parameters_page"
        );
        let stub_path = repo().join("python/photostereo/_native.pyi");
        let stub = std::fs::read_to_string(&stub_path).unwrap();
        let (head, rest) = stub
            .split_once(STUB_BEGIN)
            .expect("the stub's generated block");
        let (_, tail) = rest
            .split_once(STUB_END)
            .expect("the end of the generated block");
        let want = format!("{head}{STUB_BEGIN}{}{STUB_END}{tail}", stub_block());
        assert!(
            matches_file(&stub_path, &want),
            "_native.pyi's parameters differ from the table: PHOTOSTEREO_BLESS=1 cargo test -p photostereo-cli parameters_page"
        );
    }

    #[test]
    fn flags_keep_their_spellings() {
        let cmd = subcommand("run");
        for long in [
            "no-detect",
            "no-depth",
            "surface-prior",
            "relative-noise",
            "consensus-radius",
            "refine-lights",
            "memory-limit",
            "min-kept-share",
            "batch-alpha",
            "shadow-sigmas",
            "shadow-ratio",
            "noise-estimate",
            "noise-refinements",
            "integrator",
        ] {
            assert!(
                cmd.get_arguments().any(|a| a.get_long() == Some(long)),
                "--{long}"
            );
        }
        let spelled = |name, value| spell(ParamRef { name, value });
        assert_eq!(spelled("relative_noise", None), "--relative-noise");
        assert_eq!(spelled("force", Some("true")), "--force");
        assert_eq!(spelled("lights", Some("")), "--lights FILE");
        assert_eq!(spelled("detect", Some("false")), "--no-detect");
        assert_eq!(spelled("output", None), "-o");
    }
}
