//! The memory budget and the plan a capture is loaded with (ALGORITHMS.md §10).
//!
//! A run needs, besides the samples, a few full-frame maps per pixel (normals, albedo, depth,
//! weights, the integrator's work arrays, shadow maps and light statuses); these are the
//! *full-frame stages* and are held whole. The samples go where the budget allows:
//!
//! 1. **in memory**, whole, as `f32` (the fastest; a capture that fits is loaded as always);
//! 2. **tiles in memory** at the input's precision (`u16` for 8/16-bit images), converted to
//!    `f32` one tile at a time;
//! 3. **tiles in a spill file** beside the output, read back tile by tile.
//!
//! A budget that cannot hold the full-frame stages and one tile is refused with the smallest
//! budget that works. The per-pixel figures below are those of the memory table of
//! `docs/performance.md`; `report.json` `memory` records the plan and the measured peak.

use crate::base::error::{Error, Result};
use crate::base::machine::human_bytes;
use crate::model::store::SampleType;

/// Bytes per frame pixel of the full-frame stages, independent of the light count and of the
/// mask: at their largest (the final integration, and the recursion's surface) the gradients,
/// the weights and the integrator's work arrays beside the depth and the mask; at the end the
/// exported maps. Set on measured peaks with a margin of about 10% (`docs/performance.md`, Memory): the
/// 24-light captures measured 24 bytes per frame pixel beside the shadow planes.
pub const FRAME_BYTES_PER_PIXEL: u64 = 27;
/// Bytes per frame pixel of the full-frame stages when the per-pixel arrays a stage does not
/// read are parked in a file ([`MemoryPlan::park`]). The largest stages are then the
/// recursion's re-estimate and the fill that follows it (the estimate read back, normals 12 and
/// albedo 12 for RGB, beside the current statuses of 24 lights 6, the pixels' flags and
/// fingerprints about 10 and the last surface 4; the shadow maps wait in a file of their own
/// until the recursion ends) and the intermediate integrations (the normal map, gradients,
/// weights and the integrator's work arrays, the surface solved in its own buffer). The end of
/// the reconstruction stays below them: its maps are whole there but for the surface's, which
/// wait parked until they are written ([`crate::method::engine::reconstruct_to_write`]). Set on
/// the measured peak of a full-frame 24-light RGB capture with a margin of about 8%
/// (`docs/performance.md`, Memory).
pub const PARKED_FRAME_BYTES_PER_PIXEL: u64 = 52;
/// Bytes per mask pixel held beside every stage when the other arrays are parked: the
/// capture's mask pixel frame indices (4), the detector's residual and verdicts (6).
pub const PARKED_MASK_BYTES_PER_PIXEL: u64 = 10;
/// Bytes per mask pixel of the status map's own list of the mask pixels' frame indices, held
/// at the end of the reconstruction when the mask is not the whole frame (a whole frame's
/// statuses keep no list: `method::statusmap`).
pub const STATUS_INDEX_BYTES_PER_MASK_PIXEL: u64 = 4;
/// Bits per frame pixel and light: the shadow maps of one surface (attached and cast, as bit
/// planes).
pub const FRAME_BITS_PER_PIXEL_LIGHT: u64 = 2;
/// Bytes per mask pixel held for the whole capture, whatever the light count: the estimate
/// (normal, albedo), the detector's residual and flags, the recursion's per-pixel flags
/// (one byte each), its fingerprints of earlier usable sets, its shadow bits and the
/// attribution's keys, the mask pixels' frame indices, the trust and flags held per mask
/// pixel during the final integration. Set on the measured peak of a full-frame capture (the
/// final integration, its largest stage; there frame and mask pixels cannot be told apart, and
/// the integrator's arrays beyond [`FRAME_BYTES_PER_PIXEL`] are counted here), with a margin
/// of about 10%.
pub const MASK_BYTES_PER_PIXEL: u64 = 78;
/// Bits per mask pixel and light: the light statuses as 2-bit codes (`base::codes2`), three
/// sets of them during the recursion's consensus (the current ones, the pixels' own
/// decisions, the filtered ones). The detector's result and the method's result hold one
/// byte a light while no integration runs.
pub const MASK_BITS_PER_PIXEL_LIGHT: u64 = 6;
/// Bytes per mask pixel of the ground truth when a run is scored (`--gt`): one normal, held at
/// the mask pixels only.
pub const TRUTH_BYTES_PER_MASK_PIXEL: u64 = 12;
/// Bytes per mask pixel, per light and channel, of one tile in use: its `f32` view (4), its
/// stored bytes while read and while loaded (2 × stored size, at most 8).
pub const TILE_BYTES_PER_SAMPLE: u64 = 12;
/// Fixed allowance: code, thread stacks, decoder state, small tables (measured with 2 worker
/// threads; each further one adds [`worker_bytes`]).
pub const FIXED_BYTES: u64 = 48 << 20;
/// Bytes of each worker thread beyond the first two, whatever the stage: its stack and the
/// buffers a parallel loop holds per task (rows of the integrator, a band of a PNG being
/// encoded), which the one allocator arena the command line keeps
/// ([`crate::base::machine::cap_allocator_arenas`]) holds once freed. Set on the peaks of a
/// 2000 × 1500 capture at 2 and 16 threads (about 1.8 MiB a further thread).
pub const WORKER_BYTES: u64 = 1 << 20;
/// Bytes per frame column of each worker thread beyond the first two (row buffers; see
/// [`WORKER_BYTES`]).
pub const WORKER_BYTES_PER_COLUMN: u64 = 512;
/// Worker threads [`FIXED_BYTES`] holds.
pub const FIXED_WORKERS: usize = 2;

