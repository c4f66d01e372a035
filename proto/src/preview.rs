//! Previews on the wire: `tessera_film::preview::Blocks` as an encoded `Preview`, display
//! values as half floats. Encoded once per tick by the coordinator and shared by every
//! viewer in step; decoded and checked whole by a viewer before it paints anything.

use bytes::Bytes;
use half::f16;
use prost::Message;
use tessera_film::preview::{grid, Blocks, MAX_SHIFT};

use crate::v1 as pb;

/// Why a preview payload is refused (a coordinator speaking nonsense).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum PreviewError {
    /// The payload is not an encoded `Preview` (e.g. cut short).
    #[error("the preview payload does not decode: {0}")]
    Decode(#[from] prost::DecodeError),
    /// A group of blocks does not fit the image or its arrays disagree.
    #[error("malformed preview blocks (shift {shift}): {reason}")]
    Blocks {
        /// The group's block shift.
        shift: u32,
        /// What is wrong.
        reason: &'static str,
    },
}

/// Blocks as a watch update carries them; no blocks: an empty payload. Values beyond the
/// half float's range are clamped to its largest (a display value; exact ones come at the
/// end), NaN would be a renderer bug the merge already refused, so it shows as black.
pub fn preview_to_wire(blocks: &[Blocks]) -> Bytes {
    let groups: Vec<pb::PreviewBlocks> = blocks
        .iter()
        .filter(|b| !b.is_empty())
        .map(|b| pb::PreviewBlocks {
            shift: u32::from(b.shift),
            runs: b.runs.iter().flat_map(|&(first, count)| [first, count]).collect(),
            rgb: b
                .rgb
                .iter()
                .flatten()
                .flat_map(|&v| {
                    let v = if v.is_nan() { 0.0 } else { v.clamp(0.0, f16::MAX.to_f32()) };
                    f16::from_f32(v).to_le_bytes()
                })
                .collect(),
        })
        .collect();
    if groups.is_empty() {
        return Bytes::new();
    }
    Bytes::from(pb::Preview { blocks: groups }.encode_to_vec())
}

/// A watch update's preview for a `width × height` image, checked whole: every run within
/// the block grid, one finite, non-negative value per block.
pub fn preview_from_wire(payload: &[u8], width: u32, height: u32) -> Result<Vec<Blocks>, PreviewError> {
    if payload.is_empty() {
        return Ok(Vec::new());
    }
    let preview = pb::Preview::decode(payload)?;
    let mut out = Vec::with_capacity(preview.blocks.len());
    for g in preview.blocks {
        let bad = |reason| PreviewError::Blocks { shift: g.shift, reason };
        if g.shift > u32::from(MAX_SHIFT) {
            return Err(bad("blocks larger than 256 pixels"));
        }
        let shift = g.shift as u8;
        let (gw, gh) = grid(width, height, shift);
        let blocks = u64::from(gw) * u64::from(gh);
        if g.runs.len() % 2 != 0 {
            return Err(bad("runs are not pairs of first block and count"));
        }
        let mut runs = Vec::with_capacity(g.runs.len() / 2);
        let mut total = 0u64;
        for pair in g.runs.chunks_exact(2) {
            let (first, count) = (pair[0], pair[1]);
            if u64::from(first) + u64::from(count) > blocks {
                return Err(bad("a run extends past the image"));
            }
            total += u64::from(count);
            runs.push((first, count));
        }
        if total > blocks {
            // The publisher paints a block once per group; repeats would let a payload of a
            // few bytes a block make the viewer paint 65 536 pixels for each.
            return Err(bad("more blocks than the image has"));
        }
        if total * 6 != g.rgb.len() as u64 {
            return Err(bad("not one value of 6 bytes per block"));
        }
        let values: Vec<f32> =
            g.rgb.chunks_exact(2).map(|b| f16::from_le_bytes([b[0], b[1]]).to_f32()).collect();
        if values.iter().any(|v| !v.is_finite() || *v < 0.0) {
            return Err(bad("a value is not a finite, non-negative number"));
        }
        let rgb = values.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
        out.push(Blocks { shift, runs, rgb });
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn group(shift: u32, runs: Vec<u32>, rgb: Vec<u8>) -> Vec<u8> {
        pb::Preview { blocks: vec![pb::PreviewBlocks { shift, runs, rgb }] }.encode_to_vec()
    }

    #[test]
    fn blocks_travel_as_half_floats() {
        let b = Blocks {
            shift: 2,
            runs: vec![(0, 2), (5, 1)],
            rgb: vec![[0.5, 1.0, 2.0], [0.25, 0.0, 1e6], [0.1, 0.2, 0.3]],
        };
        let wire = preview_to_wire(std::slice::from_ref(&b));
        let back = preview_from_wire(&wire, 10, 9).unwrap();
        assert_eq!(back.len(), 1);
        assert_eq!((back[0].shift, back[0].runs.clone()), (2, b.runs.clone()));
        assert_eq!(back[0].rgb[0], [0.5, 1.0, 2.0]);
        assert_eq!(back[0].rgb[1][2], 65504.0, "clamped to the largest half float");
        assert!((back[0].rgb[2][0] - 0.1).abs() < 1e-3);
        assert!(preview_to_wire(&[Blocks::default()]).is_empty());
        assert!(preview_from_wire(&[], 10, 9).unwrap().is_empty());
    }

    #[test]
    fn hostile_previews_are_refused_with_what_is_wrong() {
        let one = f16::from_f32(1.0).to_le_bytes().repeat(3);
        let cases = [
            (group(9, vec![0, 1], one.clone()), "blocks larger than 256 pixels"),
            (group(0, vec![0], one.clone()), "runs are not pairs"),
            (group(0, vec![89, 2], one.repeat(2)), "a run extends past the image"),
            (group(0, vec![0, 2], one.clone()), "not one value of 6 bytes per block"),
            (group(0, vec![0, u32::MAX], one.clone()), "a run extends past the image"),
            (group(8, vec![0, 1, 0, 1], one.repeat(2)), "more blocks than the image has"),
            (group(0, vec![0, 1], f16::NAN.to_le_bytes().repeat(3)), "not a finite"),
            (group(0, vec![0, 1], f16::from_f32(-1.0).to_le_bytes().repeat(3)), "not a finite"),
        ];
        for (payload, want) in cases {
            let e = preview_from_wire(&payload, 10, 9).unwrap_err();
            assert!(e.to_string().contains(want), "{e} (wanted {want})");
        }
        let cut = group(0, vec![0, 1], one);
        let e = preview_from_wire(&cut[..cut.len() - 1], 10, 9).unwrap_err();
        assert!(matches!(e, PreviewError::Decode(_)), "{e}");
    }
}
