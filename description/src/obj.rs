//! A Wavefront OBJ reader for triangle meshes: positions, normals, texture coordinates,
//! polygons (fan-triangulated), negative (relative) indices. Errors name the line.
//!
//! One reader serves two ends: [`scan_obj`] checks a file and counts what it holds
//! without storing a vertex (validation and the summary), [`parse_obj`] keeps the data
//! (the renderer). Both see the same statements in the same order, so they refuse the
//! same files with the same messages.

use glam::{Vec2, Vec3};

/// An OBJ error: the 1-based line and what is wrong.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("line {line}: {message}")]
pub struct ObjError {
    /// 1-based line.
    pub line: usize,
    /// What is wrong.
    pub message: String,
}

/// What an OBJ file holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct ObjCounts {
    /// Positions (`v`).
    pub positions: usize,
    /// Normals (`vn`).
    pub normals: usize,
    /// Texture coordinates (`vt`).
    pub uvs: usize,
    /// Faces (`f`).
    pub faces: usize,
    /// Triangles after fan triangulation.
    pub triangles: usize,
}

/// What a scan of each mesh file found (its counts, its largest |coordinate| per axis), by
/// the asset's normalised path (`Description::parse_scanned`).
pub type MeshScans = std::collections::BTreeMap<String, (ObjCounts, Vec3)>;

/// A triangle mesh as the file gives it (object space).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ObjMesh {
    /// Positions.
    pub p: Vec<Vec3>,
    /// Normals (empty unless every corner has one).
    pub n: Vec<Vec3>,
    /// Texture coordinates (empty unless every corner has one).
    pub uv: Vec<Vec2>,
    /// Per triangle: position, normal and uv index of each corner (`u32::MAX`: none).
    pub tris: Vec<[[u32; 3]; 3]>,
}

/// Where the reader puts what it reads.
trait Sink {
    fn position(&mut self, p: Vec3);
    fn normal(&mut self, n: Vec3);
    fn uv(&mut self, uv: Vec2);
    fn triangle(&mut self, t: [[u32; 3]; 3]);
    /// Takes what another sink read from the text after this one's.
    fn append(&mut self, later: Self);
    /// Makes room for the statements `counts` counts (a face is at least one triangle), so
    /// that a large file's vectors never regrow and copy themselves.
    fn reserve(&mut self, _counts: &ObjCounts) {}
}

impl Sink for ObjMesh {
    fn position(&mut self, p: Vec3) {
        self.p.push(p);
    }
    fn normal(&mut self, n: Vec3) {
        self.n.push(n);
    }
    fn uv(&mut self, uv: Vec2) {
        self.uv.push(uv);
    }
    fn triangle(&mut self, t: [[u32; 3]; 3]) {
        self.tris.push(t);
    }
    fn append(&mut self, mut later: Self) {
        self.p.append(&mut later.p);
        self.n.append(&mut later.n);
        self.uv.append(&mut later.uv);
        self.tris.append(&mut later.tris);
    }
    fn reserve(&mut self, counts: &ObjCounts) {
        self.p.reserve(counts.positions);
        self.n.reserve(counts.normals);
        self.uv.reserve(counts.uvs);
        self.tris.reserve(counts.faces);
    }
}

/// What a scan keeps: the triangle count and the largest |coordinate| per axis.
#[derive(Default)]
struct Scan {
    triangles: usize,
    extent: Vec3,
}

impl Sink for Scan {
    fn position(&mut self, p: Vec3) {
        self.extent = self.extent.max(p.abs());
    }
    fn normal(&mut self, _: Vec3) {}
    fn uv(&mut self, _: Vec2) {}
    fn triangle(&mut self, _: [[u32; 3]; 3]) {
        self.triangles += 1;
    }
    fn append(&mut self, later: Self) {
        self.triangles += later.triangles;
        // |x| of finite coordinates: the maximum is the same in any order.
        self.extent = self.extent.max(later.extent);
    }
}

/// Checks OBJ text and counts what it holds, storing nothing per vertex.
pub fn scan_obj(text: &str) -> Result<ObjCounts, ObjError> {
    scan_obj_extent(text).map(|(counts, _)| counts)
}

/// [`scan_obj`], with the largest |coordinate| of a position on each axis (a box around
/// the origin holding every vertex, for checking where a transform takes them).
pub fn scan_obj_extent(text: &str) -> Result<(ObjCounts, Vec3), ObjError> {
    let mut sink = Scan::default();
    let counts = read(text, &mut sink)?;
    Ok((ObjCounts { triangles: sink.triangles, ..counts }, sink.extent))
}

