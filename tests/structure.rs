//! The house rules ARCHITECTURE.md states, checked on the sources: the coordinator and the
//! viewer depend on no renderer crate; no source file is much over 600 lines; no two files
//! of a crate import each other, directly or around a circle.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::process::Command;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// The crates' source folders: the root CLI's and every workspace member's.
fn crate_sources() -> Vec<PathBuf> {
    let mut dirs = vec![root().join("src")];
    for member in
        ["proto", "description", "film", "coordinator", "worker", "viewer", "harness", "web", "denoise"]
    {
        dirs.push(root().join(member).join("src"));
    }
    dirs.into_iter().filter(|d| d.is_dir()).collect()
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display())) {
        let path = entry.unwrap().path();
        let name = path.file_name().unwrap().to_string_lossy().into_owned();
        if path.is_dir() {
            if name != "target" && !name.starts_with('.') {
                rust_files(&path, out);
            }
        } else if name.ends_with(".rs") {
            out.push(path);
        }
    }
}

#[test]
fn the_coordinator_and_the_viewer_depend_on_no_renderer() {
    for krate in ["tessera-coordinator", "tessera-viewer"] {
        let out = Command::new(env!("CARGO"))
            .args(["tree", "--offline", "-e", "normal", "--prefix", "none", "-p", krate])
            .current_dir(root())
            .output()
            .expect("running cargo tree");
        assert!(out.status.success(), "cargo tree -p {krate}: {}", String::from_utf8_lossy(&out.stderr));
        let tree = String::from_utf8_lossy(&out.stdout);
        let renderer: Vec<&str> = tree.lines().filter(|l| l.starts_with("tessera-worker ")).collect();
        assert!(renderer.is_empty(), "{krate} depends on the renderer:\n{tree}");
        assert!(tree.lines().any(|l| l.starts_with("tessera-description ")), "{krate}: {tree}");
    }
}

/// "About 600": a file may run a little past while it is being split, not double.
const MOST_LINES: usize = 620;

#[test]
fn no_source_file_is_over_about_600_lines() {
    let mut files = Vec::new();
    for dir in crate_sources() {
        rust_files(&dir, &mut files);
    }
    for dir in ["tests", "worker/tests", "harness/tests", "benches"] {
        if root().join(dir).is_dir() {
            rust_files(&root().join(dir), &mut files);
        }
    }
    assert!(files.len() > 100, "found only {} source files", files.len());
    let long: Vec<String> = files
        .iter()
        .filter_map(|f| {
            let n = std::fs::read_to_string(f).unwrap().lines().count();
            (n > MOST_LINES).then(|| format!("{}: {n} lines", f.strip_prefix(root()).unwrap().display()))
        })
        .collect();
    assert!(long.is_empty(), "files over {MOST_LINES} lines:\n{}", long.join("\n"));
}

/// A crate's modules by file: the module path of each file (`render::bvh::wide`), a file
/// given by `#[path = "…"]` being the module its `mod` names.
fn modules(src: &Path) -> BTreeMap<String, PathBuf> {
    let mut files = Vec::new();
    rust_files(src, &mut files);
    let mut by_file: BTreeMap<PathBuf, String> = BTreeMap::new();
    for f in &files {
        let rel = f.strip_prefix(src).unwrap().with_extension("");
        let mut parts: Vec<String> = rel.iter().map(|p| p.to_string_lossy().into_owned()).collect();
        if matches!(parts.last().map(String::as_str), Some("mod" | "lib" | "main")) {
            parts.pop();
        }
        by_file.insert(f.clone(), parts.join("::"));
    }
    // `#[path = "x_tests.rs"] mod tests;` in module m makes x_tests.rs the module m::tests.
    for f in &files {
        let text = std::fs::read_to_string(f).unwrap();
        let mut lines = text.lines().map(str::trim);
        while let Some(line) = lines.next() {
            let Some(target) = line.strip_prefix("#[path = \"").and_then(|l| l.strip_suffix("\"]")) else {
                continue;
            };
            // The next item's `mod NAME;`, whatever its visibility.
            let Some(name) = lines
                .find(|l| !l.starts_with("#["))
                .and_then(|l| l.split_once("mod ").map(|(_, r)| r))
                .map(|r| ident(r.trim_start()))
                .filter(|n| !n.is_empty())
            else {
                continue;
            };
            let file = f.parent().unwrap().join(target);
            let parent = by_file[f].clone();
            let module = if parent.is_empty() { name } else { format!("{parent}::{name}") };
            by_file.insert(file, module);
        }
    }
    by_file.into_iter().map(|(f, m)| (m, f)).collect()
}

