//! A glTF file rendered on its own (`tessera render model.glb`): the TOML scene that
//! wraps it as a `[[gltf]]` table, with the defaults `docs/gltf.md` documents.

use super::{framing_camera, import, GltfError};
use crate::assets::Assets;
use crate::transform::Trs;

/// Image height of a wrapped glTF file; its width follows the file's camera's aspect
/// ratio, else 4:3.
pub const DEFAULT_HEIGHT: u32 = 480;
/// Samples per pixel of a wrapped glTF file.
pub const DEFAULT_SPP: u32 = 64;
/// Vertical field of view of the framing camera, degrees.
pub const DEFAULT_FOV_DEGREES: f32 = 40.0;
/// Radiance of the uniform white sky (`[environment] color`) that lights a wrapped glTF
/// file.
pub const DEFAULT_SKY: f32 = 0.8;

fn v3(v: glam::Vec3) -> String {
    format!("[{:?}, {:?}, {:?}]", v.x, v.y, v.z)
}

/// The scene text for the glTF asset `file` (an asset of `assets`): its own camera when
/// it has one, else one framing its bounds.
pub fn scene_text(file: &str, assets: &dyn Assets) -> Result<String, GltfError> {
    let imported = import(file, assets, None, &Trs::default(), None)?;
    let aspect = imported.camera.and_then(|c| c.aspect_ratio).unwrap_or(4.0 / 3.0).clamp(0.1, 10.0);
    let width = ((DEFAULT_HEIGHT as f32 * aspect).round() as u32).max(1);
    let quoted = toml::Value::String(file.to_string()).to_string();
    let mut text = format!(
        "# The scene Tessera renders for the glTF file {quoted} (its defaults: docs/gltf.md).\n\
         [render]\nwidth = {width}\nheight = {DEFAULT_HEIGHT}\nspp = {DEFAULT_SPP}\n\n\
         [environment]\ncolor = {DEFAULT_SKY:?}\n\n"
    );
    if imported.camera.is_none() {
        let fov = DEFAULT_FOV_DEGREES.to_radians();
        let bounds = imported.bounds.filter(|(lo, hi)| lo.is_finite() && hi.is_finite());
        let c = bounds.map(|b| framing_camera(b, fov, aspect));
        let (position, look_at) =
            c.map_or((glam::Vec3::new(0.0, 0.0, 5.0), glam::Vec3::ZERO), |c| (c.position, c.look_at));
        text += &format!(
            "[camera]\nposition = {}\nlook_at = {}\nfov = {DEFAULT_FOV_DEGREES:?}\n\n",
            v3(position),
            v3(look_at)
        );
    }
    text += &format!("[[gltf]]\nfile = {quoted}\n");
    Ok(text)
}
