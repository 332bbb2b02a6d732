//! Every shell command of the documentation runs: the fenced ```sh, ```bash, ```shell and
//! ```console blocks of README.md and docs/*.md are extracted and run with bash, with the binary
//! under test as `photostereo` on the PATH, in a temporary folder prepared with small inputs.
//! A documented command that stops working fails this test.
//!
//! The rules the markdown follows (and this test enforces):
//! - A block runs as a whole (`bash -e -o pipefail`), blocks of one file one after the other in
//!   one working folder, so a later block may read what an earlier one wrote. In a ```console
//!   block only the lines starting with `$ ` are commands; the other lines are their output.
//! - The working folder holds `my_capture/` (a synthetic capture in the folder layout, with
//!   ground truth in `gt/`: `photostereo synth sphere --rig ring8 --size 64`) and `rti.lp` (the
//!   same images as an `.lp` file); `../shared` is the project's shared data.
//! - Commands are `photostereo …` or a few harmless shell words (`cd`, `mkdir`, `ls`, `cat`, `cp`,
//!   `echo`, `true`, `head`, `for` loops, variable assignments). Anything else (`cargo`, `pip`,
//!   scripts, long benches) needs a `<!-- not run: REASON -->` comment on the line before the
//!   block, which this test honours and reports.
//! - `<!-- expect exit N: REASON -->` before a block says that it ends with that exit status (a
//!   documented refusal); the output lines shown in such a ```console block must then appear in
//!   what the commands print.
//! - An untagged fenced block that starts a line with `photostereo ` is an error: tag it `sh` to
//!   run it, or `text` for a synopsis that cannot run.
//! - Blocks run with `RAYON_NUM_THREADS=2` ([`DOC_THREADS`]): the documented outputs are a 2-core
//!   machine's, and the memory plan's named budget grows with the worker threads.
//!
//! Python blocks (```python) are run by the Python suite, `python/tests/test_docs.py`.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// The binary under test.
const BIN: &str = env!("CARGO_BIN_EXE_photostereo");

/// Worker threads the blocks run with: the documentation's figures (a refusal's named budget,
/// which counts each worker thread) are those of a 2-core machine, and read the same on any.
const DOC_THREADS: &str = "2";

/// Longest time one block may take before it counts as hung.
const BLOCK_TIMEOUT: Duration = Duration::from_secs(600);

/// The languages whose blocks are shell commands.
const SHELL: [&str; 4] = ["sh", "bash", "shell", "console"];

/// The words a runnable block may start a command with, besides `photostereo`.
const ALLOWED: [&str; 9] = [
    "photostereo",
    "cd",
    "mkdir",
    "ls",
    "cat",
    "cp",
    "echo",
    "true",
    "head",
];

/// What the comment before a block says about it.
#[derive(Clone, Debug, PartialEq)]
enum Mark {
    /// No comment: the block runs and every command succeeds.
    Run,
    /// `<!-- not run: REASON -->`.
    NotRun(String),
    /// `<!-- expect exit N: REASON -->`.
    Exit(i32),
}

/// One fenced block of a markdown file.
#[derive(Clone, Debug)]
struct Block {
    /// The file and the 1-based line of the opening fence, for messages.
    place: String,
    /// The fence's language (`sh`, `console`, `python`, ``…; lower case).
    lang: String,
    /// The lines between the fences.
    body: Vec<String>,
    mark: Mark,
}

/// The marker a comment line sets, if it is one; an error for a marker without its reason.
fn parse_mark(line: &str) -> Result<Option<Mark>, String> {
    let Some(inner) = line
        .trim()
        .strip_prefix("<!--")
        .and_then(|l| l.strip_suffix("-->"))
    else {
        return Ok(None);
    };
    let inner = inner.trim();
    if let Some(reason) = inner.strip_prefix("not run:") {
        if reason.trim().is_empty() {
            return Err(format!("`{line}`: say why the block cannot run"));
        }
        return Ok(Some(Mark::NotRun(reason.trim().to_string())));
    }
    if let Some(rest) = inner.strip_prefix("expect exit ") {
        let code = rest.split(':').next().unwrap_or("").trim();
        return code
            .parse()
            .map(|c| Some(Mark::Exit(c)))
            .map_err(|_| format!("`{line}`: expected `<!-- expect exit N: REASON -->`"));
    }
    Ok(None)
}