/// `text` with its comments and string and character literals blanked (same length, same
/// lines), so that a path in a doc comment or a `{` in a string is not read as code.
fn code_only(text: &str) -> String {
    let b = text.as_bytes();
    let mut out = b.to_vec();
    let blank = |out: &mut Vec<u8>, from: usize, to: usize| {
        for c in &mut out[from..to.min(b.len())] {
            if *c != b'\n' {
                *c = b' ';
            }
        }
    };
    let mut i = 0;
    while i < b.len() {
        match b[i] {
            b'/' if b.get(i + 1) == Some(&b'/') => {
                let end = text[i..].find('\n').map_or(b.len(), |n| i + n);
                blank(&mut out, i, end);
                i = end;
            }
            b'/' if b.get(i + 1) == Some(&b'*') => {
                let end = text[i + 2..].find("*/").map_or(b.len(), |n| i + 2 + n + 2);
                blank(&mut out, i, end);
                i = end;
            }
            b'r' if b.get(i + 1).is_some_and(|&c| c == b'"' || c == b'#')
                && (i == 0 || !(b[i - 1].is_ascii_alphanumeric() || b[i - 1] == b'_')) =>
            {
                let hashes = b[i + 1..].iter().take_while(|&&c| c == b'#').count();
                if b.get(i + 1 + hashes) != Some(&b'"') {
                    i += 1;
                    continue;
                }
                let close = format!("\"{}", "#".repeat(hashes));
                let start = i + 2 + hashes;
                let end = text[start..].find(&close).map_or(b.len(), |n| start + n + close.len());
                blank(&mut out, i, end);
                i = end;
            }
            b'"' => {
                let mut j = i + 1;
                while j < b.len() && b[j] != b'"' {
                    j += if b[j] == b'\\' { 2 } else { 1 };
                }
                blank(&mut out, i, j + 1);
                i = j + 1;
            }
            // A character literal ('x', '\n', '{'), not a lifetime ('a).
            b'\'' if b.get(i + 2) == Some(&b'\'') || b.get(i + 1) == Some(&b'\\') => {
                let end = text[i + 1..].find('\'').map_or(b.len(), |n| i + 1 + n + 1);
                let end =
                    if b.get(i + 1) == Some(&b'\\') && b.get(i + 2) == Some(&b'\'') { i + 4 } else { end };
                blank(&mut out, i, end);
                i = end;
            }
            _ => i += 1,
        }
    }
    String::from_utf8(out).expect("blanking keeps UTF-8: only ASCII bytes are replaced")
}

/// The inline modules (`mod name { … }`) of a file's code: where each one's body starts
/// and ends, and its name.
fn inline_modules(code: &str) -> Vec<(usize, usize, String)> {
    let b = code.as_bytes();
    let mut found = Vec::new();
    for (at, _) in code.match_indices("mod ") {
        if at > 0 && (b[at - 1].is_ascii_alphanumeric() || b[at - 1] == b'_') {
            continue;
        }
        let rest = &code[at + 4..];
        let name: String =
            rest.trim_start().chars().take_while(|c| c.is_alphanumeric() || *c == '_').collect();
        let after = rest.trim_start()[name.len()..].trim_start();
        if name.is_empty() || !after.starts_with('{') {
            continue;
        }
        let open = code.len() - after.len();
        let mut depth = 0usize;
        let mut end = code.len();
        for (k, c) in code[open..].char_indices() {
            match c {
                '{' => depth += 1,
                '}' => {
                    depth -= 1;
                    if depth == 0 {
                        end = open + k;
                        break;
                    }
                }
                _ => {}
            }
        }
        found.push((open, end, name));
    }
    found
}

fn ident(s: &str) -> String {
    s.chars().take_while(|c| c.is_alphanumeric() || *c == '_').collect()
}

/// The items of a `{…}` group starting at `s` (just after its `{`), each as `base` and its
/// own segments, inner groups followed; `self` names `base` itself.
fn group_items(base: &[String], s: &str, out: &mut Vec<Vec<String>>) {
    let mut depth = 0usize;
    let mut start = 0;
    let mut items = Vec::new();
    for (k, c) in s.char_indices() {
        match c {
            '{' => depth += 1,
            '}' if depth == 0 => {
                items.push(&s[start..k]);
                break;
            }
            '}' => depth -= 1,
            ',' if depth == 0 => {
                items.push(&s[start..k]);
                start = k + 1;
            }
            _ => {}
        }
    }
    for item in items {
        path_item(base, item.trim(), out);
    }
}

