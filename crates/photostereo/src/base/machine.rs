//! The machine the library runs on: the memory available (`/proc/meminfo`'s `MemAvailable` and,
//! inside a container, the cgroup's `memory.max` − `memory.current`; where neither can be read,
//! no limit is known), the cap a user sets through [`MEMORY_LIMIT_VAR`] (bytes, or with a `K`,
//! `M`, `G` or `T` suffix, powers of 1024), the process's peak resident memory, and the
//! allocator setting a long run within a budget wants.

/// Environment variable that caps the memory the readers may plan for (e.g. `8G`).
pub const MEMORY_LIMIT_VAR: &str = "PHOTOSTEREO_MAX_MEMORY";

/// Makes the C allocator hand large freed blocks back to the system at once (glibc: a fixed
/// `mmap` threshold of 1 MiB; elsewhere nothing). By default glibc raises that threshold to
/// the largest block freed so far (up to 32 MiB), after which full-frame maps of a large capture
/// come from its heap and stay resident when freed; the process's peak resident memory then
/// exceeds what the run holds at any moment by a third or more. The price is system time for
/// fresh pages (about 10% of a whole run on DiLiGenT cat), so a capture loaded into tiles
/// (a run within a budget) sets it, one held whole does not. Process-wide and lasting: the
/// loader calls it only when [`crate::io::layouts::LoadOptions::return_freed_memory_when_tiled`]
/// asks (the command line does; a host process such as Python's keeps its own allocator
/// settings).
pub fn return_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only sets allocator parameters (glibc serialises it with the arenas).
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 1 << 20);
    }
}

/// Caps glibc's arenas at [`MALLOC_ARENAS`], whatever the thread count. By default each thread
/// that allocates may get an arena of its own (up to 8 per core), and the freed blocks below
/// the `mmap` threshold that each arena keeps add up with the threads: at 16 threads a run
/// peaks a third above its peak at 2 on the same capture, which a memory plan made per pixel
/// cannot see. Arenas made before the call stay (and glibc fixes its limit once it has made
/// more than 8), so only a program that owns its process calls this, first thing, before any
/// other thread runs (the command line does; a host process such as Python's keeps its own
/// allocator settings).
pub fn cap_allocator_arenas() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only sets allocator parameters.
    unsafe {
        libc::mallopt(libc::M_ARENA_MAX, MALLOC_ARENAS);
    }
}

/// The most arenas glibc makes once [`cap_allocator_arenas`] has run: a fixed count, so that
/// what the allocator keeps is the same on any machine.
pub const MALLOC_ARENAS: i32 = 1;

/// Bytes the process may still allocate: the least of `MemAvailable`, the cgroup's headroom and
/// [`MEMORY_LIMIT_VAR`]; `None` when none of them is known.
pub fn available_memory() -> Option<u64> {
    let mut best: Option<u64> = None;
    let mut take = |v: Option<u64>| {
        if let Some(v) = v {
            best = Some(best.map_or(v, |b| b.min(v)));
        }
    };
    take(meminfo_available());
    take(cgroup_headroom());
    take(
        std::env::var(MEMORY_LIMIT_VAR)
            .ok()
            .and_then(|s| parse_bytes(&s)),
    );
    best
}

fn meminfo_available() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    kb.checked_mul(1024)
}

fn cgroup_headroom() -> Option<u64> {
    let max = std::fs::read_to_string("/sys/fs/cgroup/memory.max").ok()?;
    let max: u64 = max.trim().parse().ok()?; // "max" = no limit
    let current: u64 = std::fs::read_to_string("/sys/fs/cgroup/memory.current")
        .ok()
        .and_then(|s| s.trim().parse().ok())
        .unwrap_or(0);
    Some(max.saturating_sub(current))
}