/// What the worker threads beyond [`FIXED_WORKERS`] hold: [`WORKER_BYTES`] and
/// [`WORKER_BYTES_PER_COLUMN`] each. Every stage keeps its per-pixel arrays whatever the thread
/// count (the shadow maps are made one light at a time, the tiles one at a time, the mesh
/// writers' bands bounded in bytes), so this is the plan's only term that grows with it.
pub fn worker_bytes(s: &CaptureSize) -> u64 {
    s.threads.saturating_sub(FIXED_WORKERS) as u64
        * (WORKER_BYTES + WORKER_BYTES_PER_COLUMN * s.width as u64)
}
/// Where a tile is never made larger (f32 bytes of its view): larger tiles gain nothing.
pub const MAX_TILE_VIEW_BYTES: u64 = 256 << 20;

/// The default budget: half of the memory available (`MemAvailable`, the cgroup's headroom,
/// `PHOTOSTEREO_MAX_MEMORY`), or 4 GiB when none can be read.
pub fn default_budget() -> u64 {
    crate::base::machine::available_memory().map_or(4 << 30, |a| a / 2)
}

/// Where the samples live.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Layout {
    /// Whole, `f32`, in memory.
    InMemory,
    /// Tiles at the input's precision, in memory.
    Tiles,
    /// Tiles at the input's precision, in a spill file.
    Spill,
}

impl Layout {
    /// The name `report.json` gives it.
    pub fn name(self) -> &'static str {
        match self {
            Layout::InMemory => "in memory",
            Layout::Tiles => "tiles in memory",
            Layout::Spill => "tiles in a spill file",
        }
    }
}

/// What a command holds beside the run's stages while the capture is loaded (`run --rti`'s
/// relightable-image fit and its writing; the `rti` command's): counted in the full-frame
/// stages, so that the budget holds them too.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct Beside {
    /// Bytes per frame pixel.
    pub per_frame_pixel: u64,
    /// Bytes per mask pixel.
    pub per_mask_pixel: u64,
    /// Bytes whatever the size (buffers of fixed size).
    pub fixed: u64,
    /// Bytes per column of the frame held while the command writes its files (buffers of
    /// whole rows), after the stages when they are [`Stages::Estimate`].
    pub writing_per_column: u64,
    /// Bytes of fixed size held while the command writes its files, as
    /// [`Beside::writing_per_column`].
    pub writing_fixed: u64,
    /// The stages the command runs besides: `run`'s, or a least-squares estimate only.
    pub stages: Stages,
}

/// The full-frame stages a command runs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Stages {
    /// `run`'s: detection, the recursion, integration, the exported maps (the constants above).
    #[default]
    Run,
    /// A least-squares estimate of normals and albedo over every light, without detection or
    /// integration (the `rti` command's reference): [`ESTIMATE_BYTES_PER_PIXEL`] and
    /// [`ESTIMATE_BYTES_PER_CHANNEL`] per frame pixel, [`ESTIMATE_BYTES_PER_MASK_PIXEL`].
    Estimate,
}

