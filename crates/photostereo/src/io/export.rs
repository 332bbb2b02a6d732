//! Writing a run's output folder (CONVENTIONS.md, "The output folder of a run"). Files are
//! written into a staging folder beside the target, which is renamed into place by
//! [`OutputFolder::commit`]; dropping an uncommitted folder removes the staging folder, so an
//! interrupted or failed run never leaves half-written output behind.
//!
//! Safety of `force`: an existing target is replaced only when the same kind of command wrote
//! it there ([`OutputKind`]: a run folder by a run, an error map by an error map; the kind is
//! recorded in the [`MARKER`] file every output folder gets, and in a `tEXt` chunk of an output
//! PNG) or when it is an empty folder, and never when it is, or holds, one of the command's
//! inputs ([`check_output`]). Anything else is refused with a message saying why.
//!
//! Interruptions: staging folders (and [`OutputFile`] temporaries) in progress are registered,
//! so that a front end's SIGINT/SIGTERM handler can remove them with [`abandon_pending`]. A
//! process killed outright (SIGKILL, power loss) leaves its `.NAME.tmp-PID` behind; the next
//! output created in the same parent folder removes such leftovers of processes that no longer
//! run ([`remove_stale`]).

use crate::base::error::{param, Error, Result};
use crate::io::imageio::{write_exr_rgb, write_png16_rows};
use std::path::{Path, PathBuf};
use std::sync::{Mutex, MutexGuard};

/// The marker file in every folder photostereo writes: `force` replaces only such folders
/// (or empty ones).
pub const MARKER: &str = ".photostereo";
/// Markers of earlier versions (`demo` wrote its own).
const LEGACY_MARKERS: [&str; 1] = [".photostereo-demo"];
/// The marker line that names the kind of output (`kind: run`).
const MARKER_KIND: &str = "kind: ";
/// The `tEXt` keyword of an output PNG that names its kind.
const PNG_KIND_KEYWORD: &str = "photostereo-output";

/// What wrote an output folder or file. `force` replaces an existing output only when the same
/// kind wrote it: a run never replaces a synthetic capture, an error map never replaces a
/// photograph, an OpenLIME export never replaces a run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum OutputKind {
    /// A reconstruction's output folder (`run`).
    Run,
    /// A synthetic capture with its ground truth (`synth`).
    Synth,
    /// The demo's tables and figures.
    Demo,
    /// A comparison of methods (`compare`).
    Compare,
    /// A light calibration from a mirror sphere (`calibrate`).
    Calibration,
    /// Depth integrated from a normal map (`integrate`).
    Integration,
    /// An OpenLIME page exported from a run (`export-openlime`).
    OpenLime,
    /// A colour-mapped angular-error picture (`eval --error-map`).
    ErrorMap,
    /// Relightable-image files fitted to a capture (`rti`).
    Rti,
}

impl OutputKind {
    const ALL: [OutputKind; 9] = [
        OutputKind::Run,
        OutputKind::Synth,
        OutputKind::Demo,
        OutputKind::Compare,
        OutputKind::Calibration,
        OutputKind::Integration,
        OutputKind::OpenLime,
        OutputKind::ErrorMap,
        OutputKind::Rti,
    ];

    /// The name recorded in markers and PNG chunks.
    pub fn name(self) -> &'static str {
        match self {
            OutputKind::Run => "run",
            OutputKind::Synth => "synth",
            OutputKind::Demo => "demo",
            OutputKind::Compare => "compare",
            OutputKind::Calibration => "calibration",
            OutputKind::Integration => "integration",
            OutputKind::OpenLime => "openlime",
            OutputKind::ErrorMap => "error-map",
            OutputKind::Rti => "rti",
        }
    }

    /// "a" or "an", as the name reads.
    fn article(self) -> &'static str {
        if self.name().starts_with(['a', 'e', 'i', 'o', 'u']) {
            "an"
        } else {
            "a"
        }
    }

    fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|k| k.name() == name.trim())
    }
}

/// The kind of output recorded in `dir`'s marker: `None` where there is no marker or it names
/// no kind (markers of versions that did not record it).
pub fn marker_kind(dir: &Path) -> Option<OutputKind> {
    if dir.join(LEGACY_MARKERS[0]).is_file() {
        return Some(OutputKind::Demo);
    }
    let text = std::fs::read_to_string(dir.join(MARKER)).ok()?;
    text.lines()
        .find_map(|l| l.strip_prefix(MARKER_KIND))
        .and_then(OutputKind::from_name)
}

/// Staging folders and temporary files of this process not yet committed.
static PENDING: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());

fn pending() -> MutexGuard<'static, Vec<PathBuf>> {
    PENDING.lock().unwrap_or_else(|e| e.into_inner())
}