/// The fenced blocks of a markdown text; `name` labels them.
fn blocks(name: &str, text: &str) -> Result<Vec<Block>, String> {
    let mut out = Vec::new();
    let mut lines = text.lines().enumerate();
    let mut previous: Option<&str> = None;
    while let Some((i, line)) = lines.next() {
        let Some(info) = line.trim_start().strip_prefix("```") else {
            if !line.trim().is_empty() {
                previous = Some(line);
            }
            continue;
        };
        let mark = match previous.map(parse_mark).transpose()? {
            Some(Some(m)) => m,
            _ => Mark::Run,
        };
        let lang = info
            .split_whitespace()
            .next()
            .unwrap_or("")
            .to_ascii_lowercase();
        let mut body = Vec::new();
        let mut closed = false;
        for (_, l) in lines.by_ref() {
            if l.trim_start().starts_with("```") {
                closed = true;
                break;
            }
            body.push(l.to_string());
        }
        if !closed {
            return Err(format!(
                "{name}:{}: the fenced block is never closed",
                i + 1
            ));
        }
        out.push(Block {
            place: format!("{name}:{}", i + 1),
            lang,
            body,
            mark,
        });
        previous = None;
    }
    Ok(out)
}

/// `line` without a trailing `# comment` (a `#` at the start or after a blank, outside quotes).
fn strip_comment(line: &str) -> &str {
    let (mut single, mut double) = (false, false);
    let mut last = ' ';
    for (i, c) in line.char_indices() {
        match c {
            '\'' if !double => single = !single,
            '"' if !single => double = !double,
            '#' if !single && !double && last.is_whitespace() => return &line[..i],
            _ => {}
        }
        last = c;
    }
    line
}

/// The commands of a shell block, continuation lines joined, comments and blank lines dropped.
/// In a console block only the `$ ` lines (and their continuations) are commands.
fn commands(block: &Block) -> Vec<String> {
    let console = block.lang == "console";
    let mut out = Vec::new();
    let mut current: Option<String> = None;
    for line in &block.body {
        let text = match (&current, console) {
            (Some(_), _) => line.as_str(),
            (None, true) => match line.strip_prefix("$ ") {
                Some(c) => c,
                None => continue,
            },
            (None, false) => line.as_str(),
        };
        let text = strip_comment(text).trim_end();
        let (piece, continues) = match text.strip_suffix('\\') {
            Some(p) => (p, true),
            None => (text, false),
        };
        let joined = match current.take() {
            Some(c) => format!("{c} {}", piece.trim()),
            None => piece.trim().to_string(),
        };
        if continues {
            current = Some(joined);
        } else if !joined.is_empty() {
            out.push(joined);
        }
    }
    out.extend(current);
    out
}

/// The output lines a console block shows (the lines that are not `$ ` commands).
fn shown_output(block: &Block) -> Vec<String> {
    let mut out = Vec::new();
    let mut continuing = false;
    for line in &block.body {
        if continuing {
            continuing = line.trim_end().ends_with('\\');
            continue;
        }
        if line.starts_with("$ ") {
            continuing = line.trim_end().ends_with('\\');
            continue;
        }
        if !line.trim().is_empty() {
            out.push(line.trim().to_string());
        }
    }
    out
}

/// The simple commands of a command line, split at `&&`, `||`, `;` and `|` outside quotes.
fn simple_commands(line: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut current = String::new();
    let (mut single, mut double) = (false, false);
    let mut chars = line.chars().peekable();
    while let Some(c) = chars.next() {
        match c {
            '\'' if !double => single = !single,
            '"' if !single => double = !double,
            ';' | '|' | '&' if !single && !double => {
                if (c == '|' || c == '&') && chars.peek() == Some(&c) {
                    chars.next();
                } else if c == '&' {
                    current.push(c);
                    continue;
                }
                out.push(std::mem::take(&mut current));
                continue;
            }
            _ => {}
        }
        current.push(c);
    }
    out.push(current);
    out.into_iter()
        .map(|s| s.trim().to_string())
        .filter(|s| !s.is_empty())
        .collect()
}

