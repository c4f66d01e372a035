//! What the queue hands out and takes back: batches and their leases, the set of merged
//! batches a checkpoint holds, and the errors of completing and restoring.

use std::ops::Range;
use std::time::Instant;

use tessera_description::ids::{BatchId, WorkerId};
use tessera_film::quadtree::Quad;

/// Which pass a batch belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Pass {
    /// The first sample of every pixel, painted as mosaic blocks.
    One,
    /// The remaining samples of every pixel.
    Two,
}

impl Pass {
    /// 1 or 2, as on the wire and in status.
    pub fn number(self) -> u32 {
        match self {
            Pass::One => 1,
            Pass::Two => 2,
        }
    }
}

/// A run of consecutive pixels of the walk, with the samples to take of each.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BatchSpec {
    /// The batch's id, its position among the job's batches.
    pub id: BatchId,
    /// The pass.
    pub pass: Pass,
    /// The pixels in walk order; in pass one each with the block it paints.
    pub quads: Vec<Quad>,
    /// Sample indices taken of every pixel.
    pub samples: Range<u32>,
}

impl BatchSpec {
    /// Samples in the batch.
    pub fn sample_count(&self) -> u64 {
        self.quads.len() as u64 * u64::from(self.samples.end - self.samples.start)
    }
}

/// The unguessable token of one lease: 16 bytes from the farm's CSPRNG (`farm::Entropy`).
/// A result or failure counts only when it carries its lease's token, so a worker cannot
/// answer, fail or steal a lease it was not given, even one for the same batch.
#[derive(Clone, Copy, PartialEq, Eq, Hash)]
pub struct LeaseToken(pub [u8; 16]);

impl LeaseToken {
    /// Whether `wire` is this token, compared in constant time (its length is public).
    pub fn matches(&self, wire: &[u8]) -> bool {
        use subtle::ConstantTimeEq;
        // Slices of other lengths compare unequal.
        bool::from(self.0[..].ct_eq(wire))
    }
}

impl std::fmt::Debug for LeaseToken {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        // Tokens are capabilities: never in logs.
        f.write_str("LeaseToken(..)")
    }
}

/// A batch leased to a worker.
#[derive(Debug, Clone)]
pub struct Lease {
    /// What to render.
    pub spec: BatchSpec,
    /// Who renders it.
    pub worker: WorkerId,
    /// 1 for the first lease of the batch, 2 for the next, and so on.
    pub attempt: u32,
    /// When it was leased.
    pub since: Instant,
    /// What the holder must send back with its result or failure.
    pub token: LeaseToken,
}

/// Why a result was not accepted.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum CompleteError {
    /// The batch's result was merged already (a retry or a late lease finished second), or
    /// the batch never existed.
    #[error("{batch} is not outstanding (already merged, or never cut)")]
    NotOutstanding {
        /// The batch.
        batch: BatchId,
    },
}

/// Which batches of a job are merged: every id below `below`, and the ids in `above`; and
/// the pixels of every pass-two batch cut, in id order. This is all a checkpoint needs
/// besides the framebuffer, because the cut of the walk into batches is deterministic
/// given those sizes: the same image, spp and sizes give the same batches with the same
/// ids. (Pass one's sizes are fixed; pass two's follow the workers' speed.)
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Completed {
    /// Every batch id below this one is merged.
    pub below: u64,
    /// Merged ids above `below`, ascending (those finished out of order).
    pub above: Vec<u64>,
    /// Pixels of each pass-two batch cut, in id order (empty for jobs in rounds, and in
    /// checkpoints written before sizes were paced: their sizes are the fixed ones).
    pub sizes: Vec<u32>,
}

impl Completed {
    pub(super) fn contains(&self, id: u64) -> bool {
        id < self.below || self.above.binary_search(&id).is_ok()
    }

    /// One past the highest merged id.
    pub fn end(&self) -> u64 {
        self.above.last().map_or(self.below, |&a| a + 1).max(self.below)
    }
}

/// Why a queue could not be rebuilt from a checkpoint.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum RestoreError {
    /// The checkpoint names batches this job does not have.
    #[error("the checkpoint names batch {id}, but a {width}x{height} image at {spp} spp has only {batches} batches")]
    NoSuchBatch {
        /// The id named.
        id: u64,
        /// Batches the job has.
        batches: u64,
        /// Image width.
        width: u32,
        /// Image height.
        height: u32,
        /// Samples per pixel.
        spp: u32,
    },
    /// The sample counts of a tile fit no round (a checkpoint of another job).
    #[error("tile {tile} holds {count} samples in a pixel, which no round ends at")]
    Rounds {
        /// The tile.
        tile: u32,
        /// The count found.
        count: u32,
    },
    /// A pass-two batch size no cut makes.
    #[error("the checkpoint cuts a pass-two batch of {pixels} pixels (1..={max} expected)", max = super::PASS_TWO_MAX_PIXELS)]
    BatchSize {
        /// The size found.
        pixels: u32,
    },
    /// The merged ids are not ascending, or repeat one below `below`.
    #[error("the checkpoint's list of merged batches is not ascending above {below}")]
    Unordered {
        /// The watermark.
        below: u64,
    },
}