/// Bytes per frame pixel of a least-squares estimate's maps ([`Stages::Estimate`]), beside
/// [`ESTIMATE_BYTES_PER_CHANNEL`] per channel: the normals (12), the integration weight (4),
/// the capture's and the estimate's masks (2), and 3 of margin (measured peaks of 2000 × 1500
/// and 8000 × 6000 captures of 48 lights are 10–16% below the plan).
pub const ESTIMATE_BYTES_PER_PIXEL: u64 = 21;
/// Bytes per frame pixel and channel of a least-squares estimate's maps: the albedo.
pub const ESTIMATE_BYTES_PER_CHANNEL: u64 = 4;
/// Bytes per mask pixel of a least-squares estimate ([`Stages::Estimate`]): the mask pixels'
/// frame indices, in the capture and in the estimate's statuses.
pub const ESTIMATE_BYTES_PER_MASK_PIXEL: u64 = 8;

impl Beside {
    /// Bytes held beside the stages for a capture of `frame` pixels with `mask` mask pixels.
    pub fn bytes(&self, frame: u64, mask: u64) -> u64 {
        self.per_frame_pixel * frame + self.per_mask_pixel * mask + self.fixed
    }
    /// Bytes held while writing, for a frame `width` pixels wide.
    pub fn writing_bytes(&self, width: u64) -> u64 {
        self.writing_per_column * width + self.writing_fixed
    }
}

/// The sizes a plan is made from.
#[derive(Clone, Copy, Debug)]
pub struct CaptureSize {
    pub width: usize,
    pub height: usize,
    /// Mask pixels.
    pub pixels: usize,
    pub lights: usize,
    pub channels: usize,
    /// The stored sample type (`U16` for 8/16-bit images).
    pub sample_type: SampleType,
    /// Worker threads (each may hold one decoded image in the in-memory layout, and
    /// [`worker_bytes`] in every stage).
    pub threads: usize,
    /// Whether ground-truth normals are held for scoring the run.
    pub ground_truth: bool,
    /// Whether the tiled loader decodes the images whole (formats it cannot stream by rows, or
    /// images made linear by a camera response): then at least one decoded image is held.
    pub decoded_whole: bool,
    /// What is held beside the run's stages.
    pub beside: Beside,
}

impl CaptureSize {
    fn frame(&self) -> u64 {
        (self.width * self.height) as u64
    }
    fn samples(&self) -> u64 {
        self.pixels as u64 * (self.lights * self.channels) as u64
    }
}

/// The plan a capture is loaded with; `report.json` `memory` records it.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct MemoryPlan {
    /// The budget, bytes.
    pub budget: u64,
    /// `in memory`, `tiles in memory` or `tiles in a spill file`.
    pub layout: &'static str,
    /// `f32` (in memory), `u16` or `f32` (tiles).
    pub sample_type: &'static str,
    /// Bytes of the stored samples.
    pub sample_bytes: u64,
    /// Bytes of the samples as `f32` (what holding them whole costs).
    pub f32_bytes: u64,
    /// Mask pixels per tile at most (the whole mask in memory).
    pub tile_pixels: usize,
    /// Tiles (1 in memory).
    pub tiles: usize,
    /// Bytes of the spill file (0 when none).
    pub spill_bytes: u64,
    /// The full-frame stages' estimate, bytes (with what is held beside them).
    pub full_frame_bytes: u64,
    /// Of which held beside the run's stages ([`Beside`]; 0 when nothing is), bytes.
    pub beside_bytes: u64,
    /// What [`MemoryPlan::beside_bytes`] is made of, per pixel.
    pub beside: Beside,
    /// The smallest budget that works for this capture.
    pub minimum_budget: u64,
    /// Whether the per-pixel arrays a stage does not read wait in a parking file
    /// ([`crate::model::store::Parking`]) while the integrations and the shadow maps run: when
    /// the budget cannot hold them beside those stages.
    pub park: bool,
}

/// A size as `--memory-limit` takes it: bytes below 1 MiB (`1000`), whole MiB rounded up
/// (`219M`), or GiB with one decimal from 10 GiB on, rounded up (`13.9G`).
pub fn size_flag(bytes: u64) -> String {
    if bytes < 1 << 20 {
        return bytes.to_string();
    }
    let mib = bytes.div_ceil(1 << 20);
    if mib >= 10 << 10 {
        format!("{:.1}G", (mib as f64 / 1024.0 * 10.0).ceil() / 10.0)
    } else {
        format!("{mib}M")
    }
}