/// Why a command may not run in this test, if it may not.
fn refusal(command: &str) -> Option<String> {
    for simple in simple_commands(command) {
        let mut words = simple.split_whitespace().peekable();
        while let Some(w) = words.peek() {
            if matches!(*w, "do" | "then" | "else") {
                words.next();
            } else {
                break;
            }
        }
        // Leading assignments (`D=…`, `FOO=bar photostereo …`).
        while words
            .peek()
            .is_some_and(|w| w.split_once('=').is_some_and(|(k, _)| is_name(k)))
        {
            words.next();
        }
        let Some(first) = words.next() else { continue };
        match first {
            "done" | "fi" => {}
            "for" => {
                let var = words.next().unwrap_or("");
                if !is_name(var) || words.next() != Some("in") {
                    return Some(format!("`{simple}`: expected `for NAME in …`"));
                }
            }
            w if ALLOWED.contains(&w) => {}
            w => {
                return Some(format!(
                    "`{w}` cannot run in this test; mark the block `<!-- not run: REASON -->`"
                ))
            }
        }
    }
    None
}

fn is_name(s: &str) -> bool {
    !s.is_empty()
        && s.chars().all(|c| c.is_ascii_alphanumeric() || c == '_')
        && !s.starts_with(|c: char| c.is_ascii_digit())
}

/// The repository root.
fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../..")
        .canonicalize()
        .unwrap()
}

/// README.md and docs/*.md, sorted.
fn doc_files() -> Vec<PathBuf> {
    let root = root();
    let mut files: Vec<PathBuf> = std::fs::read_dir(root.join("docs"))
        .unwrap()
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "md"))
        .collect();
    files.sort();
    files.insert(0, root.join("README.md"));
    files
}

/// A temporary folder laid out as the documentation expects: `work/` (the commands' folder,
/// with `my_capture/` and `rti.lp`), `shared` beside it, and `bin/photostereo`.
struct Sandbox {
    dir: tempfile::TempDir,
}

impl Sandbox {
    fn new() -> Sandbox {
        let dir = tempfile::tempdir().unwrap();
        let work = dir.path().join("work");
        let bin = dir.path().join("bin");
        std::fs::create_dir(&work).unwrap();
        std::fs::create_dir(&bin).unwrap();
        std::os::unix::fs::symlink(BIN, bin.join("photostereo")).unwrap();
        let shared = root().join("../shared");
        if shared.is_dir() {
            std::os::unix::fs::symlink(&shared, dir.path().join("shared")).unwrap();
        }
        let out = Command::new(BIN)
            .args(["synth", "sphere", "--rig", "ring8", "--size", "64"])
            .args(["-o", "my_capture", "--quiet"])
            .current_dir(&work)
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "synth failed: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        let dirs = std::fs::read_to_string(work.join("my_capture/light_directions.txt")).unwrap();
        let rows: Vec<&str> = dirs.lines().filter(|l| !l.trim().is_empty()).collect();
        let mut lp = format!("{}\n", rows.len());
        for (k, row) in rows.iter().enumerate() {
            lp.push_str(&format!("my_capture/{:03}.png {row}\n", k + 1));
        }
        std::fs::write(work.join("rti.lp"), lp).unwrap();
        Sandbox { dir }
    }

    fn work(&self) -> PathBuf {
        self.dir.path().join("work")
    }

