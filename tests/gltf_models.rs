//! Real glTF 2.0 files nobody here wrote: the Khronos sample models and the invalid
//! files in Debian's `assimp-testmodels` package (fetched and unpacked by
//! scripts/assimp-testmodels.sh into the build tree). Each file read as a scene
//! (`tessera render model.glb`) either validates or is refused with its one expected
//! line; each valid one renders small without NaN and not black.

use std::path::{Path, PathBuf};
use std::process::Command;

use glam::UVec2;
use tessera_description::bundle::Bundle;
use tessera_film::fixed;
use tessera_worker::batch::{render_batch, Sums};

/// The package's glTF 2.0 folder, or why it cannot be had.
fn models() -> Result<PathBuf, String> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let target = std::env::var_os("CARGO_TARGET_DIR").map_or_else(|| root.join("target"), PathBuf::from);
    let out = Command::new(root.join("scripts/assimp-testmodels.sh"))
        .arg(&target)
        .output()
        .map_err(|e| format!("cannot run scripts/assimp-testmodels.sh: {e}"))?;
    if !out.status.success() {
        return Err(String::from_utf8_lossy(&out.stderr).trim().to_string());
    }
    Ok(PathBuf::from(String::from_utf8_lossy(&out.stdout).trim()))
}

fn files(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else if p.extension().is_some_and(|e| e == "gltf" || e == "glb") {
                out.push(p);
            }
        }
    }
    out.sort();
    out
}

/// The files the package holds that Tessera refuses, with the end of their one line
/// (after the file's name): invalid files, and valid ones using what Tessera does not
/// draw, each for the reason given.
const REFUSED: &[(&str, &str)] = &[
    ("BoxTextured-glTF-techniqueWebGL/BoxTextured.gltf", "extensionsRequired[0]: the file requires extension \"KHR_technique_webgl\", which Tessera does not support (it reads KHR_lights_punctual, KHR_materials_emissive_strength, KHR_materials_ior, KHR_materials_transmission)"),
    ("BoxWithInfinites-glTF-Binary/BoxWithInfinites.glb", "meshes[0].primitives[0].attributes[\"POSITION\"]: vertex 0 of accessor 2 is [-inf, -0.5, 0.5], not finite"),
    ("IncorrectVertexArrays/Cube.gltf", "bufferViews[2]: bytes 504..936 lie beyond the end of buffer 0 (514 bytes)"),
    ("IndexOutOfRange/AllIndicesOutOfRange.gltf", "meshes[0].primitives[0].indices: index 0 of accessor 0 is 65535, but the primitive has 24 vertices"),
    ("IndexOutOfRange/IndexOutOfRange.gltf", "meshes[0].primitives[0].indices: index 0 of accessor 0 is 255, but the primitive has 24 vertices"),
    ("MissingBin/BoxTextured.gltf", "buffers[0].uri: cannot read \"BoxTextured0.bin\" (the URI \"BoxTextured0.bin\", relative to the glTF file's folder)"),
    ("RecursiveNodes/RecursiveNodes.gltf", "nodes[0]: node 0 is its own ancestor: the node hierarchy has a cycle"),
    ("SchemaFailures/sceneWrongType.gltf", "not a glTF 2.0 document: invalid type: string \"hello\", expected index into child of root at line 6 column 20"),
    ("TestNoRootNode/NoScene.gltf", "scene: scene 0 does not exist"),
    ("TestNoRootNode/SceneWithoutNodes.gltf", "not a glTF 2.0 document: missing field `nodes` at line 8 column 9"),
    ("draco/2CylinderEngine.gltf", "extensionsRequired[0]: the file requires extension \"KHR_draco_mesh_compression\", which Tessera does not support (it reads KHR_lights_punctual, KHR_materials_emissive_strength, KHR_materials_ior, KHR_materials_transmission)"),
    ("glTF-Asset-Generator/Mesh_PrimitiveMode/Mesh_PrimitiveMode_00.gltf", "meshes[0].primitives[0].mode: mode 0 (Points) is not drawn: Tessera renders surfaces, mode 4 (TRIANGLES) only"),
    ("glTF-Asset-Generator/Mesh_PrimitiveMode/Mesh_PrimitiveMode_01.gltf", "meshes[0].primitives[0].mode: mode 1 (Lines) is not drawn: Tessera renders surfaces, mode 4 (TRIANGLES) only"),
    ("glTF-Asset-Generator/Mesh_PrimitiveMode/Mesh_PrimitiveMode_02.gltf", "meshes[0].primitives[0].mode: mode 2 (LineLoop) is not drawn: Tessera renders surfaces, mode 4 (TRIANGLES) only"),
    ("glTF-Asset-Generator/Mesh_PrimitiveMode/Mesh_PrimitiveMode_03.gltf", "meshes[0].primitives[0].mode: mode 3 (LineStrip) is not drawn: Tessera renders surfaces, mode 4 (TRIANGLES) only"),
    ("glTF-Asset-Generator/Mesh_PrimitiveMode/Mesh_PrimitiveMode_04.gltf", "meshes[0].primitives[0].mode: mode 5 (TriangleStrip) is not drawn: Tessera renders surfaces, mode 4 (TRIANGLES) only"),
    ("glTF-Asset-Generator/Mesh_PrimitiveMode/Mesh_PrimitiveMode_05.gltf", "meshes[0].primitives[0].mode: mode 6 (TriangleFan) is not drawn: Tessera renders surfaces, mode 4 (TRIANGLES) only"),
    ("glTF-Asset-Generator/Mesh_PrimitiveMode/Mesh_PrimitiveMode_07.gltf", "meshes[0].primitives[0].mode: mode 0 (Points) is not drawn: Tessera renders surfaces, mode 4 (TRIANGLES) only"),
    ("glTF-Asset-Generator/Mesh_PrimitiveMode/Mesh_PrimitiveMode_08.gltf", "meshes[0].primitives[0].mode: mode 1 (Lines) is not drawn: Tessera renders surfaces, mode 4 (TRIANGLES) only"),
    ("glTF-Asset-Generator/Mesh_PrimitiveMode/Mesh_PrimitiveMode_09.gltf", "meshes[0].primitives[0].mode: mode 2 (LineLoop) is not drawn: Tessera renders surfaces, mode 4 (TRIANGLES) only"),
    ("glTF-Asset-Generator/Mesh_PrimitiveMode/Mesh_PrimitiveMode_10.gltf", "meshes[0].primitives[0].mode: mode 3 (LineStrip) is not drawn: Tessera renders surfaces, mode 4 (TRIANGLES) only"),
    ("glTF-Asset-Generator/Mesh_PrimitiveMode/Mesh_PrimitiveMode_11.gltf", "meshes[0].primitives[0].mode: mode 5 (TriangleStrip) is not drawn: Tessera renders surfaces, mode 4 (TRIANGLES) only"),
    ("glTF-Asset-Generator/Mesh_PrimitiveMode/Mesh_PrimitiveMode_12.gltf", "meshes[0].primitives[0].mode: mode 6 (TriangleFan) is not drawn: Tessera renders surfaces, mode 4 (TRIANGLES) only"),
    ("wrongTypes/badArray.gltf", "not a glTF 2.0 document: invalid type: map, expected a sequence at line 44 column 26"),
    ("wrongTypes/badNumber.gltf", "not a glTF 2.0 document: invalid type: string \"not a number\", expected f32 at line 132 column 27"),
    ("wrongTypes/badObject.gltf", "not a glTF 2.0 document: invalid type: string \"not an object\", expected an array of length 4 at line 125 column 52"),
    ("wrongTypes/badString.gltf", "not a glTF 2.0 document: invalid type: integer `42`, expected a string at line 12 column 14"),
    ("wrongTypes/badUint.gltf", "not a glTF 2.0 document: invalid type: integer `-1`, expected index into child of root at line 128 column 31"),
];