/// The full-frame stages' bytes (see the constants), with what is held beside them.
pub fn full_frame_bytes(s: &CaptureSize) -> u64 {
    let n = s.lights as u64;
    let beside = s.beside.bytes(s.frame(), s.pixels as u64);
    let writing = s.beside.writing_bytes(s.width as u64);
    if s.beside.stages == Stages::Estimate {
        // The files are written once the capture and the estimate are released.
        let stages = s.frame()
            * (ESTIMATE_BYTES_PER_PIXEL + ESTIMATE_BYTES_PER_CHANNEL * s.channels as u64)
            + s.pixels as u64 * ESTIMATE_BYTES_PER_MASK_PIXEL;
        return stages.max(writing) + FIXED_BYTES + worker_bytes(s) + beside;
    }
    s.frame() * FRAME_BYTES_PER_PIXEL
        + (s.frame() * FRAME_BITS_PER_PIXEL_LIGHT * n).div_ceil(8)
        + (s.pixels as u64 * MASK_BITS_PER_PIXEL_LIGHT * n).div_ceil(8)
        + mask_bytes(s, MASK_BYTES_PER_PIXEL)
        + FIXED_BYTES
        + worker_bytes(s)
        + beside
        + writing
}

/// The bytes held per mask pixel, `per_pixel` plus the ground truth's when the run holds it.
fn mask_bytes(s: &CaptureSize, per_pixel: u64) -> u64 {
    let truth = if s.ground_truth {
        TRUTH_BYTES_PER_MASK_PIXEL
    } else {
        0
    };
    s.pixels as u64 * (per_pixel + truth)
}

/// The full-frame stages' bytes with the per-pixel arrays parked ([`MemoryPlan::park`]), with
/// what is held beside them.
pub fn parked_full_frame_bytes(s: &CaptureSize) -> u64 {
    if s.beside.stages == Stages::Estimate {
        return full_frame_bytes(s);
    }
    let beside = s.beside.bytes(s.frame(), s.pixels as u64);
    let writing = s.beside.writing_bytes(s.width as u64);
    let status_index = if (s.pixels as u64) < s.frame() {
        s.pixels as u64 * STATUS_INDEX_BYTES_PER_MASK_PIXEL
    } else {
        0
    };
    s.frame() * PARKED_FRAME_BYTES_PER_PIXEL
        + mask_bytes(s, PARKED_MASK_BYTES_PER_PIXEL)
        + status_index
        + FIXED_BYTES
        + worker_bytes(s)
        + beside
        + writing
}

/// The full-frame stages' bytes under a plan that parks (`park`) or not.
fn stage_bytes(s: &CaptureSize, park: bool) -> u64 {
    if park {
        parked_full_frame_bytes(s).min(full_frame_bytes(s))
    } else {
        full_frame_bytes(s)
    }
}

/// Bytes of one tile of `pixels` mask pixels in use.
fn tile_bytes(s: &CaptureSize, pixels: u64) -> u64 {
    pixels * (s.lights * s.channels) as u64 * TILE_BYTES_PER_SAMPLE
}

/// The loaders' row buffers: one row per light (streaming decoders) plus their state.
fn decoder_bytes(s: &CaptureSize) -> u64 {
    s.lights as u64 * (s.width as u64 * s.channels as u64 * 4 + (256 << 10))
}

/// What the loader holds at least: the streaming decoders' row buffers, or one image decoded
/// whole ([`image_bytes`]).
fn loader_bytes(s: &CaptureSize) -> u64 {
    if s.decoded_whole {
        decoder_bytes(s).max(image_bytes(s))
    } else {
        decoder_bytes(s)
    }
}

/// One image decoded whole: its `f32` samples and its decoder's buffer (6 bytes a sample).
fn image_bytes(s: &CaptureSize) -> u64 {
    (s.frame() * s.channels as u64 * 6).max(1)
}

/// How many images the tiled loader decodes whole at once (formats it cannot stream by rows):
/// as many as the budget holds beside the full-frame stages, the samples held in memory and
/// the tile in use, each image's `f32` samples and its decoder's buffer (6 bytes a sample); at
/// least one, at most one per worker thread.
pub fn images_at_once(s: &CaptureSize, plan: &MemoryPlan) -> usize {
    let held = if plan.spill_bytes == 0 {
        plan.sample_bytes
    } else {
        0
    };
    let used = plan.full_frame_bytes + held + tile_bytes(s, plan.tile_pixels as u64);
    let fit = plan.budget.saturating_sub(used) / image_bytes(s);
    (fit as usize).clamp(1, s.threads.max(1))
}

