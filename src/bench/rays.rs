//! `tessera bench rays DIR`: the tracer's ray casting against Embree's on the same rays.
//! `bench/peers/embree_rays.py` writes the rays (DIR/<set>.rays: records of
//! seven little-endian f32, origin, direction, t_max) and Embree's figures (DIR/rays.json);
//! this casts every set through `Scene::nearest_primitive` (closest hit: the primitive
//! and distance, which is what the script times Embree returning) or
//! `Scene::transmittance` (any hit: an opaque mesh stops at the first blocker), as the
//! renderer does, checks that the hit fractions agree and prints Mrays/s with 1 and 2
//! threads beside Embree's. A last column gives the closest-hit sets' rate on one thread
//! through `Scene::intersect`, which also completes the hit (point, error bound, shading
//! normal, uv) as the renderer needs.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use anyhow::{bail, Context, Result};
use glam::Vec3;
use serde::Deserialize;
use tessera_worker::render::geometry::Ray;
use tessera_worker::render::Scene;

/// Largest difference of hit fraction from Embree's that still counts as the same rays.
const FRACTION_TOLERANCE: f64 = 1e-3;
/// Rays to a chunk of `--ab`: a few milliseconds of one thread.
const AB_CHUNK: usize = 20_000;

#[derive(Deserialize)]
struct RaysJson {
    mesh: PathBuf,
    triangles: usize,
    sets: std::collections::BTreeMap<String, SetJson>,
}

#[derive(Deserialize)]
struct SetJson {
    file: String,
    query: String,
    rays: usize,
    hit_fraction: f64,
    mrays_per_s_1t: f64,
    mrays_per_s_2t: f64,
}

/// One ray of a file: the ray and its t_max.
#[derive(Clone, Copy)]
struct Record {
    ray: Ray,
    t_max: f32,
}

fn read_rays(path: &Path, expected: usize) -> Result<Vec<Record>> {
    // Sized before it is read: a file far larger than rays.json says is refused, not loaded.
    let len = std::fs::metadata(path).with_context(|| format!("reading {}", path.display()))?.len();
    if expected.checked_mul(28).is_none_or(|want| len > want as u64) {
        bail!("{}: {len} bytes, more than the {expected} rays rays.json says", path.display());
    }
    let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    if bytes.len() % 28 != 0 {
        bail!("{}: {} bytes is not a whole number of 28-byte rays", path.display(), bytes.len());
    }
    let rays: Vec<Record> = bytes
        .chunks_exact(28)
        .enumerate()
        .map(|(i, c)| {
            let f = |k: usize| f32::from_le_bytes(c[4 * k..4 * k + 4].try_into().expect("4 bytes"));
            let (o, d) = (Vec3::new(f(0), f(1), f(2)), Vec3::new(f(3), f(4), f(5)));
            if !(o.is_finite() && d.is_finite() && (d.length() - 1.0).abs() < 1e-3) {
                bail!(
                    "{}: ray {i} has a non-finite origin or a direction not of unit length",
                    path.display()
                );
            }
            Ok(Record { ray: Ray::new(o, d), t_max: f(6) })
        })
        .collect::<Result<_>>()?;
    if rays.len() != expected {
        bail!("{}: {} rays, rays.json says {expected}", path.display(), rays.len());
    }
    Ok(rays)
}

/// The mesh as a scene: one opaque material, nothing else.
fn mesh_scene(mesh: &Path) -> Result<Scene> {
    struct One(Vec<u8>);
    impl tessera_description::bundle::Assets for One {
        fn get(&self, path: &str) -> Option<&[u8]> {
            (path == "mesh.obj").then_some(&self.0[..])
        }
    }
    let obj = One(std::fs::read(mesh).with_context(|| format!("reading the mesh {}", mesh.display()))?);
    let text =
        "[render]\nwidth = 1\nheight = 1\nspp = 1\n[camera]\nposition = [0, 0, 1]\nlook_at = [0, 0, 0]\n\
                fov = 40\n[materials.m]\ntype = \"lambert\"\nalbedo = 0.5\n[[mesh]]\nfile = \"mesh.obj\"\n\
                material = \"m\"\n";
    tessera_worker::build::parse_scene_with_assets(&mesh.display().to_string(), text, &obj)
        .map_err(|e| anyhow::anyhow!("{e}"))
}

/// What a set's rays ask.
#[derive(Clone, Copy, PartialEq)]
enum Query {
    /// Whether anything blocks the ray before its t_max.
    Any,
    /// The nearest primitive and its distance.
    Closest,
    /// The nearest hit completed as the renderer uses it.
    Completed,
}