fn register(path: &Path) {
    pending().push(path.to_path_buf());
}

fn deregister(path: &Path) {
    pending().retain(|p| p != path);
}

/// Removes every staging folder and temporary file in progress and keeps them from being
/// written again: the registry stays locked, so a thread that would commit or clean up blocks.
/// For a signal handler that ends the process right after. Returns how many were removed.
pub fn abandon_pending() -> usize {
    let guard = pending();
    let mut removed = 0;
    for p in guard.iter() {
        // A writer may still be creating files inside: try a few times.
        for attempt in 0..20 {
            if attempt > 0 {
                std::thread::sleep(std::time::Duration::from_millis(5));
            }
            let r = if p.is_dir() {
                std::fs::remove_dir_all(p)
            } else {
                std::fs::remove_file(p)
            };
            if r.is_ok() || !p.exists() {
                removed += 1;
                break;
            }
        }
    }
    std::mem::forget(guard);
    removed
}

/// Whether `dir` holds the marker of a folder photostereo wrote.
pub fn has_marker(dir: &Path) -> bool {
    std::iter::once(MARKER)
        .chain(LEGACY_MARKERS)
        .any(|m| dir.join(m).is_file())
}

/// `path` made absolute and, where it exists, with symbolic links resolved.
fn resolved(path: &Path) -> PathBuf {
    if let Ok(p) = std::fs::canonicalize(path) {
        return p;
    }
    let abs = if path.is_absolute() {
        path.to_path_buf()
    } else {
        std::env::current_dir()
            .map(|d| d.join(path))
            .unwrap_or_else(|_| path.to_path_buf())
    };
    // Resolve the longest existing ancestor, keep the rest as written.
    let mut tail = Vec::new();
    let mut head = abs.as_path();
    while let Some(parent) = head.parent() {
        if let Ok(p) = std::fs::canonicalize(head) {
            let mut out = p;
            for t in tail.iter().rev() {
                out.push(t);
            }
            return out;
        }
        if let Some(name) = head.file_name() {
            tail.push(name.to_os_string());
        }
        head = parent;
    }
    abs
}

/// Checks that `target` may be written as a `kind` folder: refused when it exists and `force` is
/// off; with `force`, refused unless it is a folder the same kind of command wrote (its
/// [`MARKER`] names `kind`) or an empty folder, and refused whenever it is one of `inputs` or
/// holds one. Errors say why.
pub fn check_output(target: &Path, force: bool, kind: OutputKind, inputs: &[&Path]) -> Result<()> {
    let meta = match std::fs::symlink_metadata(target) {
        Ok(m) => m,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(()),
        Err(e) => return Err(Error::io(target, e)),
    };
    if !force {
        return Err(Error::OutputExists {
            path: target.to_path_buf(),
        });
    }
    let why = |m: String| {
        Err(Error::file(
            target,
            format!("{} refused: {m}", param("force")),
        ))
    };
    let t = resolved(target);
    for input in inputs {
        let i = resolved(input);
        if i == t {
            return why(format!(
                "it is an input of this command; choose another output ({})",
                param("output")
            ));
        }
        if i.starts_with(&t) {
            return why(format!(
                "it holds an input of this command ({}); choose another output ({})",
                input.display(),
                param("output")
            ));
        }
    }
    if meta.file_type().is_symlink() {
        return why(format!(
            "it is a symbolic link; {} replaces only a folder that photostereo wrote or an empty folder",
            param("force")
        ));
    }
    if !meta.is_dir() {
        return why(format!(
            "it is a file, not a folder; {} replaces only a folder that photostereo wrote or an empty folder",
            param("force")
        ));
    }
    if has_marker(target) {
        return match marker_kind(target) {
            Some(k) if k == kind => Ok(()),
            Some(k) => why(format!(
                "it holds {} {} folder, and {} replaces only {} {} folder; \
                 choose another output ({})",
                k.article(),
                k.name(),
                param("force"),
                kind.article(),
                kind.name(),
                param("output")
            )),
            None => why(format!(
                "an earlier photostereo wrote it without recording what it holds, and {} \
                 replaces only {} {} folder; remove it yourself or choose another output ({})",
                param("force"),
                kind.article(),
                kind.name(),
                param("output")
            )),
        };
    }
    let empty = std::fs::read_dir(target)
        .map_err(|e| Error::io(target, e))?
        .next()
        .is_none();
    if empty {
        return Ok(());
    }
    why(format!(
        "the folder was not written by photostereo (it has no {MARKER} marker) and is not empty; \
         remove it yourself or choose another output ({})",
        param("output")
    ))
}