/// The smallest budget that works: the full-frame stages (their arrays parked when that needs
/// less) and a tile of the widest row.
pub fn minimum_budget(s: &CaptureSize) -> u64 {
    stage_bytes(s, true) + tile_bytes(s, s.width as u64) + loader_bytes(s)
}

/// The smallest budget that holds every per-pixel array in memory (no parking).
fn minimum_unparked(s: &CaptureSize) -> u64 {
    full_frame_bytes(s) + tile_bytes(s, s.width as u64) + loader_bytes(s)
}

/// Options of a plan beyond the budget, for tests and experiments: a forced layout and tile
/// size (within the budget's minimum).
#[derive(Clone, Copy, Debug, Default)]
pub struct Force {
    /// Use this layout whatever the budget allows.
    pub layout: Option<Layout>,
    /// Mask pixels per tile.
    pub tile_pixels: Option<usize>,
    /// Park the per-pixel arrays during the full-frame stages, or not, whatever the budget asks.
    pub park: Option<bool>,
}

/// Why a budget below [`minimum_budget`] cannot hold a capture of size `s`, naming the
/// smallest budget that works.
pub fn too_small(s: &CaptureSize) -> String {
    format!(
        "too small for this capture ({}×{} pixels{}, {} lights × {} channel(s)); \
         its full-frame stages alone need {}: the smallest budget that works is {}",
        s.width,
        s.height,
        if s.pixels > 0 {
            format!(", {} mask pixels", s.pixels)
        } else {
            String::new()
        },
        s.lights,
        s.channels,
        human_bytes(stage_bytes(s, true)),
        size_flag(minimum_budget(s))
    )
}