    /// Runs `script` with bash in `work/`; the exit status (None when it was killed) and the
    /// output, stdout then stderr.
    fn run(&self, script: &str) -> (Option<i32>, String) {
        use std::os::unix::process::CommandExt;
        let path = format!(
            "{}:{}",
            self.dir.path().join("bin").display(),
            std::env::var("PATH").unwrap_or_default()
        );
        let file = self.dir.path().join("block.sh");
        std::fs::write(&file, script).unwrap();
        let out_file = self.dir.path().join("block.out");
        let err_file = self.dir.path().join("block.err");
        let mut child = Command::new("bash")
            .args(["--noprofile", "--norc", "-e", "-o", "pipefail"])
            .arg(&file)
            .current_dir(self.work())
            .env("PATH", path)
            .env("RAYON_NUM_THREADS", DOC_THREADS)
            .stdin(Stdio::null())
            .stdout(std::fs::File::create(&out_file).unwrap())
            .stderr(std::fs::File::create(&err_file).unwrap())
            .process_group(0)
            .spawn()
            .unwrap();
        let start = Instant::now();
        let status = loop {
            if let Some(s) = child.try_wait().unwrap() {
                break s.code();
            }
            if start.elapsed() > BLOCK_TIMEOUT {
                let _ = Command::new("kill")
                    .args(["-KILL", &format!("-{}", child.id())])
                    .status();
                let _ = child.wait();
                break None;
            }
            std::thread::sleep(Duration::from_millis(20));
        };
        let output = format!(
            "{}{}",
            std::fs::read_to_string(&out_file).unwrap_or_default(),
            std::fs::read_to_string(&err_file).unwrap_or_default()
        );
        (status, output)
    }
}

/// What checking one markdown file found.
#[derive(Default)]
struct Outcome {
    ran: usize,
    not_run: Vec<String>,
    failures: Vec<String>,
}

/// The last `n` lines of `text`.
fn tail(text: &str, n: usize) -> String {
    let lines: Vec<&str> = text.lines().collect();
    lines[lines.len().saturating_sub(n)..].join("\n")
}

/// Checks and runs the shell blocks of one markdown text in a fresh sandbox.
fn check_markdown(name: &str, text: &str) -> Outcome {
    let mut outcome = Outcome::default();
    let blocks = match blocks(name, text) {
        Ok(b) => b,
        Err(e) => {
            outcome.failures.push(e);
            return outcome;
        }
    };
    let mut sandbox: Option<Sandbox> = None;
    for block in blocks {
        if block.lang.is_empty()
            && block
                .body
                .iter()
                .any(|l| l.trim_start().starts_with("photostereo "))
        {
            outcome.failures.push(format!(
                "{}: an untagged block with photostereo commands: tag it `sh` to run it, or `text`",
                block.place
            ));
            continue;
        }
        if !SHELL.contains(&block.lang.as_str()) {
            continue;
        }
        if let Mark::NotRun(reason) = &block.mark {
            outcome
                .not_run
                .push(format!("{}: not run: {reason}", block.place));
            continue;
        }
        let cmds = commands(&block);
        if let Some(why) = cmds.iter().find_map(|c| refusal(c)) {
            outcome.failures.push(format!("{}: {why}", block.place));
            continue;
        }
        let script = if block.lang == "console" {
            cmds.join("\n")
        } else {
            block.body.join("\n")
        };
        let sandbox = sandbox.get_or_insert_with(Sandbox::new);
        let (status, output) = sandbox.run(&format!("{script}\n"));
        outcome.ran += 1;
        let expected = match block.mark {
            Mark::Exit(code) => code,
            _ => 0,
        };
        if status != Some(expected) {
            outcome.failures.push(format!(
                "{}: exit status {status:?}, expected {expected}\n--- block\n{script}\n--- output (last lines)\n{}",
                block.place,
                tail(&output, 20)
            ));
            continue;
        }
        if let (Mark::Exit(_), "console") = (&block.mark, block.lang.as_str()) {
            for line in shown_output(&block) {
                if !output.contains(&line) {
                    outcome.failures.push(format!(
                        "{}: the output shown is not printed: `{line}`\n--- output\n{}",
                        block.place,
                        tail(&output, 20)
                    ));
                }
            }
        }
    }
    outcome
}

#[test]
fn every_documented_command_runs() {
    let root = root();
    let files = doc_files();
    let outcomes: Vec<(String, Outcome)> = std::thread::scope(|s| {
        let handles: Vec<_> = files
            .iter()
            .map(|f| {
                let name = f.strip_prefix(&root).unwrap().display().to_string();
                let text = std::fs::read_to_string(f).unwrap();
                s.spawn(move || {
                    let o = check_markdown(&name, &text);
                    (name, o)
                })
            })
            .collect();
        handles.into_iter().map(|h| h.join().unwrap()).collect()
    });
    let mut failures = Vec::new();
    let mut ran = 0;
    for (name, o) in &outcomes {
        eprintln!("{name}: {} block(s) run", o.ran);
        for n in &o.not_run {
            eprintln!("  {n}");
        }
        ran += o.ran;
        failures.extend(o.failures.iter().cloned());
    }
    assert!(ran > 0, "no documented command ran");
    assert!(
        failures.is_empty(),
        "{} documented block(s) failed:\n\n{}",
        failures.len(),
        failures.join("\n\n")
    );
}