/// The parent folder of `target` ("." for a bare name).
fn parent_of(target: &Path) -> PathBuf {
    match target.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    }
}

/// Whether a process with this id is running (conservatively true where it cannot be told).
fn process_alive(pid: u32) -> bool {
    if pid == std::process::id() {
        return true;
    }
    #[cfg(unix)]
    {
        let Ok(p) = libc::pid_t::try_from(pid) else {
            return false;
        };
        if p <= 0 {
            return false;
        }
        // SAFETY: kill with signal 0 only checks whether the process exists.
        let r = unsafe { libc::kill(p, 0) };
        r == 0 || std::io::Error::last_os_error().raw_os_error() != Some(libc::ESRCH)
    }
    #[cfg(not(unix))]
    {
        true
    }
}

/// Splits `.NAME.tmp-PID` / `.NAME.old-PID` into (NAME, kind, PID).
fn leftover_name(file_name: &str) -> Option<(&str, &str, u32)> {
    let rest = file_name.strip_prefix('.')?;
    let (head, pid) = rest.rsplit_once('-')?;
    let pid: u32 = pid.parse().ok()?;
    let (name, kind) = head.rsplit_once('.')?;
    (matches!(kind, "tmp" | "old") && !name.is_empty()).then_some((name, kind, pid))
}

/// Removes, in `parent`, the staging folders (`.NAME.tmp-PID`) and temporary files of
/// photostereo processes that no longer run, and puts back a `.NAME.old-PID` folder whose
/// replacement was cut short (when NAME is missing). Only entries photostereo made are touched
/// (folders with the marker or empty; files that are PNGs photostereo wrote). Returns what was
/// removed or restored.
pub fn remove_stale(parent: &Path) -> Vec<PathBuf> {
    let mut done = Vec::new();
    let Ok(entries) = std::fs::read_dir(parent) else {
        return done;
    };
    for e in entries.flatten() {
        let file_name = e.file_name();
        let Some((name, kind, pid)) = file_name.to_str().and_then(leftover_name) else {
            continue;
        };
        if process_alive(pid) {
            continue;
        }
        let path = e.path();
        let Ok(meta) = std::fs::symlink_metadata(&path) else {
            continue;
        };
        let ours = if meta.is_dir() {
            if has_marker(&path) {
                // A process id means nothing on another machine sharing this folder.
                std::fs::read_to_string(path.join(MARKER))
                    .map_or(true, |t| marker_host(&t).is_none_or(|h| h == host_name()))
            } else {
                // Empty, and not just made by a process (maybe on another machine) that is
                // about to write its marker.
                std::fs::read_dir(&path).is_ok_and(|mut d| d.next().is_none())
                    && meta
                        .modified()
                        .ok()
                        .and_then(|m| m.elapsed().ok())
                        .is_some_and(|age| age.as_secs() >= 60)
            }
        } else {
            meta.is_file() && written_by_photostereo(&path)
        };
        if !ours {
            continue;
        }
        let original = parent.join(name);
        let ok = if kind == "old" && std::fs::symlink_metadata(&original).is_err() {
            std::fs::rename(&path, &original).is_ok()
        } else if meta.is_dir() {
            std::fs::remove_dir_all(&path).is_ok()
        } else {
            std::fs::remove_file(&path).is_ok()
        };
        if ok {
            done.push(path);
        }
    }
    done
}

/// This machine's name, as the marker records it ("" where unknown).
fn host_name() -> String {
    #[cfg(unix)]
    {
        let mut buf = [0u8; 256];
        // SAFETY: the buffer is valid for its length; the result is NUL-terminated or cut.
        if unsafe { libc::gethostname(buf.as_mut_ptr().cast(), buf.len()) } == 0 {
            let end = buf.iter().position(|&b| b == 0).unwrap_or(buf.len());
            return String::from_utf8_lossy(&buf[..end]).into_owned();
        }
    }
    std::env::var("COMPUTERNAME").unwrap_or_default()
}

/// The host a marker's text names ("… on host NAME (process …)").
fn marker_host(text: &str) -> Option<&str> {
    let rest = text.split_once(" on host ")?.1;
    Some(rest.split(" (process").next().unwrap_or(rest).trim())
}

/// A staging folder that becomes the output folder on [`commit`](OutputFolder::commit).
#[derive(Debug)]
pub struct OutputFolder {
    target: PathBuf,
    staging: PathBuf,
    force: bool,
    kind: OutputKind,
    committed: bool,
    /// Leftovers of interrupted runs removed when this folder was created.
    pub removed_stale: Vec<PathBuf>,
}

impl OutputFolder {
    /// Prepares writing a `kind` folder to `target` (see [`check_output`] for what `force` may
    /// replace).
    pub fn create(target: &Path, force: bool, kind: OutputKind) -> Result<Self> {
        Self::create_for(target, force, kind, &[])
    }