/// Chooses where the samples of a capture of size `s` go under `budget` bytes. Errors when the
/// budget is below [`minimum_budget`], naming the parameter `memory_limit` and that minimum.
pub fn plan(s: &CaptureSize, budget: u64, force: Force) -> Result<(Layout, MemoryPlan)> {
    let minimum = minimum_budget(s);
    if budget < minimum {
        return Err(Error::parameter(
            "memory_limit",
            format!("{}: {}", size_flag(budget), too_small(s)),
        ));
    }
    let park = force
        .park
        .unwrap_or(budget < minimum_unparked(s) && stage_bytes(s, true) < full_frame_bytes(s));
    let full = stage_bytes(s, park);
    let f32_bytes = s.samples() * 4;
    let stored = s.samples() * s.sample_type.bytes() as u64;
    // Whole f32 samples, their transient second copy while loading, one image per thread.
    let in_memory_need = full
        + 2 * f32_bytes
        + s.threads as u64 * s.frame() * s.channels as u64 * 6
        + decoder_bytes(s);
    let layout = force.layout.unwrap_or(if in_memory_need <= budget {
        Layout::InMemory
    } else if full + stored + tile_bytes(s, s.pixels.div_ceil(8) as u64) + loader_bytes(s) <= budget
    {
        Layout::Tiles
    } else {
        Layout::Spill
    });
    let per_pixel = tile_bytes(s, 1).max(1);
    let (tile_pixels, tiles) = match layout {
        Layout::InMemory => (s.pixels, 1),
        _ => {
            let held = if layout == Layout::Tiles { stored } else { 0 };
            let left = budget.saturating_sub(full + held + loader_bytes(s));
            let by_budget = left / per_pixel;
            let by_cap = MAX_TILE_VIEW_BYTES / (4 * (s.lights * s.channels) as u64).max(1);
            let tp = force
                .tile_pixels
                .unwrap_or(by_budget.min(by_cap).max(s.width as u64) as usize)
                .max(1);
            (tp, s.pixels.div_ceil(tp).max(1))
        }
    };
    let plan = MemoryPlan {
        budget,
        layout: layout.name(),
        sample_type: match (layout, s.sample_type) {
            (Layout::InMemory, _) | (_, SampleType::F32) => "f32",
            (_, SampleType::U16) => "u16",
        },
        sample_bytes: if layout == Layout::InMemory {
            f32_bytes
        } else {
            stored
        },
        f32_bytes,
        tile_pixels,
        tiles,
        spill_bytes: if layout == Layout::Spill { stored } else { 0 },
        full_frame_bytes: full,
        beside_bytes: s.beside.bytes(s.frame(), s.pixels as u64)
            + s.beside.writing_bytes(s.width as u64),
        beside: s.beside,
        minimum_budget: minimum,
        park,
    };
    Ok((layout, plan))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn size(w: usize, h: usize, n: usize) -> CaptureSize {
        CaptureSize {
            width: w,
            height: h,
            pixels: w * h,
            lights: n,
            channels: 3,
            sample_type: SampleType::U16,
            threads: 2,
            ground_truth: false,
            decoded_whole: false,
            beside: Beside::default(),
        }
    }

    #[test]
    fn the_status_maps_index_list_is_planned_only_for_a_mask_short_of_the_frame() {
        let whole = size(1000, 1000, 24);
        // The same frame with one pixel fewer in the mask: one pixel's parked bytes fewer,
        // and the status map's list of every mask pixel's index more.
        let short = CaptureSize {
            pixels: whole.pixels - 1,
            ..whole
        };
        assert_eq!(
            parked_full_frame_bytes(&short) + PARKED_MASK_BYTES_PER_PIXEL,
            parked_full_frame_bytes(&whole)
                + short.pixels as u64 * STATUS_INDEX_BYTES_PER_MASK_PIXEL
        );
    }

    #[test]
    fn plans_follow_the_budget() {
        let s = size(1000, 1000, 24);
        let (l, p) = plan(&s, 8 << 30, Force::default()).unwrap();
        assert_eq!(l, Layout::InMemory);
        assert_eq!(p.tiles, 1);
        // Room for the u16 store (144 MB) but not for f32 twice (576 MB).
        let (l, p) = plan(&s, full_frame_bytes(&s) + (400 << 20), Force::default()).unwrap();
        assert_eq!(l, Layout::Tiles);
        assert_eq!(p.sample_bytes, 144_000_000);
        assert!(p.tiles > 1);
        let (l, p) = plan(&s, minimum_budget(&s) + (1 << 20), Force::default()).unwrap();
        assert_eq!(l, Layout::Spill);
        assert_eq!(p.spill_bytes, 144_000_000);
        // Scoring against ground truth holds one normal per mask pixel more.
        let scored = CaptureSize {
            ground_truth: true,
            ..s
        };
        assert_eq!(
            full_frame_bytes(&scored) - full_frame_bytes(&s),
            s.pixels as u64 * TRUTH_BYTES_PER_MASK_PIXEL
        );
        // Between the two minimums the arrays are parked during the full-frame stages; above
        // the larger one they are not.
        assert!(minimum_budget(&s) < minimum_unparked(&s));
        let (_, p) = plan(&s, minimum_budget(&s), Force::default()).unwrap();
        assert!(p.park && p.full_frame_bytes == parked_full_frame_bytes(&s));
        let (_, p) = plan(&s, minimum_unparked(&s), Force::default()).unwrap();
        assert!(!p.park && p.full_frame_bytes == full_frame_bytes(&s));
        // Each worker thread beyond the first two adds its stack and row buffers, and nothing
        // else: the per-pixel stages hold the same arrays at any thread count.
        let many = CaptureSize { threads: 16, ..s };
        assert_eq!(
            minimum_budget(&many) - minimum_budget(&s),
            14 * (WORKER_BYTES + WORKER_BYTES_PER_COLUMN * 1000)
        );
        // Images decoded whole: one at the smallest budget, one per thread when the budget
        // holds them all.
        let (_, p) = plan(&many, minimum_budget(&many), Force::default()).unwrap();
        assert_eq!(images_at_once(&many, &p), 1);
        let (_, p) = plan(&many, 64 << 30, Force::default()).unwrap();
        assert_eq!(images_at_once(&many, &p), 16);
        // A capture decoded whole holds one whole image at its smallest budget (6 bytes a
        // sample of the frame, 18 MB here) instead of the streaming decoders' row buffers.
        let whole = CaptureSize {
            decoded_whole: true,
            ..s
        };
        assert_eq!(
            minimum_budget(&whole) - minimum_budget(&s),
            1000 * 1000 * 3 * 6 - decoder_bytes(&s)
        );
        let (_, p) = plan(&whole, minimum_budget(&whole), Force::default()).unwrap();
        assert_eq!(images_at_once(&whole, &p), 1);
        let left = p.budget - p.full_frame_bytes - tile_bytes(&whole, p.tile_pixels as u64);
        assert!(left >= image_bytes(&whole), "{left}");
        let e = plan(&s, minimum_budget(&s) - 1, Force::default()).unwrap_err();
        let m = e.to_string();
        assert!(
            m.contains("memory_limit") && m.contains("smallest budget"),
            "{m}"
        );
    }
}