/// An OBJ file parsed, with what [`scan_obj_extent`] would have said of it.
#[derive(Debug, Clone, PartialEq)]
pub struct ParsedObj {
    /// The mesh, as [`parse_obj`] gives it.
    pub mesh: ObjMesh,
    /// The counts, as [`scan_obj`] gives them.
    pub counts: ObjCounts,
    /// The largest |coordinate| per axis, as [`scan_obj_extent`] gives it.
    pub extent: Vec3,
}

/// Parses OBJ text into a mesh (object space).
pub fn parse_obj(text: &str) -> Result<ObjMesh, ObjError> {
    parse_counted(text).map(|(mesh, _)| mesh)
}

/// [`parse_obj`] with the counts and extent of [`scan_obj_extent`], from one pass over the
/// text: what a reader that needs both (the worker validates, then builds) reads once.
pub fn parse_obj_scanned(text: &str) -> Result<ParsedObj, ObjError> {
    let (mesh, counts) = parse_counted(text)?;
    // The scan's fold: a maximum of |x| of finite coordinates is the same in any order.
    let extent = mesh.p.iter().fold(Vec3::ZERO, |e, p| e.max(p.abs()));
    let counts = ObjCounts { triangles: mesh.tris.len(), ..counts };
    Ok(ParsedObj { mesh, counts, extent })
}

fn parse_counted(text: &str) -> Result<(ObjMesh, ObjCounts), ObjError> {
    let mut mesh = ObjMesh::default();
    let counts = read(text, &mut mesh)?;
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
    Ok((mesh, counts))
}

/// Text at least this long is read in parallel chunks.
const PARALLEL_BYTES: usize = 1 << 20;

/// Reads every statement into `sink`; returns the counts of positions, normals, uvs and
/// faces (triangles are the sink's to count). A large file is read in chunks of whole
/// lines on every core: a first pass counts each chunk's lines and vertex statements, so
/// that each chunk then knows the line numbers and the vertices before it, and the second
/// reads the chunks in parallel and joins them in order. The result, and the first error
/// (the one of the lowest line), are those of one sequential pass.
fn read<S: Sink + Default + Send>(text: &str, sink: &mut S) -> Result<ObjCounts, ObjError> {
    let threads = rayon::current_num_threads();
    if text.len() < PARALLEL_BYTES || threads < 2 {
        return read_lines(text, is_plain(text), 0, ObjCounts::default(), sink);
    }
    use rayon::prelude::*;
    let chunks = chunks(text, threads * 4);
    // Whether each chunk is plain is found once, for both passes.
    let plain: Vec<bool> = chunks.par_iter().map(|c| is_plain(c)).collect();
    let before: Vec<(usize, ObjCounts)> =
        chunks.par_iter().zip(&plain).map(|(c, &plain)| count_lines(c, plain)).collect();
    let mut starts = Vec::with_capacity(chunks.len());
    let (mut line, mut n) = (0, ObjCounts::default());
    for (lines, c) in &before {
        starts.push((line, n));
        line += lines;
        n.positions += c.positions;
        n.normals += c.normals;
        n.uvs += c.uvs;
    }
    let parts: Vec<Result<(S, ObjCounts), ObjError>> = chunks
        .par_iter()
        .zip(&plain)
        .zip(starts.par_iter().zip(&before))
        .map(|((c, &plain), (&(line, n), (_, own)))| {
            let mut part = S::default();
            part.reserve(own);
            read_lines(c, plain, line, n, &mut part).map(|counts| (part, counts))
        })
        .collect();
    let faces = before.iter().map(|(_, c)| c.faces).sum();
    sink.reserve(&ObjCounts { faces, ..n });
    let mut total = ObjCounts::default();
    for part in parts {
        let (part, counts) = part?;
        sink.append(part);
        // The vertex counts run on from chunk to chunk; faces are each chunk's own.
        total = ObjCounts { faces: total.faces + counts.faces, ..counts };
    }
    Ok(total)
}

/// `text` cut after newlines into about `count` pieces.
fn chunks(text: &str, count: usize) -> Vec<&str> {
    let mut out = Vec::with_capacity(count);
    let mut rest = text;
    let size = text.len().div_ceil(count).max(1);
    while !rest.is_empty() {
        let cut = match rest.as_bytes().get(size..).and_then(|b| b.iter().position(|&c| c == b'\n')) {
            Some(at) => size + at + 1,
            None => rest.len(),
        };
        let (piece, tail) = rest.split_at(cut);
        out.push(piece);
        rest = tail;
    }
    out
}