/// Parses `123`, `64K`, `512M`, `8G`, `1T` (powers of 1024; a trailing `B`/`iB` is allowed).
pub fn parse_bytes(s: &str) -> Option<u64> {
    let s = s.trim();
    let s = s
        .strip_suffix("iB")
        .or_else(|| s.strip_suffix('B'))
        .unwrap_or(s);
    let (num, shift) = match s.chars().last()? {
        'k' | 'K' => (&s[..s.len() - 1], 10),
        'm' | 'M' => (&s[..s.len() - 1], 20),
        'g' | 'G' => (&s[..s.len() - 1], 30),
        't' | 'T' => (&s[..s.len() - 1], 40),
        _ => (s, 0),
    };
    let v: f64 = num.trim().parse().ok()?;
    let bytes = v * (1u64 << shift) as f64;
    // A size beyond what 64 bits count is refused rather than saturated.
    (v.is_finite() && v >= 0.0 && bytes < u64::MAX as f64).then_some(bytes as u64)
}

/// Checks the [`MEMORY_LIMIT_VAR`] environment variable: unset, or a size [`parse_bytes`]
/// reads and greater than zero. Front ends call it before any work, so that a value the
/// library cannot read is refused instead of being passed over.
pub fn check_memory_limit_var() -> crate::Result<()> {
    match std::env::var(MEMORY_LIMIT_VAR) {
        Err(std::env::VarError::NotPresent) => Ok(()),
        Ok(v) if parse_bytes(&v).is_some_and(|b| b > 0) => Ok(()),
        Ok(v) => Err(crate::Error::invalid(format!(
            "environment variable {MEMORY_LIMIT_VAR}={v}: expected a size in bytes such as 8G, \
             500M or 1.5G (powers of 1024)"
        ))),
        Err(_) => Err(crate::Error::invalid(format!(
            "environment variable {MEMORY_LIMIT_VAR} is not valid Unicode: expected a size such as 8G"
        ))),
    }
}

/// A byte count for messages: `512 B`, `3.4 MB`, `60.0 GB` (powers of 1000).
pub fn human_bytes(b: u64) -> String {
    const UNITS: [&str; 5] = ["kB", "MB", "GB", "TB", "PB"];
    if b < 1000 {
        return format!("{b} B");
    }
    let mut v = b as f64 / 1000.0;
    let mut unit = 0;
    while v >= 1000.0 && unit + 1 < UNITS.len() {
        v /= 1000.0;
        unit += 1;
    }
    format!("{v:.1} {}", UNITS[unit])
}

/// Checks that `bytes` can be allocated: at most the available memory when it is known.
/// `what` says what needs it ("decoding it", "the capture's samples").
pub fn check_memory(bytes: u64, what: &str) -> Result<(), String> {
    check_memory_with(bytes, what, available_memory())
}

pub(crate) fn check_memory_with(
    bytes: u64,
    what: &str,
    available: Option<u64>,
) -> Result<(), String> {
    match available {
        Some(avail) if bytes > avail => Err(format!(
            "{what} needs {} but only {} of memory are available{}",
            human_bytes(bytes),
            human_bytes(avail),
            if std::env::var_os(MEMORY_LIMIT_VAR).is_some() {
                format!(" (with {MEMORY_LIMIT_VAR} set)")
            } else {
                String::new()
            }
        )),
        _ => Ok(()),
    }
}

/// Peak resident memory of this process so far (`VmHWM` of `/proc/self/status`), bytes;
/// `None` where it cannot be read.
pub fn peak_rss() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = text.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn byte_counts_parse_and_print() {
        assert_eq!(parse_bytes("8G"), Some(8 << 30));
        assert_eq!(parse_bytes("512MiB"), Some(512 << 20));
        assert_eq!(parse_bytes("1000"), Some(1000));
        assert_eq!(parse_bytes("x"), None);
        assert_eq!(parse_bytes("99999999999999999999T"), None);
        assert_eq!(parse_bytes("15E"), None);
        assert_eq!(parse_bytes("16777215T"), Some(16_777_215 << 40));
        assert_eq!(human_bytes(60_000_000_000), "60.0 GB");
        assert_eq!(human_bytes(12), "12 B");
    }
}