    /// Prepares writing a `kind` folder to `target`, refusing to replace any of `inputs` or a
    /// folder holding one (see [`check_output`]).
    pub fn create_for(
        target: &Path,
        force: bool,
        kind: OutputKind,
        inputs: &[&Path],
    ) -> Result<Self> {
        check_output(target, force, kind, inputs)?;
        let name = target
            .file_name()
            .filter(|n| *n != "." && *n != "..")
            .ok_or_else(|| Error::file(target, "not a valid output folder name"))?
            .to_string_lossy()
            .to_string();
        let parent = parent_of(target);
        if !parent.is_dir() {
            return Err(Error::file(
                &parent,
                "the output folder's parent does not exist",
            ));
        }
        let removed_stale = remove_stale(&parent);
        let staging = parent.join(format!(".{name}.tmp-{}", std::process::id()));
        if staging.exists() {
            std::fs::remove_dir_all(&staging).map_err(|e| Error::io(&staging, e))?;
        }
        // The user named the target: a parent they cannot write in is reported on it.
        std::fs::create_dir(&staging).map_err(|e| {
            Error::file(
                target,
                format!("cannot write the output in {}: {e}", parent.display()),
            )
        })?;
        register(&staging);
        let folder = OutputFolder {
            target: target.to_path_buf(),
            staging,
            force,
            kind,
            committed: false,
            removed_stale,
        };
        std::fs::write(
            folder.file(MARKER),
            format!(
                "written by photostereo {} on host {} (process {}); photostereo may replace this folder when forced\n\
                 {MARKER_KIND}{}\n",
                env!("CARGO_PKG_VERSION"),
                host_name(),
                std::process::id(),
                kind.name()
            ),
        )
        .map_err(|e| Error::io(folder.file(MARKER), e))?;
        Ok(folder)
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
        // Hold the registry while renaming, so that a signal handler waits until the folders
        // are in a consistent state.
        let mut guard = pending();
        if std::fs::symlink_metadata(&self.target).is_ok() {
            check_output(&self.target, self.force, self.kind, &[])?;
            let old = self.staging.with_file_name(format!(
                ".{}.old-{}",
                self.target
                    .file_name()
                    .unwrap_or_default()
                    .to_string_lossy(),
                std::process::id()
            ));
            std::fs::rename(&self.target, &old).map_err(|e| Error::io(&self.target, e))?;
            if let Err(e) = std::fs::rename(&self.staging, &self.target) {
                let _ = std::fs::rename(&old, &self.target);
                return Err(Error::io(&self.target, e));
            }
            let _ = if old.is_dir() {
                std::fs::remove_dir_all(&old)
            } else {
                std::fs::remove_file(&old)
            };
        } else {
            std::fs::rename(&self.staging, &self.target).map_err(|e| Error::io(&self.target, e))?;
        }
        guard.retain(|p| *p != self.staging);
        drop(guard);
        self.committed = true;
        Ok(self.target.clone())
    }
}

impl Drop for OutputFolder {
    fn drop(&mut self) {
        if !self.committed {
            let _ = std::fs::remove_dir_all(&self.staging);
            deregister(&self.staging);
        }
    }
}

/// One output PNG written under a temporary name beside it (`.NAME.tmp-PID`) and renamed into
/// place by [`commit`](OutputFile::commit), which first records its [`OutputKind`] in a `tEXt`
/// chunk; removed when dropped uncommitted or on a signal. `force` replaces an existing file
/// only when it is a PNG that the same kind of command wrote (or empty), and never one of the
/// inputs.
#[derive(Debug)]
pub struct OutputFile {
    target: PathBuf,
    temp: PathBuf,
    force: bool,
    kind: OutputKind,
    committed: bool,
}

impl OutputFile {
    /// Prepares writing the PNG `target` as a `kind` file.
    pub fn create(target: &Path, force: bool, kind: OutputKind, inputs: &[&Path]) -> Result<Self> {
        check_output_file(target, force, kind, inputs)?;
        let name = target
            .file_name()
            .ok_or_else(|| Error::file(target, "not a valid output file name"))?
            .to_string_lossy()
            .to_string();
        let parent = parent_of(target);
        if !parent.is_dir() {
            return Err(Error::file(
                &parent,
                "the output file's folder does not exist",
            ));
        }
        remove_stale(&parent);
        let temp = parent.join(format!(".{name}.tmp-{}", std::process::id()));
        register(&temp);
        Ok(OutputFile {
            target: target.to_path_buf(),
            temp,
            force,
            kind,
            committed: false,
        })
    }

