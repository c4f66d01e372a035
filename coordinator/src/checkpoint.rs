//! A job's checkpoint and its byte format: the merged batches and the framebuffer's
//! accumulators, cut into parts that each carry a BLAKE3 checksum, so that a damaged part
//! is detected on reading and never resumed from. Pure: `store.rs` keeps the parts.
//!
//! The framebuffer is integer sums, so a checkpoint read back is bit-exact, and the batches
//! are a deterministic cut of the walk, so the merged set names exactly which samples the
//! sums hold. Together they make a resumed job end in the same bytes as an uninterrupted one.

use crate::scheduler::Completed;
use tessera_description::ids::JobId;

/// Identifies the header part and its layout: format 4 names the renderer that rendered
/// the samples (`RENDERER_VERSION`, its bytes after the sizes, counted in a last header
/// word); format 3 logs the pass-two batch sizes (`Completed::sizes`) after the merged
/// ids, in a word counting them after the others.
const MAGIC: &[u8; 8] = b"TSRCKPT4";
/// Format 3, written before checkpoints named their renderer: read back as one that does
/// not say.
const MAGIC_3: &[u8; 8] = b"TSRCKPT3";
/// Format 2, written before pass-two sizes followed the workers' speed: read back as a
/// checkpoint whose sizes are the fixed ones (an empty log).
const MAGIC_2: &[u8; 8] = b"TSRCKPT2";
/// Pixels per part: 14 MB of accumulators, far below SQLite's 1 GB value limit, and a
/// bounded buffer when reading back.
pub const PART_PIXELS: usize = 1 << 19;
/// Bytes a pixel takes: three u64 sums and a u32 count (and a u64 even-sample sum for jobs
/// with a noise target).
const PIXEL_BYTES: usize = 28;
/// Words of the header after the magic, before the merged-batch ids (one fewer in format
/// 3, which has no renderer, and two in format 2, which has no count of sizes either).
const HEADER_WORDS: usize = 13;
/// In header word 8: bit 0 says the pixel parts hold even-sample sums; bits 1..=3 are the
/// job's AOV layers (`tessera_film::aov::Layout::bits`), whose sums follow the pixel parts
/// in parts of their own, `PART_PIXELS` pixels each. A checkpoint written before AOV layers
/// existed has 0 or 1 there, and reads back as one without layers.
const EVEN_FLAG: u64 = 1;

/// A job's state at one moment.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Checkpoint {
    /// The job.
    pub job: JobId,
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Samples per pixel.
    pub spp: u32,
    /// The merged batches.
    pub completed: Completed,
    /// Samples that came back NaN or infinite so far.
    pub nonfinite_samples: u64,
    /// Samples merged (the sum of `counts`; checked on reading).
    pub samples_done: u64,
    /// Per-pixel fixed-point sums.
    pub sums: Vec<[u64; 3]>,
    /// Per-pixel sample counts.
    pub counts: Vec<u32>,
    /// Per-pixel even-sample luminance sums (jobs with a noise target), else empty.
    pub even: Vec<u64>,
    /// Rendering time so far (counted against a time budget).
    pub spent: std::time::Duration,
    /// The AOV layers kept (`tessera_film::aov::Layout::bits`), 0 for none.
    pub aov_layout: u32,
    /// Their sums, pixel-major, `per_pixel()` a pixel (`AovLayers::sums`); empty for none.
    pub aov: Vec<u64>,
    /// The renderer that rendered the samples (`tessera_description::RENDERER_VERSION`):
    /// another's samples of the same indices differ, so a resume from it would not end
    /// in the bytes of an uninterrupted render. Empty in checkpoints of format 3 and
    /// older, which did not say.
    pub renderer: String,
}

/// One stored part: its bytes and their checksum.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Part {
    /// The bytes.
    pub data: Vec<u8>,
    /// BLAKE3 of `data`.
    pub sum: [u8; 32],
}

impl Part {
    fn new(data: Vec<u8>) -> Self {
        let sum = *blake3::hash(&data).as_bytes();
        Part { data, sum }
    }
}

