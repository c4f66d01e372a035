//! A look at a submission's wire bytes before prost decodes them. A message's size is
//! bounded by the decode limit, but not its entries: an `Asset {}` is 2 bytes on the wire
//! and about 50 once decoded (and again when converted), so a bundle of millions of empty
//! assets would cost gigabytes before `Description::parse` could refuse it. Counting the
//! assets takes a walk over the tags, skipping every value, with no allocation.
//!
//! Hand-written because prost decodes or skips whole messages only; no crate here counts
//! the entries of a nested repeated field without decoding them.

use bytes::Bytes;

/// Bytes held in the frames a body arrived in, read in order without copying them.
pub(super) struct Frames<'a> {
    frames: &'a [Bytes],
    frame: usize,
    at: usize,
    /// Bytes read so far.
    pos: usize,
}

impl<'a> Frames<'a> {
    /// The bytes of `frames` from `skip` on (the gRPC prefix is skipped this way).
    pub(super) fn new(frames: &'a [Bytes], skip: usize) -> Frames<'a> {
        let mut f = Frames { frames, frame: 0, at: 0, pos: 0 };
        f.skip(skip);
        f
    }

    fn byte(&mut self) -> Option<u8> {
        while let Some(frame) = self.frames.get(self.frame) {
            if let Some(&b) = frame.get(self.at) {
                self.at += 1;
                self.pos += 1;
                return Some(b);
            }
            self.frame += 1;
            self.at = 0;
        }
        None
    }

    /// Skips `n` bytes; `None` if there are fewer.
    fn skip(&mut self, mut n: usize) -> Option<()> {
        while n > 0 {
            let frame = self.frames.get(self.frame)?;
            let here = (frame.len() - self.at.min(frame.len())).min(n);
            if here == 0 {
                self.frame += 1;
                self.at = 0;
                continue;
            }
            self.at += here;
            self.pos += here;
            n -= here;
        }
        Some(())
    }

    fn varint(&mut self) -> Option<u64> {
        let mut v = 0u64;
        for shift in (0..64).step_by(7) {
            let b = self.byte()?;
            v |= u64::from(b & 0x7f) << shift;
            if b & 0x80 == 0 {
                return Some(v);
            }
        }
        None
    }

    /// Skips a value of wire type `wire`; `None` for groups or a truncated value (prost
    /// then reports the message as malformed itself).
    fn skip_value(&mut self, wire: u64) -> Option<()> {
        match wire {
            0 => self.varint().map(|_| ()),
            1 => self.skip(8),
            2 => {
                let n = usize::try_from(self.varint()?).ok()?;
                self.skip(n)
            }
            5 => self.skip(4),
            _ => None,
        }
    }
}

/// `SubmitRequest.bundle` (field 2) and `SceneBundle.assets` (field 3), as in
/// `proto/tessera.proto`.
const SUBMIT_BUNDLE: u64 = 2;
const BUNDLE_ASSETS: u64 = 3;

/// The assets of the encoded `SubmitRequest` of `len` bytes in `bytes`, counted over every
/// occurrence of its bundle (prost merges repeated occurrences); `None` if the message is
/// malformed, which prost will then refuse.
pub(super) fn count_assets(bytes: &mut Frames<'_>, len: usize) -> Option<u64> {
    let mut count = 0u64;
    let mut left = len;
    while left > 0 {
        let before = bytes.position();
        let key = bytes.varint()?;
        let (field, wire) = (key >> 3, key & 7);
        if field == SUBMIT_BUNDLE && wire == 2 {
            let n = usize::try_from(bytes.varint()?).ok()?;
            let mut inner = n;
            while inner > 0 {
                let start = bytes.position();
                let key = bytes.varint()?;
                if key >> 3 == BUNDLE_ASSETS && key & 7 == 2 {
                    count += 1;
                }
                bytes.skip_value(key & 7)?;
                inner = inner.checked_sub(bytes.position() - start)?;
            }
        } else {
            bytes.skip_value(wire)?;
        }
        left = left.checked_sub(bytes.position() - before)?;
    }
    Some(count)
}

impl Frames<'_> {
    /// Bytes read so far.
    fn position(&self) -> usize {
        self.pos
    }
}

#[cfg(test)]
mod tests {
    use prost::Message;
    use tessera_proto::v1 as pb;

    use super::*;

    fn frames(bytes: &[u8], size: usize) -> Vec<Bytes> {
        bytes.chunks(size).map(Bytes::copy_from_slice).collect()
    }

    #[test]
    fn assets_are_counted_across_frames_without_decoding() {
        let assets = (0..1000).map(|i| pb::Asset { path: format!("a{i}"), data: vec![7; i % 5] }).collect();
        let request = pb::SubmitRequest {
            protocol_version: 3,
            bundle: Some(pb::SceneBundle { name: "s.toml".into(), text: "x = 1".into(), assets }),
            settings: Some(pb::RenderSettings { spp: 4, ..Default::default() }),
            priority: -3,
        };
        let bytes = request.encode_to_vec();
        for size in [1, 3, 64, bytes.len()] {
            let f = frames(&bytes, size);
            assert_eq!(count_assets(&mut Frames::new(&f, 0), bytes.len()), Some(1000), "frames of {size}");
        }
        // Empty assets count as well: they are what inflates.
        let empty = pb::SubmitRequest {
            bundle: Some(pb::SceneBundle { assets: vec![pb::Asset::default(); 300], ..Default::default() }),
            ..Default::default()
        };
        let bytes = empty.encode_to_vec();
        assert_eq!(count_assets(&mut Frames::new(&frames(&bytes, 7), 0), bytes.len()), Some(300));
    }

    #[test]
    fn truncated_or_malformed_messages_are_left_to_prost() {
        let request = pb::SubmitRequest {
            bundle: Some(pb::SceneBundle { assets: vec![pb::Asset::default(); 3], ..Default::default() }),
            ..Default::default()
        };
        let bytes = request.encode_to_vec();
        let f = frames(&bytes[..bytes.len() - 1], 4);
        assert_eq!(count_assets(&mut Frames::new(&f, 0), bytes.len()), None);
        let group = [0x13u8, 0x14];
        assert_eq!(count_assets(&mut Frames::new(&frames(&group, 1), 0), 2), None);
        // The gRPC prefix skipped.
        let mut prefixed = vec![0, 0, 0, 0, bytes.len() as u8];
        prefixed.extend_from_slice(&bytes);
        assert_eq!(count_assets(&mut Frames::new(&frames(&prefixed, 2), 5), bytes.len()), Some(3));
    }
}