/// The lines of `text` and its vertex statements (what the chunks after it need to know);
/// `plain` is [`is_plain`]`(text)`.
fn count_lines(text: &str, plain: bool) -> (usize, ObjCounts) {
    let mut n = ObjCounts::default();
    let mut lines = 0;
    for raw in text.lines() {
        lines += 1;
        let keyword = if plain {
            AsciiWords(raw).next()
        } else if raw.is_ascii() {
            AsciiWords(content(raw)).next()
        } else {
            content(raw).split_whitespace().next()
        };
        match keyword {
            Some("v") => n.positions += 1,
            Some("vn") => n.normals += 1,
            Some("vt") => n.uvs += 1,
            Some("f") => n.faces += 1,
            _ => {}
        }
    }
    (lines, n)
}

/// Whether `text` is ASCII without a comment: then every line is its own content and
/// splits on ASCII whitespace, and the per-line checks are skipped. A generated mesh
/// usually is, and those checks were a tenth of reading the 1M-triangle terrain, in the
/// coordinator's validation and the worker's build both (docs/speed.md, "Ninth part");
/// here they are two passes over the whole text at memory speed.
fn is_plain(text: &str) -> bool {
    text.is_ascii() && !text.as_bytes().contains(&b'#')
}

/// A line without its comment.
#[inline]
fn content(raw: &str) -> &str {
    if raw.is_ascii() {
        // Lines are short: a plain loop beats `memchr`'s set-up.
        raw.as_bytes().iter().position(|&b| b == b'#').map_or(raw, |at| &raw[..at])
    } else {
        raw.split('#').next().unwrap_or("")
    }
}

/// Reads the statements of `text` (`plain`: [`is_plain`]`(text)`), whose first line is
/// number `first_line + 1` and before which the file had the vertices counted in `n`;
/// returns the counts after it.
fn read_lines(
    text: &str,
    plain: bool,
    first_line: usize,
    mut n: ObjCounts,
    sink: &mut impl Sink,
) -> Result<ObjCounts, ObjError> {
    for (i, raw) in text.lines().enumerate() {
        let line = first_line + i + 1;
        // A million-line file is mostly short ASCII lines: split those on bytes. Lines with
        // other characters take `split_whitespace`, which knows Unicode's spaces; both
        // split ASCII text alike (U+0009..U+000D and U+0020 are its ASCII whitespace).
        if plain {
            statement(AsciiWords(raw), line, &mut n, sink)?;
        } else if raw.is_ascii() {
            statement(AsciiWords(content(raw)), line, &mut n, sink)?;
        } else {
            statement(content(raw).split_whitespace(), line, &mut n, sink)?;
        }
    }
    Ok(n)
}

/// The words of an ASCII line, split on ASCII whitespace as `char::is_whitespace` sees it.
#[derive(Clone)]
struct AsciiWords<'a>(&'a str);

impl<'a> Iterator for AsciiWords<'a> {
    type Item = &'a str;
    #[inline]
    fn next(&mut self) -> Option<&'a str> {
        let space = |b: &u8| matches!(b, b' ' | b'\t'..=b'\r');
        let bytes = self.0.as_bytes();
        let start = bytes.iter().position(|b| !space(b))?;
        let len = bytes[start..].iter().position(space).unwrap_or(bytes.len() - start);
        // ASCII bytes are char boundaries: the slices are valid.
        let (word, rest) = self.0[start..].split_at(len);
        self.0 = rest;
        Some(word)
    }
}