    /// Where to write until commit.
    pub fn path(&self) -> &Path {
        &self.temp
    }

    /// Records the file's kind in it and renames it into place.
    pub fn commit(mut self) -> Result<PathBuf> {
        tag_png(&self.temp, self.kind)?;
        let mut guard = pending();
        check_output_file(&self.target, self.force, self.kind, &[])?;
        std::fs::rename(&self.temp, &self.target).map_err(|e| Error::io(&self.target, e))?;
        guard.retain(|p| *p != self.temp);
        drop(guard);
        self.committed = true;
        Ok(self.target.clone())
    }
}

impl Drop for OutputFile {
    fn drop(&mut self) {
        if !self.committed {
            let _ = std::fs::remove_file(&self.temp);
            deregister(&self.temp);
        }
    }
}

fn check_output_file(target: &Path, force: bool, kind: OutputKind, inputs: &[&Path]) -> Result<()> {
    let meta = match std::fs::symlink_metadata(target) {
        Ok(m) => m,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(()),
        Err(e) => return Err(Error::io(target, e)),
    };
    if !force {
        return Err(Error::OutputExists {
            path: target.to_path_buf(),
        });
    }
    let why = |m: &str| {
        Err(Error::file(
            target,
            format!("{} refused: {m}", param("force")),
        ))
    };
    let t = resolved(target);
    if inputs.iter().any(|i| resolved(i) == t) {
        return why("it is an input of this command; choose another output file");
    }
    if !meta.is_file() {
        return why("it is not a regular file");
    }
    if meta.len() == 0 || png_kind(target) == Some(kind) {
        return Ok(());
    }
    let replaces = format!(
        "{} replaces only a PNG that photostereo wrote as {}",
        param("force"),
        kind.name()
    );
    match png_kind(target) {
        Some(k) => why(&format!(
            "photostereo wrote it as {}; {replaces}; choose another name",
            k.name()
        )),
        None if written_by_photostereo(target) => why(&format!(
            "photostereo wrote it as part of another output; {replaces}; choose another name"
        )),
        None => why(&format!(
            "photostereo did not write it; {replaces}; remove it yourself or choose another name"
        )),
    }
}

/// The PNG chunks before the image data of `path` (at most the first 64 KiB): `(type, body)`.
fn png_head_chunks(path: &Path) -> Vec<([u8; 4], Vec<u8>)> {
    use std::io::Read;
    let mut head = Vec::new();
    let Ok(f) = std::fs::File::open(path) else {
        return Vec::new();
    };
    if f.take(1 << 16).read_to_end(&mut head).is_err() || !head.starts_with(b"\x89PNG\r\n\x1a\n") {
        return Vec::new();
    }
    let mut chunks = Vec::new();
    let mut pos = 8;
    while pos + 8 <= head.len() {
        let len =
            u32::from_be_bytes([head[pos], head[pos + 1], head[pos + 2], head[pos + 3]]) as usize;
        let kind = [head[pos + 4], head[pos + 5], head[pos + 6], head[pos + 7]];
        let Some(body) = head.get(pos + 8..(pos + 8).saturating_add(len)) else {
            break;
        };
        if &kind == b"IDAT" {
            break;
        }
        chunks.push((kind, body.to_vec()));
        pos += 12 + len;
    }
    chunks
}

/// The [`OutputKind`] an output PNG records in its `photostereo-output` text chunk.
pub fn png_kind(path: &Path) -> Option<OutputKind> {
    let key = format!("{PNG_KIND_KEYWORD}\0");
    png_head_chunks(path).into_iter().find_map(|(kind, body)| {
        let value = body
            .strip_prefix(key.as_bytes())
            .filter(|_| &kind == b"tEXt")?;
        OutputKind::from_name(std::str::from_utf8(value).ok()?)
    })
}

/// Inserts a `tEXt` chunk recording `kind` after the header of the PNG at `path`.
fn tag_png(path: &Path, kind: OutputKind) -> Result<()> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    // Signature (8) + IHDR (length 4, type 4, body 13, CRC 4).
    const AFTER_IHDR: usize = 8 + 25;
    if bytes.len() < AFTER_IHDR || &bytes[12..16] != b"IHDR" {
        return Err(Error::file(path, "not a PNG written here"));
    }
    let body = format!("{PNG_KIND_KEYWORD}\0{}", kind.name());
    let mut chunk = Vec::with_capacity(body.len() + 12);
    chunk.extend_from_slice(&(body.len() as u32).to_be_bytes());
    chunk.extend_from_slice(b"tEXt");
    chunk.extend_from_slice(body.as_bytes());
    let crc = crc32fast::hash(&chunk[4..]);
    chunk.extend_from_slice(&crc.to_be_bytes());
    let mut out = Vec::with_capacity(bytes.len() + chunk.len());
    out.extend_from_slice(&bytes[..AFTER_IHDR]);
    out.extend_from_slice(&chunk);
    out.extend_from_slice(&bytes[AFTER_IHDR..]);
    std::fs::write(path, out).map_err(|e| Error::io(path, e))
}