/// Why stored parts are not a checkpoint.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum DecodeError {
    /// A part's bytes do not match its checksum.
    #[error("part {part} fails its checksum (the stored bytes changed after they were written)")]
    Checksum {
        /// Part index, 0 being the header.
        part: usize,
    },
    /// The header is not a checkpoint header of this format.
    #[error("part 0 is not a checkpoint header of format {}", String::from_utf8_lossy(MAGIC))]
    Magic,
    /// Parts are missing or too many.
    #[error("expected {expected} parts, found {found}")]
    PartCount {
        /// Parts the header announces.
        expected: usize,
        /// Parts stored.
        found: usize,
    },
    /// A part has the wrong length.
    #[error("part {part} is {got} bytes, expected {expected}")]
    PartLength {
        /// Part index.
        part: usize,
        /// Bytes expected.
        expected: usize,
        /// Bytes found.
        got: usize,
    },
    /// The header names AOV layers that do not exist.
    #[error("the header names unknown AOV layers {0:#x}")]
    AovLayout(u32),
    /// The header's renderer is empty or not UTF-8 (format 4 always names one).
    #[error("the header's renderer is not a renderer's name")]
    Renderer,
    /// The counts do not add up to the samples the header claims.
    #[error("the pixels hold {counted} samples, the header says {claimed}")]
    Samples {
        /// Sum of the counts.
        counted: u64,
        /// `samples_done` in the header.
        claimed: u64,
    },
}

impl Checkpoint {
    /// The checkpoint as parts: a header, then the pixels `PART_PIXELS` at a time.
    pub fn encode(&self) -> Vec<Part> {
        let pixel_parts = self.counts.len().div_ceil(PART_PIXELS);
        let mut h = Vec::with_capacity(
            8 * (1 + HEADER_WORDS) + self.completed.above.len() * 8 + self.completed.sizes.len() * 4,
        );
        h.extend_from_slice(MAGIC);
        for v in [u64::from(self.width), u64::from(self.height), u64::from(self.spp), self.job.0] {
            h.extend_from_slice(&v.to_le_bytes());
        }
        for v in [self.nonfinite_samples, self.samples_done, self.completed.below] {
            h.extend_from_slice(&v.to_le_bytes());
        }
        h.extend_from_slice(&(pixel_parts as u64).to_le_bytes());
        let flags = (u64::from(!self.even.is_empty()) * EVEN_FLAG) | (u64::from(self.aov_layout) << 1);
        h.extend_from_slice(&flags.to_le_bytes());
        h.extend_from_slice(&(self.spent.as_millis() as u64).to_le_bytes());
        h.extend_from_slice(&(self.completed.above.len() as u64).to_le_bytes());
        h.extend_from_slice(&(self.completed.sizes.len() as u64).to_le_bytes());
        h.extend_from_slice(&(self.renderer.len() as u64).to_le_bytes());
        for id in &self.completed.above {
            h.extend_from_slice(&id.to_le_bytes());
        }
        for size in &self.completed.sizes {
            h.extend_from_slice(&size.to_le_bytes());
        }
        h.extend_from_slice(self.renderer.as_bytes());
        let mut parts = vec![Part::new(h)];
        for (k, (sums, counts)) in
            self.sums.chunks(PART_PIXELS).zip(self.counts.chunks(PART_PIXELS)).enumerate()
        {
            let mut d = Vec::with_capacity(sums.len() * (PIXEL_BYTES + 8));
            for s in sums {
                s.iter().for_each(|v| d.extend_from_slice(&v.to_le_bytes()));
            }
            counts.iter().for_each(|c| d.extend_from_slice(&c.to_le_bytes()));
            if !self.even.is_empty() {
                let even = &self.even[k * PART_PIXELS..k * PART_PIXELS + counts.len()];
                even.iter().for_each(|e| d.extend_from_slice(&e.to_le_bytes()));
            }
            parts.push(Part::new(d));
        }
        let per = self.aov_per_pixel();
        if per > 0 {
            for chunk in self.aov.chunks(PART_PIXELS * per) {
                parts.push(Part::new(chunk.iter().flat_map(|v| v.to_le_bytes()).collect()));
            }
        }
        parts
    }

