//! Reading accessors: elements out of buffer views, integers normalised as glTF says
//! (§3.11: `c / 255`, `max(c / 127, -1)`, …), sparse substitutions applied. Every read is
//! bounds-checked; the structural checks before give the precise messages.

use gltf::json::accessor::{ComponentType, Type};
use gltf::json::validation::Checked;
use gltf::json::{self, Root};

/// Components of an element of type `t`.
pub(crate) fn components(t: Type) -> usize {
    match t {
        Type::Scalar => 1,
        Type::Vec2 => 2,
        Type::Vec3 => 3,
        Type::Vec4 | Type::Mat2 => 4,
        Type::Mat3 => 9,
        Type::Mat4 => 16,
    }
}

/// Bytes of one component.
pub(crate) fn size(c: ComponentType) -> usize {
    match c {
        ComponentType::I8 | ComponentType::U8 => 1,
        ComponentType::I16 | ComponentType::U16 => 2,
        ComponentType::U32 | ComponentType::F32 => 4,
    }
}

/// The name glTF's specification uses for a component type.
pub(crate) fn name(c: ComponentType) -> &'static str {
    match c {
        ComponentType::I8 => "BYTE",
        ComponentType::U8 => "UNSIGNED_BYTE",
        ComponentType::I16 => "SHORT",
        ComponentType::U16 => "UNSIGNED_SHORT",
        ComponentType::U32 => "UNSIGNED_INT",
        ComponentType::F32 => "FLOAT",
    }
}

/// An accessor's component type and element type (validated before: both are valid).
pub(crate) fn kind(a: &json::Accessor) -> Option<(ComponentType, Type)> {
    match (&a.component_type, &a.type_) {
        (Checked::Valid(c), Checked::Valid(t)) => Some((c.0, *t)),
        _ => None,
    }
}

fn component(bytes: &[u8], c: ComponentType, normalized: bool) -> Option<f32> {
    let b = |n: usize| bytes.get(..n);
    Some(match c {
        ComponentType::F32 => f32::from_le_bytes(b(4)?.try_into().ok()?),
        ComponentType::U8 => {
            let v = f32::from(b(1)?[0]);
            if normalized {
                v / 255.0
            } else {
                v
            }
        }
        ComponentType::I8 => {
            let v = f32::from(b(1)?[0] as i8);
            if normalized {
                (v / 127.0).max(-1.0)
            } else {
                v
            }
        }
        ComponentType::U16 => {
            let v = f32::from(u16::from_le_bytes(b(2)?.try_into().ok()?));
            if normalized {
                v / 65535.0
            } else {
                v
            }
        }
        ComponentType::I16 => {
            let v = f32::from(i16::from_le_bytes(b(2)?.try_into().ok()?));
            if normalized {
                (v / 32767.0).max(-1.0)
            } else {
                v
            }
        }
        ComponentType::U32 => {
            let v = u32::from_le_bytes(b(4)?.try_into().ok()?);
            if normalized {
                (f64::from(v) / f64::from(u32::MAX)) as f32
            } else {
                v as f32
            }
        }
    })
}

fn uint(bytes: &[u8], c: ComponentType) -> Option<u32> {
    Some(match c {
        ComponentType::U8 => u32::from(*bytes.first()?),
        ComponentType::U16 => u32::from(u16::from_le_bytes(bytes.get(..2)?.try_into().ok()?)),
        ComponentType::U32 => u32::from_le_bytes(bytes.get(..4)?.try_into().ok()?),
        _ => return None,
    })
}

/// The bytes of buffer view `view` and its stride (`elem` when tightly packed).
fn view_bytes<'a>(
    root: &Root,
    buffers: &'a [Vec<u8>],
    view: usize,
    elem: usize,
) -> Option<(&'a [u8], usize)> {
    let v = root.buffer_views.get(view)?;
    let data = buffers.get(v.buffer.value())?;
    let start = v.byte_offset.map_or(0, |o| o.0) as usize;
    let end = start.checked_add(v.byte_length.0 as usize)?;
    Some((data.get(start..end)?, v.byte_stride.map_or(elem, |s| s.0)))
}

/// Every element of accessor `index` as `count × components` floats.
pub(crate) fn floats(root: &Root, buffers: &[Vec<u8>], index: usize) -> Option<Vec<f32>> {
    let a = root.accessors.get(index)?;
    let (c, t) = kind(a)?;
    let n = components(t);
    let csize = size(c);
    let count = a.count.0 as usize;
    let mut out = vec![0f32; count.checked_mul(n)?];
    if let Some(view) = a.buffer_view {
        let (bytes, stride) = view_bytes(root, buffers, view.value(), n * csize)?;
        let base = a.byte_offset.map_or(0, |o| o.0) as usize;
        for (i, e) in out.chunks_exact_mut(n).enumerate() {
            let at = base + i * stride;
            for (j, slot) in e.iter_mut().enumerate() {
                *slot = component(bytes.get(at + j * csize..)?, c, a.normalized)?;
            }
        }
    }
    if let Some(s) = &a.sparse {
        let ic = match &s.indices.component_type {
            Checked::Valid(ic) => ic.0,
            Checked::Invalid => return None,
        };
        let (ib, _) = view_bytes(root, buffers, s.indices.buffer_view.value(), size(ic))?;
        let (vb, _) = view_bytes(root, buffers, s.values.buffer_view.value(), n * csize)?;
        let (ib, vb) =
            (ib.get(s.indices.byte_offset.0 as usize..)?, vb.get(s.values.byte_offset.0 as usize..)?);
        for k in 0..s.count.0 as usize {
            let target = uint(ib.get(k * size(ic)..)?, ic)? as usize;
            let e = out.get_mut(target * n..target * n + n)?;
            for (j, slot) in e.iter_mut().enumerate() {
                *slot = component(vb.get((k * n + j) * csize..)?, c, a.normalized)?;
            }
        }
    }
    Some(out)
}

/// Every element of a scalar unsigned-integer accessor (indices).
pub(crate) fn uints(root: &Root, buffers: &[Vec<u8>], index: usize) -> Option<Vec<u32>> {
    let a = root.accessors.get(index)?;
    let (c, _) = kind(a)?;
    if a.sparse.is_some() || a.buffer_view.is_none() {
        // Sparse or absent index data: read as floats (exact below 2^24, checked by the
        // caller against the vertex count).
        return floats(root, buffers, index).map(|v| v.into_iter().map(|x| x as u32).collect());
    }
    let (bytes, stride) = view_bytes(root, buffers, a.buffer_view?.value(), size(c))?;
    let base = a.byte_offset.map_or(0, |o| o.0) as usize;
    (0..a.count.0 as usize).map(|i| uint(bytes.get(base + i * stride..)?, c)).collect()
}