/// Whether `path` is a PNG photostereo wrote (a `Software` text chunk naming it, before the
/// image data).
pub fn written_by_photostereo(path: &Path) -> bool {
    png_head_chunks(path).iter().any(|(kind, body)| {
        kind == b"tEXt" && body.starts_with(crate::io::imageio::PNG_SOFTWARE_TEXT)
    })
}

/// Writes `normals.npy` (float32 (H, W, 3)), `normals.png` (16-bit RGB, (n + 1) / 2 · 65535,
/// black outside the mask) and `normals.exr` into `dir`. `normals` is `height * width` row-major;
/// zero vectors mark pixels outside the mask.
pub fn write_normals(dir: &Path, width: usize, height: usize, normals: &[[f32; 3]]) -> Result<()> {
    let flat: &[f32] = normals.as_flattened();
    write_npy_f32(&dir.join("normals.npy"), &[height, width, 3], flat)?;
    write_png16_rows(&dir.join("normals.png"), width, height, 3, |r, out| {
        for (o, n) in out
            .chunks_exact_mut(3)
            .zip(&normals[r * width..(r + 1) * width])
        {
            if *n == [0.0; 3] {
                o.fill(0);
            } else {
                for (v, &c) in o.iter_mut().zip(n) {
                    *v = (((c + 1.0) * 0.5).clamp(0.0, 1.0) * 65535.0).round() as u16;
                }
            }
        }
    })?;
    write_exr_rgb(&dir.join("normals.exr"), width, height, flat)
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
    // The 99.5th percentile of the mask's finite values, selected without a copy of them.
    let inside = |visit: &mut dyn FnMut(f32)| {
        for (v, _) in albedo.chunks_exact(channels).zip(mask).filter(|(_, &m)| m) {
            v.iter()
                .copied()
                .filter(|x| x.is_finite())
                .for_each(&mut *visit);
        }
    };
    let top = match crate::solve::metrics::select_by_total_order(&inside, 0.995) {
        Some(v) if v > 0.0 => v,
        _ => 1.0,
    };
    let row = width * channels;
    write_png16_rows(
        &dir.join("albedo.png"),
        width,
        height,
        channels,
        |r, out| {
            for (o, v) in out.iter_mut().zip(&albedo[r * row..(r + 1) * row]) {
                *o = ((v / top).clamp(0.0, 1.0) * 65535.0).round() as u16;
            }
        },
    )
}

/// Writes a float32 `.npy` array of the given shape (C order).
pub fn write_npy_f32(path: &Path, shape: &[usize], data: &[f32]) -> Result<()> {
    // A view of the caller's data: no second copy of the array.
    let arr = ndarray::ArrayViewD::from_shape(ndarray::IxDyn(shape), data)
        .map_err(|e| Error::invalid(format!("array shape {shape:?}: {e}")))?;
    ndarray_npy::write_npy(path, &arr)
        .map_err(|e| Error::file(path, format!("writing .npy failed: {e}")))
}

/// Writes a uint8 `.npy` array of the given shape (C order).
pub fn write_npy_u8(path: &Path, shape: &[usize], data: &[u8]) -> Result<()> {
    // A view of the caller's data: no second copy of the array.
    let arr = ndarray::ArrayViewD::from_shape(ndarray::IxDyn(shape), data)
        .map_err(|e| Error::invalid(format!("array shape {shape:?}: {e}")))?;
    ndarray_npy::write_npy(path, &arr)
        .map_err(|e| Error::file(path, format!("writing .npy failed: {e}")))
}

/// Writes a uint8 `.npy` array of the given shape (C order) plane by plane: `plane(k, out)`
/// fills `out` with the `k`-th of the `shape[0]` planes (`shape[1..]` elements each), so that
/// only one plane is held at a time. The file is the one [`write_npy_u8`] writes.
pub fn write_npy_u8_planes(
    path: &Path,
    shape: &[usize],
    mut plane: impl FnMut(usize, &mut Vec<u8>),
) -> Result<()> {
    use std::io::Write;
    let io = |e: std::io::Error| Error::file(path, format!("writing .npy failed: {e}"));
    let (&planes, rest) = shape
        .split_first()
        .ok_or_else(|| Error::invalid("a plane-wise array needs at least one dimension"))?;
    let per_plane: usize = rest.iter().product();
    let mut file = std::io::BufWriter::new(std::fs::File::create(path).map_err(io)?);
    file.write_all(&npy_header("|u1", shape)).map_err(io)?;
    let mut buf = Vec::with_capacity(per_plane);
    for k in 0..planes {
        buf.clear();
        plane(k, &mut buf);
        if buf.len() != per_plane {
            return Err(Error::invalid(format!(
                "plane {k} of {shape:?}: {} values, expected {per_plane}",
                buf.len()
            )));
        }
        file.write_all(&buf).map_err(io)?;
    }
    file.flush().map_err(io)
}