#[test]
fn the_readme_is_a_front_door_of_at_most_300_lines() {
    let text = std::fs::read_to_string(root().join("README.md")).unwrap();
    let lines = text.lines().count();
    assert!(lines <= 300, "README.md has {lines} lines (at most 300)");
    // The two commands come first.
    let first = blocks("README.md", &text)
        .unwrap()
        .into_iter()
        .find(|b| SHELL.contains(&b.lang.as_str()))
        .expect("a shell block");
    let cmds = commands(&first);
    assert!(
        cmds.first()
            .is_some_and(|c| c == "cargo run --release -- demo")
            && cmds.get(1).is_some_and(|c| c == "./test.sh"),
        "the README's first commands are {cmds:?}"
    );
    // And a Python quick start (run by python/tests/test_docs.py).
    assert!(blocks("README.md", &text)
        .unwrap()
        .iter()
        .any(|b| b.lang == "python"));
}

#[test]
fn blocks_honour_their_markers() {
    let md = "text\n\n<!-- not run: takes an hour -->\n```sh\ncargo bench\n```\n\n\
              <!-- expect exit 2: refused -->\n```console\n$ photostereo run nothing \\\n  -o x\n\
              error: nothing\n```\n\n```python\nprint(1)\n```\n\n```sh\n# a comment\n\
              photostereo synth --list   # scenes\n```\n";
    let b = blocks("t.md", md).unwrap();
    assert_eq!(b.len(), 4);
    assert_eq!(b[0].mark, Mark::NotRun("takes an hour".into()));
    assert_eq!(b[1].mark, Mark::Exit(2));
    assert_eq!(commands(&b[1]), ["photostereo run nothing -o x"]);
    assert_eq!(shown_output(&b[1]), ["error: nothing"]);
    assert_eq!(b[2].lang, "python");
    assert_eq!(b[3].mark, Mark::Run);
    assert_eq!(commands(&b[3]), ["photostereo synth --list"]);
    assert!(parse_mark("<!-- not run: -->").is_err());
    assert!(parse_mark("<!-- expect exit two -->").is_err());
    assert!(blocks("t.md", "```sh\nls\n").is_err());
}

#[test]
fn only_photostereo_and_harmless_shell_words_run() {
    assert_eq!(refusal("photostereo run cap -o out"), None);
    assert_eq!(
        refusal("for o in a b; do photostereo run $o -o out-$o; done"),
        None
    );
    assert_eq!(refusal("D=../shared/data && photostereo eval a b"), None);
    assert_eq!(
        refusal("P=x photostereo compare $P/owl.txt --lights 'a;b' -o y"),
        None
    );
    for cmd in [
        "cargo bench",
        "pip install .",
        "./test.sh",
        "photostereo demo && rm -rf /",
        "photostereo run a | python3 x.py",
    ] {
        assert!(refusal(cmd).is_some(), "{cmd} should need a marker");
    }
}

#[test]
fn a_documented_command_that_fails_fails_the_check() {
    let md = "```sh\nphotostereo synth --list\n```\n\n```sh\nphotostereo run no-such-folder -o out\n```\n\n\
              ```sh\ncargo build\n```\n\n```\nphotostereo run my_capture\n```\n\n\
              <!-- expect exit 2: refused -->\n```console\n$ photostereo run no-such-folder -o out\n\
              error: a message it does not print\n```\n";
    let o = check_markdown("t.md", md);
    assert_eq!(o.ran, 3);
    assert_eq!(o.failures.len(), 4, "{:#?}", o.failures);
    assert!(o.failures[0].contains("t.md:5") && o.failures[0].contains("exit status Some(2)"));
    assert!(o.failures[1].contains("`cargo` cannot run"));
    assert!(o.failures[2].contains("untagged"));
    assert!(o.failures[3].contains("not printed"));
}