fn render_small(bundle: &Bundle) -> Result<(f64, u64), String> {
    const SIZE: (u32, u32) = (48, 48);
    const SPP: u32 = 4;
    let mut scene = tessera_worker::build::parse_bundle(bundle).map_err(|e| e.to_string())?;
    scene.apply(Some(SPP), Some(SIZE));
    let (w, h) = SIZE;
    let (mut total, mut nonfinite) = (0f64, 0u64);
    for row in 0..h {
        let pixels: Vec<UVec2> = (0..w).map(|x| UVec2::new(x, row)).collect();
        let sums = render_batch(&scene, &pixels, 0..SPP, Sums::Radiance);
        nonfinite += sums.nonfinite;
        total += sums.sums.iter().map(|&s| f64::from(fixed::mean(s, SPP))).sum::<f64>();
    }
    Ok((total / f64::from(w * h * 3), nonfinite))
}

#[test]
fn every_sample_model_validates_or_is_refused_in_one_line() {
    let dir = match models() {
        Ok(d) => d,
        Err(why) => {
            eprintln!("SKIPPED: {why}");
            return;
        }
    };
    let all = files(&dir);
    assert!(all.len() >= 40, "expected the package's glTF 2.0 files, found {}", all.len());
    let mut failures = Vec::new();
    let mut rendered = 0;
    for path in &all {
        let rel = path.strip_prefix(&dir).unwrap().to_string_lossy().to_string();
        let expected = REFUSED.iter().find(|(p, _)| *p == rel).map(|(_, m)| *m);
        let got = Bundle::read(path)
            .map_err(|e| e.to_string())
            .and_then(|b| tessera_description::Description::parse(&b).map(|_| b).map_err(|e| e.to_string()));
        match (got, expected) {
            (Ok(bundle), None) => match render_small(&bundle) {
                Ok((mean, nonfinite)) => {
                    eprintln!("{rel}: rendered, mean {mean:.4}, {nonfinite} non-finite samples");
                    rendered += 1;
                    if nonfinite > 0 || mean.is_nan() || mean <= 1e-3 {
                        failures.push(format!("{rel}: mean {mean}, {nonfinite} non-finite samples"));
                    }
                }
                Err(e) => failures.push(format!("{rel}: validated but does not build: {e}")),
            },
            (Ok(_), Some(want)) => failures.push(format!("{rel}: validated, expected the refusal {want:?}")),
            (Err(e), want) => {
                eprintln!("{rel}: refused: {e}");
                let one_line = !e.contains('\n') && e.contains(path.file_name().unwrap().to_str().unwrap());
                match want {
                    Some(w) if one_line && e.ends_with(w) => {}
                    _ => failures.push(format!("{rel}: refused with {e:?}, expected {want:?}")),
                }
            }
        }
    }
    eprintln!("{rendered} of {} files rendered", all.len());
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}