    /// The AOV values a pixel holds (0 for an unknown layout, refused on decoding).
    fn aov_per_pixel(&self) -> usize {
        tessera_film::aov::Layout::from_bits(self.aov_layout).map_or(0, |l| l.per_pixel())
    }

    /// Reads parts back, checking every checksum, length and count before trusting any of it.
    pub fn decode(parts: &[Part]) -> Result<Checkpoint, DecodeError> {
        for (i, p) in parts.iter().enumerate() {
            if *blake3::hash(&p.data).as_bytes() != p.sum {
                return Err(DecodeError::Checksum { part: i });
            }
        }
        let header = parts.first().ok_or(DecodeError::PartCount { expected: 1, found: 0 })?;
        let h = &header.data;
        let words = match h.get(..8) {
            Some(m) if m == MAGIC => HEADER_WORDS,
            Some(m) if m == MAGIC_3 => HEADER_WORDS - 1,
            Some(m) if m == MAGIC_2 => HEADER_WORDS - 2,
            _ => return Err(DecodeError::Magic),
        };
        if h.len() < MAGIC.len() + words * 8 {
            return Err(DecodeError::Magic);
        }
        let word = |i: usize| u64::from_le_bytes(h[8 + i * 8..16 + i * 8].try_into().expect("8 bytes"));
        let narrow = |v: u64| u32::try_from(v).map_err(|_| DecodeError::Magic);
        let (width, height, spp, job) =
            (narrow(word(0))?, narrow(word(1))?, narrow(word(2))?, JobId(word(3)));
        let (nonfinite_samples, samples_done, below) = (word(4), word(5), word(6));
        let (pixel_parts, flags, spent_ms, n_above) = (word(7) as usize, word(8), word(9), word(10) as usize);
        let has_even = flags & EVEN_FLAG != 0;
        let aov_layout = u32::try_from(flags >> 1).map_err(|_| DecodeError::Magic)?;
        let aov_per_pixel = tessera_film::aov::Layout::from_bits(aov_layout)
            .ok_or(DecodeError::AovLayout(aov_layout))?
            .per_pixel();
        let n_sizes = if words >= HEADER_WORDS - 1 { word(11) as usize } else { 0 };
        let n_renderer = if words == HEADER_WORDS { word(12) as usize } else { 0 };
        let expected_len = (8 + words * 8)
            .saturating_add(n_above.saturating_mul(8))
            .saturating_add(n_sizes.saturating_mul(4))
            .saturating_add(n_renderer);
        if h.len() != expected_len {
            return Err(DecodeError::PartLength { part: 0, expected: expected_len, got: h.len() });
        }
        let above = (0..n_above).map(|i| word(words + i)).collect();
        let (sizes, renderer) = h[8 + (words + n_above) * 8..].split_at(n_sizes * 4);
        let sizes =
            sizes.chunks_exact(4).map(|b| u32::from_le_bytes(b.try_into().expect("4 bytes"))).collect();
        let renderer = String::from_utf8(renderer.to_vec()).map_err(|_| DecodeError::Renderer)?;
        if words == HEADER_WORDS && renderer.is_empty() {
            return Err(DecodeError::Renderer);
        }
        let pixels = width as usize * height as usize;
        let aov_parts = if aov_per_pixel > 0 { pixel_parts } else { 0 };
        if pixel_parts != pixels.div_ceil(PART_PIXELS) || parts.len() != pixel_parts + aov_parts + 1 {
            return Err(DecodeError::PartCount {
                expected: pixels.div_ceil(PART_PIXELS) * (1 + usize::from(aov_per_pixel > 0)) + 1,
                found: parts.len(),
            });
        }
        let mut sums = Vec::with_capacity(pixels);
        let mut counts = Vec::with_capacity(pixels);
        let mut even = Vec::with_capacity(if has_even { pixels } else { 0 });
        let pixel_bytes = PIXEL_BYTES + if has_even { 8 } else { 0 };
        let u64s = |b: &[u8]| -> Vec<u64> {
            b.chunks_exact(8).map(|b| u64::from_le_bytes(b.try_into().expect("8"))).collect()
        };
        for (i, p) in parts[1..=pixel_parts].iter().enumerate() {
            let n = (pixels - i * PART_PIXELS).min(PART_PIXELS);
            if p.data.len() != n * pixel_bytes {
                return Err(DecodeError::PartLength {
                    part: i + 1,
                    expected: n * pixel_bytes,
                    got: p.data.len(),
                });
            }
            let (s, rest) = p.data.split_at(n * 24);
            let (c, e) = rest.split_at(n * 4);
            sums.extend(u64s(s).chunks_exact(3).map(|t| [t[0], t[1], t[2]]));
            counts.extend(c.chunks_exact(4).map(|b| u32::from_le_bytes(b.try_into().expect("4"))));
            even.extend(u64s(e));
        }
        let mut aov = Vec::with_capacity(pixels * aov_per_pixel);
        for (i, p) in parts[pixel_parts + 1..].iter().enumerate() {
            let n = (pixels - i * PART_PIXELS).min(PART_PIXELS) * aov_per_pixel * 8;
            if p.data.len() != n {
                return Err(DecodeError::PartLength {
                    part: pixel_parts + 1 + i,
                    expected: n,
                    got: p.data.len(),
                });
            }
            aov.extend(u64s(&p.data));
        }
        let counted: u64 = counts.iter().map(|&c| u64::from(c)).sum();
        if counted != samples_done {
            return Err(DecodeError::Samples { counted, claimed: samples_done });
        }
        Ok(Checkpoint {
            job,
            width,
            height,
            spp,
            completed: Completed { below, above, sizes },
            nonfinite_samples,
            samples_done,
            sums,
            counts,
            even,
            spent: std::time::Duration::from_millis(spent_ms),
            aov_layout,
            aov,
            renderer,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(width: u32, height: u32) -> Checkpoint {
        let n = (width * height) as usize;
        let counts: Vec<u32> = (0..n).map(|i| (i % 5) as u32).collect();
        Checkpoint {
            job: JobId(7),
            width,
            height,
            spp: 4,
            completed: Completed { below: 12, above: vec![14, 15, 99], sizes: vec![520, 7, 8192] },
            nonfinite_samples: 3,
            samples_done: counts.iter().map(|&c| u64::from(c)).sum(),
            sums: (0..n as u64).map(|i| [i, i * 3, u64::MAX - i]).collect(),
            even: if width % 2 == 1 { (0..n as u64).map(|i| i * 7).collect() } else { Vec::new() },
            counts,
            spent: std::time::Duration::from_millis(4321),
            aov_layout: if height % 2 == 1 { 5 } else { 0 },
            aov: if height % 2 == 1 { (0..5 * n as u64).map(|i| i * 11).collect() } else { Vec::new() },
            renderer: tessera_description::RENDERER_VERSION.into(),
        }
    }

    #[test]
    fn round_trips_across_several_parts() {
        for (w, h) in [(1, 1), (7, 3), (8, 2), (1024, 1025)] {
            let c = sample(w, h);
            let parts = c.encode();
            let aov_parts = if h % 2 == 1 { ((w * h) as usize).div_ceil(PART_PIXELS) } else { 0 };
            assert_eq!(parts.len(), 1 + ((w * h) as usize).div_ceil(PART_PIXELS) + aov_parts);
            assert_eq!(Checkpoint::decode(&parts).unwrap(), c);
        }
    }

    /// A checkpoint of format 2 (no logged sizes: the word counting them and the sizes
    /// are missing) reads back with an empty log, which restores the fixed sizes it was
    /// cut with.
    #[test]
    fn format_2_reads_back_without_sizes() {
        let mut c = sample(7, 4);
        c.completed.sizes.clear();
        c.renderer.clear();
        let mut parts = c.encode();
        let mut h = parts[0].data.clone();
        h[..8].copy_from_slice(MAGIC_2);
        h.drain(8 + 11 * 8..8 + 13 * 8);
        parts[0] = Part::new(h);
        assert_eq!(Checkpoint::decode(&parts).unwrap(), c);
    }

    /// A checkpoint of format 3 (no renderer: its length word and bytes are missing) reads
    /// back as one that does not say which renderer made it.
    #[test]
    fn format_3_reads_back_without_a_renderer() {
        let mut c = sample(7, 5);
        let mut h = c.encode()[0].data.clone();
        h[..8].copy_from_slice(MAGIC_3);
        h.truncate(h.len() - c.renderer.len());
        h.drain(8 + 12 * 8..8 + 13 * 8);
        let mut parts = c.encode();
        parts[0] = Part::new(h);
        c.renderer.clear();
        assert_eq!(Checkpoint::decode(&parts).unwrap(), c);
        // A renderer's name that is not UTF-8 is no checkpoint of this format.
        let mut bad = c.clone();
        bad.renderer = "x".into();
        let mut parts = bad.encode();
        let mut h = parts[0].data.clone();
        *h.last_mut().unwrap() = 0xff;
        parts[0] = Part::new(h);
        assert_eq!(Checkpoint::decode(&parts), Err(DecodeError::Renderer));
        // Format 4 always names its renderer.
        bad.renderer.clear();
        assert_eq!(Checkpoint::decode(&bad.encode()), Err(DecodeError::Renderer));
    }

    /// A header whose counts (merged ids, sizes, renderer bytes) are huge or one off, its
    /// checksum made anew, is refused by its length, and nothing is read past its end.
    #[test]
    fn crafted_counts_are_refused() {
        let parts = sample(7, 5).encode();
        for word in [10, 11, 12] {
            for value in [u64::MAX, u64::MAX / 8, 1 << 40, 0] {
                let mut h = parts[0].data.clone();
                let at = 8 + word * 8;
                let old = u64::from_le_bytes(h[at..at + 8].try_into().unwrap());
                for v in [value, old + 1, old.wrapping_sub(1)] {
                    h[at..at + 8].copy_from_slice(&v.to_le_bytes());
                    let mut bad = parts.clone();
                    bad[0] = Part::new(h.clone());
                    if v != old {
                        let e = Checkpoint::decode(&bad);
                        assert!(
                            matches!(e, Err(DecodeError::PartLength { part: 0, .. })),
                            "word {word} = {v}: {e:?}"
                        );
                    }
                }
            }
        }
    }

    /// Every single flipped bit, in the header or a pixel part, is caught by a checksum;
    /// a part whose checksum was recomputed still fails the structural checks.
    #[test]
    fn damage_is_detected() {
        let parts = sample(9, 5).encode();
        for part in 0..parts.len() {
            for byte in [0, parts[part].data.len() / 2, parts[part].data.len() - 1] {
                let mut bad = parts.clone();
                bad[part].data[byte] ^= 0x10;
                assert_eq!(Checkpoint::decode(&bad), Err(DecodeError::Checksum { part }));
            }
        }
        let mut truncated = parts.clone();
        truncated.pop();
        assert!(matches!(Checkpoint::decode(&truncated), Err(DecodeError::PartCount { .. })));
        let mut short = parts.clone();
        short[1].data.truncate(10);
        short[1] = Part::new(short[1].data.clone());
        assert!(matches!(Checkpoint::decode(&short), Err(DecodeError::PartLength { part: 1, .. })));
        let mut lying = parts.clone();
        lying[1].data[24 * 45] ^= 1;
        lying[1] = Part::new(lying[1].data.clone());
        assert!(matches!(Checkpoint::decode(&lying), Err(DecodeError::Samples { .. })));
        assert_eq!(Checkpoint::decode(&[]), Err(DecodeError::PartCount { expected: 1, found: 0 }));
        assert_eq!(Checkpoint::decode(&[Part::new(b"garbage".to_vec())]), Err(DecodeError::Magic));
    }
}