/// The header of a C-order `.npy` array of `shape` whose elements have the NumPy type string
/// `descr` (`<f4`, `|u1`), as NPY format 1.0 lays it out: the magic `\x93NUMPY`, version 1.0,
/// the header's length (u16, little-endian), then the header dictionary padded with spaces
/// and ended by a newline so that the data starts at a multiple of 64 bytes; the data follows.
/// The bytes are those `ndarray-npy` writes, but for a dictionary that ends exactly on the
/// boundary: NumPy and `ndarray-npy` then pad a further 64 bytes, here none (both valid).
pub(crate) fn npy_header(descr: &str, shape: &[usize]) -> Vec<u8> {
    let dims: Vec<String> = shape.iter().map(|d| d.to_string()).collect();
    let shape_text = if dims.len() == 1 {
        format!("({},)", dims[0])
    } else {
        format!("({})", dims.join(", "))
    };
    let mut header =
        format!("{{'descr': '{descr}', 'fortran_order': False, 'shape': {shape_text}}}");
    let unpadded = 10 + header.len() + 1;
    header.push_str(&" ".repeat(unpadded.next_multiple_of(64) - unpadded));
    header.push('\n');
    let mut out = b"\x93NUMPY\x01\x00".to_vec();
    out.extend_from_slice(&(header.len() as u16).to_le_bytes());
    out.extend_from_slice(header.as_bytes());
    out
}