/// One statement (a line's words) into `sink`, counted in `n`.
#[inline]
fn statement<'a>(
    mut words: impl Iterator<Item = &'a str>,
    line: usize,
    n: &mut ObjCounts,
    sink: &mut impl Sink,
) -> Result<(), ObjError> {
    let err = |message: String| ObjError { line, message };
    let Some(keyword) = words.next() else { return Ok(()) };
    let mut numbers = |count: usize| -> Result<[f32; 3], ObjError> {
        let mut v = [0f32; 3];
        let mut got = 0;
        for (slot, w) in v.iter_mut().zip(words.by_ref().take(count)) {
            *slot = w.parse::<f32>().map_err(|_| err(format!("expected a number, got {w:?}")))?;
            got += 1;
        }
        if got < count {
            return Err(err(format!("expected {count} numbers after {keyword:?}")));
        }
        if v.iter().any(|x| !x.is_finite()) {
            return Err(err("coordinates must be finite".into()));
        }
        Ok(v)
    };
    match keyword {
        "v" => {
            sink.position(Vec3::from(numbers(3)?));
            n.positions += 1;
        }
        "vn" => {
            sink.normal(Vec3::from(numbers(3)?));
            n.normals += 1;
        }
        "vt" => {
            let v = numbers(2)?;
            sink.uv(Vec2::new(v[0], v[1]));
            n.uvs += 1;
        }
        "f" => {
            // Fan triangulation as the corners come: no list of corners is kept.
            let (mut first, mut prev, mut corners) = ([0u32; 3], [0u32; 3], 0usize);
            for w in words {
                // Bounded before anything is made of them: the builder holds a face's
                // triangles as it goes.
                if corners == crate::limits::MAX_FACE_CORNERS {
                    return Err(err(format!(
                        "a face has more than {} corners",
                        crate::limits::MAX_FACE_CORNERS
                    )));
                }
                let c = corner(w, n.positions, n.uvs, n.normals).map_err(&err)?;
                match corners {
                    0 => first = c,
                    1 => {}
                    // A face that fails later fails the whole file: its first triangles never count.
                    _ => sink.triangle([first, prev, c]),
                }
                prev = c;
                corners += 1;
            }
            if corners < 3 {
                return Err(err(format!("a face needs at least 3 corners, got {corners}")));
            }
            n.faces += 1;
        }
        // Groups, objects, smoothing groups and materials do not change the geometry.
        "g" | "o" | "s" | "usemtl" | "mtllib" | "l" | "p" => {}
        other => return Err(err(format!("unknown statement {other:?}"))),
    }
    Ok(())
}

