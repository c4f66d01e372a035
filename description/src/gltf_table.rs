//! The `[[gltf]]` table of a TOML scene: a glTF asset's scene placed among the scene's own
//! objects, its materials, textures, lights and (when the TOML has no `[camera]`) its
//! first camera added to the description. A part of the validator, beside `objects.rs`
//! and `lights.rs`; `gltf/` reads the asset and knows nothing of the validator.

use std::collections::BTreeMap;
use std::ops::Range;

use glam::Vec3;

use crate::bundle::{check_asset_path, unreadable};
use crate::gltf::{default_material, import, GltfCamera};
use crate::model::{Material, Shape, TexRef, Texture, TextureKind};
use crate::schema::GltfDef;
use crate::validate::{Validator, R};

impl Validator<'_> {
    /// Adds what a `[[gltf]]` table's asset holds.
    pub(crate) fn gltf(&mut self, span: &Range<usize>, d: &GltfDef) -> R<()> {
        let path = check_asset_path(&d.file).map_err(|e| self.ctx.err(span, format!("gltf.file: {e}")))?;
        if self.assets.get(&path).is_none() {
            return Err(self.ctx.err(span, unreadable(self.assets, "gltf.file", &d.file)));
        }
        let no_keys = Vec::new();
        let keys = crate::schema::KeysDef { keys: &no_keys, interpolation: &None };
        let (base, _) = self.placement(span, "gltf", &d.transform, &None, keys)?;
        let imported = import(&path, self.assets, d.scene.as_ref(), &base, self.time)
            .map_err(|e| self.ctx.err(span, e.to_string()))?;
        let at = self.ctx.at(span);
        let mut image_index = BTreeMap::new();
        for &(image, width, height) in &imported.images {
            image_index.insert(image, self.textures.len() as u32);
            self.textures.push(Texture {
                name: format!("{path}#images[{image}]"),
                kind: TextureKind::GltfImage { file: path.clone(), image, width, height },
                at,
            });
        }
        let remap = |t: Option<TexRef>| t.map(|t| TexRef { texture: image_index[&t.texture], ..t });
        let mut material_index = BTreeMap::new();
        for (i, mut m) in imported.materials {
            m.base_color_texture = remap(m.base_color_texture);
            m.metallic_roughness_texture = remap(m.metallic_roughness_texture);
            m.normal_texture = m.normal_texture.map(|(t, s)| (remap(Some(t)).expect("mapped"), s));
            m.emissive_texture = remap(m.emissive_texture);
            material_index.insert(i, (self.materials.len() as u32, m.emissive));
            self.materials.push(Material::Pbr(m));
        }
        let mut default = None;
        for inst in &imported.instances {
            let (material, emissive) = match inst.material {
                Some(i) => material_index[&i],
                None => *default.get_or_insert_with(|| {
                    self.materials.push(Material::Pbr(default_material()));
                    (self.materials.len() as u32 - 1, Vec3::ZERO)
                }),
            };
            let what = format!(
                "gltf {:?}: nodes[{}] (meshes[{}].primitives[{}])",
                d.file, inst.node, inst.mesh, inst.primitive
            );
            let emission = (emissive != Vec3::ZERO).then_some(emissive);
            // An emitter is a light built in world space: an animated one takes its pose at
            // the shutter's opening, as keyed TOML emitters do.
            let place = (inst.world, if emission.is_some() { None } else { inst.motion });
            self.check_reach(span, &what, inst.extent, 0.0, &place)?;
            self.count_triangles(span, inst.triangles as usize)?;
            let shape = Shape::GltfPrimitive {
                file: path.clone(),
                mesh: inst.mesh,
                primitive: inst.primitive,
                triangles: inst.triangles,
                vertices: inst.vertices,
            };
            self.push(span, shape, (material, emission), place);
        }
        if self.gltf_camera.is_none() {
            self.gltf_camera = imported.camera.map(|c: GltfCamera| c);
        }
        self.gltf_lights.extend(imported.lights);
        Ok(())
    }
}