/// Writes a bool `.npy` array of the given shape (C order).
pub fn write_npy_bool(path: &Path, shape: &[usize], data: &[bool]) -> Result<()> {
    // A view of the caller's data: no second copy of the array.
    let arr = ndarray::ArrayViewD::from_shape(ndarray::IxDyn(shape), data)
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
    fn plane_wise_npy_is_the_file_of_the_whole_array() {
        let dir = tempfile::tempdir().unwrap();
        for shape in [
            vec![3usize, 2, 5],
            vec![1, 4, 4],
            vec![7],
            vec![2, 33, 17, 3],
        ] {
            let total: usize = shape.iter().product();
            let data: Vec<u8> = (0..total).map(|i| (i * 37 % 251) as u8).collect();
            let (a, b) = (dir.path().join("whole.npy"), dir.path().join("planes.npy"));
            write_npy_u8(&a, &shape, &data).unwrap();
            let per = total / shape[0];
            write_npy_u8_planes(&b, &shape, |k, out| {
                out.extend_from_slice(&data[k * per..(k + 1) * per])
            })
            .unwrap();
            assert_eq!(
                std::fs::read(&a).unwrap(),
                std::fs::read(&b).unwrap(),
                "{shape:?}"
            );
        }
        // A plane of the wrong size is an error, not a malformed file.
        let c = dir.path().join("short.npy");
        let e = write_npy_u8_planes(&c, &[2, 3], |_, out| out.push(0)).unwrap_err();
        assert!(e.to_string().contains("expected 3"), "{e}");
    }

    #[test]
    fn npy_headers_follow_the_format_and_match_ndarray_npy() {
        // NPY format 1.0 (numpy.lib.format): magic, version 1.0, header length, then the
        // dictionary literal, space-padded, newline-ended, the data 64-byte aligned.
        let h = npy_header("<f4", &[2, 3]);
        let dict = "{'descr': '<f4', 'fortran_order': False, 'shape': (2, 3)}";
        let mut want = b"\x93NUMPY\x01\x00".to_vec();
        want.extend_from_slice(&[118, 0]);
        want.extend_from_slice(dict.as_bytes());
        want.extend(std::iter::repeat_n(b' ', 128 - 10 - dict.len() - 1));
        want.push(b'\n');
        assert_eq!((h.len(), &h), (128, &want));
        assert!(String::from_utf8_lossy(&npy_header("|u1", &[7])).contains("'shape': (7,)}"));
        // An independent writer (ndarray-npy) writes the same bytes before the data.
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.npy");
        for shape in [vec![5usize], vec![4, 3, 2], vec![8000, 6000, 3, 9]] {
            let n: usize = shape.iter().product::<usize>().min(64);
            if n == shape.iter().product::<usize>() {
                write_npy_f32(&p, &shape, &vec![0.5; n]).unwrap();
                let head = npy_header("<f4", &shape);
                assert_eq!(
                    &std::fs::read(&p).unwrap()[..head.len()],
                    &head[..],
                    "{shape:?}"
                );
                write_npy_u8(&p, &shape, &vec![1; n]).unwrap();
                let head = npy_header("|u1", &shape);
                assert_eq!(
                    &std::fs::read(&p).unwrap()[..head.len()],
                    &head[..],
                    "{shape:?}"
                );
            }
            assert_eq!(npy_header("<f4", &shape).len() % 64, 0, "{shape:?}");
        }
    }

    #[test]
    fn leftover_names_and_marker_hosts() {
        assert_eq!(leftover_name(".out.tmp-123"), Some(("out", "tmp", 123)));
        assert_eq!(leftover_name(".my.out.old-7"), Some(("my.out", "old", 7)));
        assert_eq!(leftover_name(".out.tmp-x"), None);
        assert_eq!(leftover_name("out.tmp-1"), None);
        assert_eq!(leftover_name(".out.bak-1"), None);
        let text = "written by photostereo 0.1.0 on host lab-3 (process 42); …";
        assert_eq!(marker_host(text), Some("lab-3"));
        assert_eq!(marker_host("written by photostereo demo"), None);
    }

    #[test]
    fn stale_folders_of_other_hosts_are_kept() {
        let dir = tempfile::tempdir().unwrap();
        let mut dead = std::process::Command::new("true").spawn().unwrap();
        let pid = dead.id();
        dead.wait().unwrap();
        let mine = dir.path().join(format!(".a.tmp-{pid}"));
        let theirs = dir.path().join(format!(".b.tmp-{pid}"));
        for (d, host) in [(&mine, host_name()), (&theirs, "elsewhere".to_string())] {
            std::fs::create_dir(d).unwrap();
            std::fs::write(
                d.join(MARKER),
                format!("written by photostereo on host {host} (process {pid})"),
            )
            .unwrap();
        }
        let removed = remove_stale(dir.path());
        assert_eq!(removed, vec![mine.clone()]);
        assert!(!mine.exists() && theirs.exists());
    }

    #[test]
    fn staging_is_removed_unless_committed_and_force_is_required() {
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("out");
        {
            let f = OutputFolder::create(&target, false, OutputKind::Run).unwrap();
            std::fs::write(f.file("a.txt"), "x").unwrap();
        }
        assert!(!target.exists());
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
        let f = OutputFolder::create(&target, false, OutputKind::Run).unwrap();
        std::fs::write(f.file("a.txt"), "x").unwrap();
        f.commit().unwrap();
        assert!(target.join("a.txt").exists());
        assert!(matches!(
            OutputFolder::create(&target, false, OutputKind::Run),
            Err(Error::OutputExists { .. })
        ));
        let f = OutputFolder::create(&target, true, OutputKind::Run).unwrap();
        std::fs::write(f.file("b.txt"), "y").unwrap();
        f.commit().unwrap();
        assert!(target.join("b.txt").exists() && !target.join("a.txt").exists());
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    }

    #[test]
    fn an_output_png_records_its_kind_in_a_chunk_other_decoders_read() {
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("err.png");
        let f = OutputFile::create(&target, false, OutputKind::ErrorMap, &[]).unwrap();
        crate::io::imageio::write_png8(f.path(), 3, 2, 1, &[0, 50, 100, 150, 200, 250]).unwrap();
        f.commit().unwrap();
        assert_eq!(png_kind(&target), Some(OutputKind::ErrorMap));
        // The png crate checks every chunk's CRC and reads the text chunk back.
        let mut dec = png::Decoder::new(std::io::BufReader::new(
            std::fs::File::open(&target).unwrap(),
        ));
        dec.set_ignore_text_chunk(false);
        let mut reader = dec.read_info().unwrap();
        let mut buf = vec![0; reader.output_buffer_size().unwrap()];
        reader.next_frame(&mut buf).unwrap();
        let texts: Vec<(String, String)> = reader
            .info()
            .uncompressed_latin1_text
            .iter()
            .map(|t| (t.keyword.clone(), t.text.clone()))
            .collect();
        assert!(texts.contains(&("photostereo-output".into(), "error-map".into())));
        assert_eq!(&buf[..6], &[0, 50, 100, 150, 200, 250]);
        // A PNG of another kind is not replaced, even with force; its own kind is.
        assert!(OutputFile::create(&target, true, OutputKind::Run, &[]).is_err());
        assert!(OutputFile::create(&target, true, OutputKind::ErrorMap, &[]).is_ok());
    }
}