/// One path below `base` (`a::b`, `a::{b, c}`, `self`), written at `s`: each path it names
/// goes into `out`, inner groups followed; `self` names `base` itself.
fn path_item(base: &[String], s: &str, out: &mut Vec<Vec<String>>) {
    let mut p = base.to_vec();
    let mut named = false;
    let mut rest = s;
    loop {
        let seg = ident(rest);
        if seg.is_empty() {
            if let Some(inner) = rest.strip_prefix('{') {
                group_items(&p, inner, out);
                named = false;
            }
            break;
        }
        rest = rest[seg.len()..].trim_start();
        named = true;
        if seg != "self" {
            p.push(seg);
        }
        match rest.strip_prefix("::") {
            Some(r) => rest = r.trim_start(),
            None => break,
        }
    }
    if named && !p.is_empty() {
        out.push(p);
    }
}

/// The paths a file names through `crate::` or `super::`, resolved against the module they
/// are written in (the file's, or an inline module's within it).
fn named_paths(text: &str, module: &str) -> Vec<Vec<String>> {
    let code = code_only(text);
    let inline = inline_modules(&code);
    let file: Vec<String> =
        if module.is_empty() { vec![] } else { module.split("::").map(String::from).collect() };
    let mut out = Vec::new();
    for (at, _) in code.match_indices("::") {
        // Only where a path starts: `crate::` or `super::` not preceded by an identifier
        // character or another `::`.
        let head = &code[..at];
        let word: String = head.chars().rev().take_while(|c| c.is_alphanumeric() || *c == '_').collect();
        let word: String = word.chars().rev().collect();
        if word != "crate" && word != "super" {
            continue;
        }
        let before = &head[..head.len() - word.len()];
        if before.ends_with("::") || before.ends_with(|c: char| c.is_alphanumeric() || c == '_') {
            continue;
        }
        // The module this path is written in: the file's, and the inline ones around it.
        let mut me = file.clone();
        let mut around: Vec<&(usize, usize, String)> =
            inline.iter().filter(|(s, e, _)| *s < at && at < *e).collect();
        around.sort_by_key(|(s, _, _)| *s);
        me.extend(around.into_iter().map(|(_, _, n)| n.clone()));
        let mut base: Vec<String> =
            if word == "crate" { vec![] } else { me[..me.len().saturating_sub(1)].to_vec() };
        let mut rest = code[at + 2..].trim_start();
        while let Some(r) =
            (ident(rest) == "super").then(|| rest[5..].trim_start()).and_then(|r| r.strip_prefix("::"))
        {
            base.pop();
            rest = r.trim_start();
        }
        path_item(&base, rest, &mut out);
    }
    out
}

fn is_within(inner: &str, outer: &str) -> bool {
    outer.is_empty() || inner == outer || inner.starts_with(&format!("{outer}::"))
}

/// Each file's imports of the crate's other files, leaving out a module's own ancestors and
/// descendants (a parent declares its children and they see its items: that is nesting, not
/// a circle).
fn file_graph(src: &Path) -> BTreeMap<String, BTreeSet<String>> {
    let mods = modules(src);
    let mut graph: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    for (module, file) in &mods {
        let text = std::fs::read_to_string(file).unwrap();
        let edges = graph.entry(module.clone()).or_default();
        for path in named_paths(&text, module) {
            let target = (0..=path.len()).rev().map(|n| path[..n].join("::")).find(|m| mods.contains_key(m));
            if let Some(t) = target {
                if !is_within(&t, module) && !is_within(module, &t) {
                    edges.insert(t);
                }
            }
        }
    }
    graph
}