/// Casts `rays` on `threads` threads (contiguous chunks, as the Embree script splits them);
/// returns the hits.
/// `coherent`: the rays come in pixel order, a pixel's after one another (the camera set),
/// and take the walk the renderer takes for its camera rays.
fn cast(scene: &Scene, rays: &[Record], query: Query, coherent: bool, threads: usize) -> usize {
    let one = |chunk: &[Record]| {
        chunk
            .iter()
            .filter(|r| match query {
                Query::Any => scene.transmittance(&r.ray, r.t_max, 0.0) == Vec3::ZERO,
                Query::Closest => scene.nearest_primitive(&r.ray, r.t_max, 0.0, coherent).is_some(),
                Query::Completed if coherent => scene.intersect_coherent(&r.ray, r.t_max, 0.0).is_some(),
                Query::Completed => scene.intersect(&r.ray, r.t_max, 0.0).is_some(),
            })
            .count()
    };
    let size = rays.len().div_ceil(threads.max(1)).max(1);
    std::thread::scope(|s| {
        let handles: Vec<_> = rays.chunks(size).map(|c| s.spawn(move || one(c))).collect();
        handles.into_iter().map(|h| h.join().expect("a ray thread panicked")).sum()
    })
}

/// Runs the benchmark on the rays in `dir`, `repeats` times per thread count (the median
/// is reported).
pub fn run(dir: &Path, mesh: Option<&Path>, repeats: usize, ab: bool) -> Result<ExitCode> {
    let json = dir.join("rays.json");
    let meta: RaysJson = serde_json::from_str(
        &std::fs::read_to_string(&json).with_context(|| format!("reading {}", json.display()))?,
    )
    .with_context(|| format!("{}: not the rays.json of embree_rays.py", json.display()))?;
    let mesh = mesh.map_or(meta.mesh.clone(), Path::to_path_buf);
    let t = Instant::now();
    let scene = mesh_scene(&mesh)?;
    let load = t.elapsed().as_secs_f64();
    let tris = scene.world.prims.len();
    if tris != meta.triangles {
        bail!("{}: {tris} triangles, rays.json says {}", mesh.display(), meta.triangles);
    }
    println!("{} ({tris} triangles): validated, read and BVH built in {load:.2} s", mesh.display());
    if !ab {
        println!(
            "{:8} {:8} {:>8} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9} {:>11}",
            "set", "query", "rays", "hits", "Embree", "1t M/s", "Embree", "2t M/s", "Embree", "1t, +shade"
        );
    }
    let mut ok = true;
    // The script's order: camera, random, diffuse, shadow.
    let mut names: Vec<&String> = meta.sets.keys().collect();
    let rank = |n: &str| ["camera", "random", "diffuse", "shadow"].iter().position(|k| *k == n).unwrap_or(9);
    names.sort_by_key(|n| rank(n));
    for name in names {
        let set = &meta.sets[name];
        let query = match set.query.as_str() {
            "any" => Query::Any,
            "closest" => Query::Closest,
            q => bail!("{}: set {name:?} has query {q:?}, not \"closest\" or \"any\"", json.display()),
        };
        let rays = read_rays(&dir.join(&set.file), set.rays)?;
        let coherent = name == "camera";
        if ab {
            // One thread, chunks of 20 000 rays (some 5 ms), each with the switch off and on.
            let chunks: Vec<&[Record]> = rays.chunks(AB_CHUNK).collect();
            let r = super::ab::interleave_timed(chunks.len(), repeats, |k, _| {
                cast(&scene, chunks[k], query, coherent, 1) as u64
            });
            println!("{name:8} {:8} {}", set.query, r.line());
            continue;
        }
        // The median rate of `repeats` casts, and the hits of the last.
        let rate = |query: Query, threads: usize| {
            let mut times = Vec::with_capacity(repeats);
            let mut hits = 0;
            for _ in 0..repeats {
                let t = Instant::now();
                hits = cast(&scene, &rays, query, coherent, threads);
                times.push(t.elapsed().as_secs_f64());
            }
            times.sort_by(f64::total_cmp);
            (rays.len() as f64 / times[times.len() / 2] / 1e6, hits)
        };
        let (one, hits) = rate(query, 1);
        let (two, _) = rate(query, 2);
        let completed = match query {
            Query::Closest => {
                let (rate, completed_hits) = rate(Query::Completed, 1);
                if completed_hits != hits {
                    bail!("set {name}: {completed_hits} completed hits against {hits} nearest primitives");
                }
                format!("{rate:.2}")
            }
            _ => "-".to_string(),
        };
        let fraction = hits as f64 / rays.len().max(1) as f64;
        let same = (fraction - set.hit_fraction).abs() <= FRACTION_TOLERANCE;
        ok &= same;
        println!(
            "{:8} {:8} {:>8} {:>9.4} {:>9.4} {:>9.2} {:>9.2} {:>9.2} {:>9.2} {:>11}{}",
            name,
            if query == Query::Any { "any hit" } else { "closest" },
            rays.len(),
            fraction,
            set.hit_fraction,
            one,
            set.mrays_per_s_1t,
            two,
            set.mrays_per_s_2t,
            completed,
            if same { "" } else { "  <- hit fraction differs from Embree's" }
        );
    }
    if ab {
        println!("(A: the switch off, B: on; above 1, B is faster)");
        return Ok(ExitCode::SUCCESS);
    }
    println!("(Embree's figures are the script's, from rays.json: run it just before, on the same machine)");
    if !ok {
        eprintln!(
            "hit fractions differ from Embree's by more than {FRACTION_TOLERANCE}: not the same rays or mesh"
        );
        return Ok(ExitCode::FAILURE);
    }
    Ok(ExitCode::SUCCESS)
}