/// One face corner `v`, `v/vt`, `v//vn` or `v/vt/vn` as (position, normal, uv) indices.
fn corner(word: &str, np: usize, nuv: usize, nn: usize) -> Result<[u32; 3], String> {
    // The common case, a bare positive vertex index, without the general path's splitting
    // and parsing (the same value and checks).
    if (1..=9).contains(&word.len()) && word.bytes().all(|b| b.is_ascii_digit()) {
        let i = word.bytes().fold(0usize, |v, b| v * 10 + usize::from(b - b'0'));
        if i >= 1 && i <= np {
            return Ok([(i - 1) as u32, u32::MAX, u32::MAX]);
        }
    }
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

    /// The byte splitter of ASCII lines splits as `split_whitespace` does.
    #[test]
    fn ascii_words_split_like_split_whitespace() {
        for line in
            ["", "   ", "v 1 2 3", "\tv\x0b1\x0c2\r3  ", "f 1/2/3  4//5\t6", "  vn  -0 +1 .5e3 ", "x\t\ty"]
        {
            let ours: Vec<&str> = AsciiWords(line).collect();
            let std: Vec<&str> = line.split_whitespace().collect();
            assert_eq!(ours, std, "{line:?}");
        }
        // A line with a non-ASCII space takes the Unicode splitter.
        let m = parse_obj("v 0\u{a0}0 0\nv 1 0 0\nv 0 1 0 # é\nf 1 2 3\n").unwrap();
        assert_eq!(m.p.len(), 3);
        assert_eq!(m.tris.len(), 1);
    }

    /// A text without comments takes the plain path, and reads as the per-line path reads it.
    #[test]
    fn text_without_comments_reads_as_line_by_line() {
        let plain = "v 0 0 0\nv 1 0 0\t\nv 1 1 0\r\nv  0 1 0\nvt 0 0\nvn 0 0 1\n\n  f 1/1/1 2/1/1 3/1/1 4/1/1\nf -1 -2 -3\n";
        // The same statements, each line taking the path that looks for comments.
        let commented = format!("{plain}# the end\n");
        assert!(is_plain(plain) && !is_plain(&commented));
        assert_eq!(parse_obj_scanned(plain).unwrap(), parse_obj_scanned(&commented).unwrap());
        assert_eq!(count_lines(plain, true).1, count_lines(&commented, false).1);
        let bad = "v 0 0 0\nv 1 0 0\nf 1 2 x\n";
        assert_eq!(parse_obj(bad).unwrap_err(), parse_obj(&format!("{bad}#\n")).unwrap_err());
    }

    /// A file read in parallel chunks gives what one sequential pass gives: the same mesh,
    /// counts and extent, and the same first error with its line.
    #[test]
    fn parallel_chunks_read_like_one_pass() {
        let mut text = String::new();
        let n = 40_000;
        for i in 0..n {
            text.push_str(&format!("v {} {} -{}.25 # c\nvt 0.{i} 1\nvn 0 0 1\n", i % 97, i / 97, i % 13));
        }
        for i in 0..n - 2 {
            // Absolute and relative corners, with and without normals and uvs.
            text.push_str(&format!("f {}/{}/1 -2 -1//-1\n", i + 1, i + 1));
        }
        assert!(text.len() > 2 * PARALLEL_BYTES);
        let sequential = |t: &str| {
            let mut m = ObjMesh::default();
            read_lines(t, is_plain(t), 0, ObjCounts::default(), &mut m).map(|c| (m, c))
        };
        let pool = rayon::ThreadPoolBuilder::new().num_threads(3).build().unwrap();
        let mut m = ObjMesh::default();
        let c = pool.install(|| read(&text, &mut m)).unwrap();
        // Room made from the first pass's counts (every face here is one triangle): the
        // vectors were never regrown.
        let room = |m: &ObjMesh| [m.p.capacity(), m.n.capacity(), m.uv.capacity(), m.tris.capacity()];
        assert_eq!(room(&m), [m.p.len(), m.n.len(), m.uv.len(), m.tris.len()]);
        assert_eq!((m, c), sequential(&text).unwrap());
        let scan = pool.install(|| scan_obj_extent(&text)).unwrap();
        let mut s = Scan::default();
        let sc = read_lines(&text, is_plain(&text), 0, ObjCounts::default(), &mut s).unwrap();
        assert_eq!(scan, (ObjCounts { triangles: s.triangles, ..sc }, s.extent));
        // Errors late in the file, one of them behind a chunk boundary: the first is named.
        let bad = format!("{text}f 1 2 {}\nv x 0 0\n", n + 1);
        let mut m = ObjMesh::default();
        let e = pool.install(|| read(&bad, &mut m)).unwrap_err();
        assert_eq!(e, sequential(&bad).unwrap_err());
        assert_eq!(e.line, 4 * n - 2 + 1);
    }

    #[test]
    fn scan_counts_what_parse_keeps() {
        let text = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvn 0 0 1\n# a quad and a triangle\n\
                    f 1//1 2//1 3//1 4//1\nf 1 2 3\n";
        let c = scan_obj(text).unwrap();
        assert_eq!(c, ObjCounts { positions: 4, normals: 1, uvs: 1, faces: 2, triangles: 3 });
        assert_eq!(parse_obj(text).unwrap().tris.len(), c.triangles);
    }

    /// The scanned parse says what a scan says, on one pass and on parallel chunks.
    #[test]
    fn scanned_parse_counts_like_a_scan() {
        let mut big = String::new();
        for i in 0..60_000 {
            big.push_str(&format!("v {} -{} {}.5\nvt 0 1\n", i % 89, i / 89, i % 7));
        }
        for i in 3..60_000 {
            big.push_str(&format!("f {} {}/1 -3 {}\n", i, i - 1, i - 2));
        }
        let small =
            "v 0 0 0\nv -3 1 0\nv 1 1 -0\nv 0 1 0\nvt 0 0\nvn 0 0 1\nf 1//1 2//1 3//1 4//1\nf 1 2 3\n";
        let pool = rayon::ThreadPoolBuilder::new().num_threads(2).build().unwrap();
        for text in [small, big.as_str()] {
            let p = pool.install(|| parse_obj_scanned(text)).unwrap();
            let (counts, extent) = scan_obj_extent(text).unwrap();
            assert_eq!(
                (p.counts, p.extent.to_array().map(f32::to_bits)),
                (counts, extent.to_array().map(f32::to_bits))
            );
            assert_eq!(p.mesh, parse_obj(text).unwrap());
        }
        assert_eq!(
            parse_obj_scanned("v 0 0 0\nf 1 1 2\n").unwrap_err(),
            scan_obj("v 0 0 0\nf 1 1 2\n").unwrap_err()
        );
    }

    #[test]
    fn scan_refuses_what_parse_refuses_with_the_same_words() {
        for bad in [
            "v 0 0 0\nv 1 0 0\n\nf 1 2 7\n",
            "v 0 0\n",
            "v 0 0 x\n",
            "v 0 0 inf\n",
            "v 0 0 0\nf 1 1\n",
            "v 0 0 0\nf 0 1 1\n",
            "v 0 0 0\nf 1/2 1 1\n",
            "v 0 0 0\nf /1 1 1\n",
            "v 0 0 0\nf a 1 1\n",
            "bogus 1\n",
        ] {
            let (s, p) = (scan_obj(bad).unwrap_err(), parse_obj(bad).unwrap_err());
            assert_eq!(s, p, "{bad:?}");
        }
    }
}
