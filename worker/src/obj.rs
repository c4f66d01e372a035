//! A Wavefront OBJ reader for triangle meshes: positions, normals, texture coordinates,
//! polygons (fan-triangulated), negative (relative) indices. Errors name the line.

use glam::{Vec2, Vec3};

use crate::render::shape::Mesh;

/// An OBJ error: the 1-based line and what is wrong.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("line {line}: {message}")]
pub struct ObjError {
    /// 1-based line.
    pub line: usize,
    /// What is wrong.
    pub message: String,
}

/// Parses OBJ text into a mesh (object space).
pub fn parse_obj(text: &str) -> Result<Mesh, ObjError> {
    let mut mesh = Mesh::default();
    for (i, raw) in text.lines().enumerate() {
        let line = i + 1;
        let err = |message: String| ObjError { line, message };
        let content = raw.split('#').next().unwrap_or("").trim();
        let mut words = content.split_whitespace();
        let Some(keyword) = words.next() else { continue };
        let numbers = |words: std::str::SplitWhitespace, n: usize| -> Result<Vec<f32>, ObjError> {
            let v: Vec<f32> = words
                .take(n)
                .map(|w| w.parse::<f32>().map_err(|_| err(format!("expected a number, got {w:?}"))))
                .collect::<Result<_, _>>()?;
            if v.len() < n {
                return Err(err(format!("expected {n} numbers after {keyword:?}")));
            }
            if v.iter().any(|x| !x.is_finite()) {
                return Err(err("coordinates must be finite".into()));
            }
            Ok(v)
        };
        match keyword {
            "v" => {
                let v = numbers(words, 3)?;
                mesh.p.push(Vec3::new(v[0], v[1], v[2]));
            }
            "vn" => {
                let v = numbers(words, 3)?;
                mesh.n.push(Vec3::new(v[0], v[1], v[2]));
            }
            "vt" => {
                let v = numbers(words, 2)?;
                mesh.uv.push(Vec2::new(v[0], v[1]));
            }
            "f" => {
                let corners: Vec<[u32; 3]> = words
                    .map(|w| corner(w, mesh.p.len(), mesh.uv.len(), mesh.n.len()).map_err(&err))
                    .collect::<Result<_, _>>()?;
                if corners.len() < 3 {
                    return Err(err(format!("a face needs at least 3 corners, got {}", corners.len())));
                }
                for k in 1..corners.len() - 1 {
                    mesh.tris.push([corners[0], corners[k], corners[k + 1]]);
                }
            }
            // Groups, objects, smoothing groups and materials do not change the geometry.
            "g" | "o" | "s" | "usemtl" | "mtllib" | "l" | "p" => {}
            other => return Err(err(format!("unknown statement {other:?}"))),
        }
    }
    // Use normals only when every corner has one; the same for texture coordinates.
    let all = |k: usize| mesh.tris.iter().all(|t| t.iter().all(|c| c[k] != u32::MAX));
    let (has_n, has_uv) = (all(1), all(2));
    for t in &mut mesh.tris {
        for c in t.iter_mut() {
            if !has_n {
                c[1] = u32::MAX;
            }
            if !has_uv {
                c[2] = u32::MAX;
            }
        }
    }
    Ok(mesh)
}

/// One face corner `v`, `v/vt`, `v//vn` or `v/vt/vn` as (position, normal, uv) indices.
fn corner(word: &str, np: usize, nuv: usize, nn: usize) -> Result<[u32; 3], String> {
    let mut parts = word.split('/');
    let index = |s: Option<&str>, count: usize, what: &str| -> Result<u32, String> {
        match s {
            None | Some("") => Ok(u32::MAX),
            Some(s) => {
                let i: i64 = s.parse().map_err(|_| format!("bad {what} index {s:?} in {word:?}"))?;
                let resolved = if i < 0 { count as i64 + i } else { i - 1 };
                if i == 0 || resolved < 0 || resolved >= count as i64 {
                    return Err(format!("{what} index {i} is out of range (the file has {count} so far)"));
                }
                Ok(resolved as u32)
            }
        }
    };
    let p = index(parts.next(), np, "vertex")?;
    if p == u32::MAX {
        return Err(format!("face corner {word:?} has no vertex index"));
    }
    let uv = index(parts.next(), nuv, "texture coordinate")?;
    let n = index(parts.next(), nn, "normal")?;
    Ok([p, n, uv])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quad_with_normals_and_relative_indices() {
        let m = parse_obj("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvn 0 0 1\nf 1//1 2//1 3//1 -1//1\n").unwrap();
        assert_eq!(m.tris.len(), 2);
        assert_eq!(m.tris[1][2], [3, 0, u32::MAX]);
    }

    #[test]
    fn broken_indices_name_the_line() {
        let e = parse_obj("v 0 0 0\nv 1 0 0\n\nf 1 2 7\n").unwrap_err();
        assert_eq!(e.line, 4);
        assert!(e.message.contains("vertex index 7 is out of range"), "{e}");
        assert!(parse_obj("v 0 0\n").unwrap_err().message.contains("3 numbers"));
        assert!(parse_obj("v 0 0 0\nf 1 1\n").unwrap_err().message.contains("at least 3"));
        assert!(parse_obj("v 0 0 0\nf 0 1 1\n").unwrap_err().message.contains("out of range"));
        assert!(parse_obj("bogus 1\n").unwrap_err().message.contains("unknown statement"));
    }
}