/// The strongly connected groups of more than one file (Tarjan's algorithm).
fn circles(graph: &BTreeMap<String, BTreeSet<String>>) -> Vec<Vec<String>> {
    struct State<'a> {
        graph: &'a BTreeMap<String, BTreeSet<String>>,
        index: BTreeMap<&'a str, usize>,
        low: BTreeMap<&'a str, usize>,
        stack: Vec<&'a str>,
        on: BTreeSet<&'a str>,
        found: Vec<Vec<String>>,
    }
    fn visit<'a>(s: &mut State<'a>, v: &'a str) {
        let n = s.index.len();
        s.index.insert(v, n);
        s.low.insert(v, n);
        s.stack.push(v);
        s.on.insert(v);
        let graph = s.graph;
        for w in graph.get(v).into_iter().flatten() {
            let w = w.as_str();
            if !s.index.contains_key(w) {
                visit(s, w);
                let lw = s.low[w];
                let lv = s.low.get_mut(v).unwrap();
                *lv = (*lv).min(lw);
            } else if s.on.contains(w) {
                let iw = s.index[w];
                let lv = s.low.get_mut(v).unwrap();
                *lv = (*lv).min(iw);
            }
        }
        if s.low[v] == s.index[v] {
            let mut group = Vec::new();
            loop {
                let w = s.stack.pop().unwrap();
                s.on.remove(w);
                group.push(w.to_string());
                if w == v {
                    break;
                }
            }
            if group.len() > 1 {
                group.sort();
                s.found.push(group);
            }
        }
    }
    let mut s = State {
        graph,
        index: BTreeMap::new(),
        low: BTreeMap::new(),
        stack: Vec::new(),
        on: BTreeSet::new(),
        found: Vec::new(),
    };
    for v in graph.keys() {
        if !s.index.contains_key(v.as_str()) {
            visit(&mut s, v);
        }
    }
    s.found
}

#[test]
fn no_import_circle_between_files() {
    let mut found = Vec::new();
    for src in crate_sources() {
        for group in circles(&file_graph(&src)) {
            found.push(format!("{}: {}", src.strip_prefix(root()).unwrap().display(), group.join(" <-> ")));
        }
    }
    assert!(found.is_empty(), "files that import each other:\n{}", found.join("\n"));
}

/// The checker finds a circle of siblings through `super::` (grouped or not), and leaves
/// nesting alone.
#[test]
fn the_circle_checker_sees_circles() {
    let dir = tempfile::tempdir().unwrap();
    let src = dir.path();
    std::fs::create_dir_all(src.join("a")).unwrap();
    std::fs::write(src.join("lib.rs"), "mod a;\nmod c;\nuse crate::a::Thing;\n").unwrap();
    std::fs::write(src.join("a/mod.rs"), "mod x;\nmod y;\npub use x::Thing;\n").unwrap();
    std::fs::write(src.join("a/x.rs"), "use super::{y::Other, Thing};\npub struct Thing;\n").unwrap();
    std::fs::write(src.join("a/y.rs"), "pub struct Other(super::x::Thing);\nuse crate::c::C;\n").unwrap();
    std::fs::write(src.join("c.rs"), "pub struct C;\n#[cfg(test)]\n#[path = \"c_tests.rs\"]\nmod tests;\n")
        .unwrap();
    std::fs::write(src.join("c_tests.rs"), "use crate::a::Thing;\nuse super::C;\n").unwrap();
    // An inline test module reaching a sibling through super::super, a nested group, and
    // paths in a comment and a string that are not imports.
    std::fs::create_dir_all(src.join("d")).unwrap();
    std::fs::write(src.join("d/mod.rs"), "mod p;\nmod q;\nmod r;\nmod s;\n").unwrap();
    std::fs::write(src.join("d/p.rs"), "use super::q::Q;\npub struct P;\n").unwrap();
    std::fs::write(
        src.join("d/q.rs"),
        "pub struct Q;\n#[cfg(test)]\nmod tests {\n    use super::super::p::P;\n}\n",
    )
    .unwrap();
    std::fs::write(src.join("d/r.rs"), "use crate::{d::{s::S, p}, c::C};\npub struct R;\n").unwrap();
    std::fs::write(
        src.join("d/s.rs"),
        "/// see `super::r::R`\nconst T: &str = \"crate::d::r\";\npub struct S;\n",
    )
    .unwrap();
    let graph = file_graph(src);
    assert_eq!(
        circles(&graph),
        vec![vec!["a::x".to_string(), "a::y".to_string()], vec!["d::p".to_string(), "d::q".to_string()]],
        "{graph:?}"
    );
    assert_eq!(graph["d::r"], ["c", "d::p", "d::s"].map(String::from).into(), "{graph:?}");
    assert!(graph["d::s"].is_empty(), "comments and strings are not imports: {graph:?}");
    assert!(graph["c::tests"].contains("a"), "{graph:?}");
    assert!(!graph["c::tests"].contains("c"), "a test file within its module: {graph:?}");
}
