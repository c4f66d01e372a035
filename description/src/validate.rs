//! From the parsed schema to a [`Description`]: every value checked, every name resolved,
//! each error located at the table it concerns, in the order the file's parts are built
//! (render, camera, textures, materials, objects, lights), so that the first error found
//! is always the same one.

use std::collections::BTreeMap;

use glam::Vec3;
use toml::Spanned;

use crate::animation::FrameTime;
use crate::bundle::Assets;
use crate::keyframes::{self, light_tracks, CameraTracks, Clock, ObjectTracks, SceneTracks};
use crate::limits;
use crate::model::SamplerKind;
use crate::model::{Camera, Description, FovAxis, Light, Material, Object, Plane, RenderSettings};
use crate::obj::MeshScans;
use crate::schema::{CameraDef, KeysDef, SceneFile};
use crate::SceneError;

pub(crate) use crate::ctx::{Ctx, R};

/// The description being put together, with the names resolved so far.
pub(crate) struct Validator<'a> {
    pub(crate) ctx: Ctx<'a>,
    pub(crate) assets: &'a dyn Assets,
    pub(crate) textures: Vec<crate::model::Texture>,
    pub(crate) texture_index: BTreeMap<String, u32>,
    pub(crate) materials: Vec<Material>,
    pub(crate) material_index: BTreeMap<String, u32>,
    pub(crate) emitter_material: Option<u32>,
    pub(crate) objects: Vec<Object>,
    /// Triangles so far, every use of a mesh counted.
    pub(crate) triangles: usize,
    /// Each mesh file's scan, made once however often the scene uses it: a scene of many
    /// uses of one large file costs one scan, not one per use.
    pub(crate) scans: MeshScans,
    /// The `[animation]` table, checked.
    pub(crate) clock: Option<Clock>,
    /// The frame the scene is read at, with its shutter window (glTF assets' animations
    /// are evaluated over it too).
    pub(crate) time: Option<FrameTime>,
    /// The keys of the object being checked, until it is pushed.
    pub(crate) pending: Option<ObjectTracks>,
    /// Objects' animations.
    pub(crate) object_tracks: Vec<ObjectTracks>,
    /// The first `[[gltf]]` camera, for a scene without `[camera]`.
    pub(crate) gltf_camera: Option<crate::gltf::GltfCamera>,
    /// The `[[gltf]]` assets' punctual lights.
    pub(crate) gltf_lights: Vec<Light>,
}

/// Parses and validates a scene whose meshes and images come from `assets`, as it stands
/// at `frame` when it is animated (its first frame for `None`).
///
/// `scans` holds the counts and extents of mesh files already read, by asset path: those
/// are not scanned again.
pub(crate) fn validate(
    file: &str,
    text: &str,
    assets: &dyn Assets,
    frame: Option<u32>,
    scans: MeshScans,
) -> R<Description> {
    crate::bounds::check_text(file, text)?;
    let ctx = Ctx { file, text };
    let raw: SceneFile = toml::from_str(text).map_err(|e| {
        let span = e.span().unwrap_or(0..0);
        ctx.err(&span, e.message().trim().to_string())
    })?;

    let rspan = raw.render.span();
    let r = raw.render.into_inner();
    if r.width == 0 || r.height == 0 || r.width > limits::MAX_SIDE || r.height > limits::MAX_SIDE {
        return Err(ctx.err(
            &rspan,
            format!("image size must be 1..={} on each side, got {}x{}", limits::MAX_SIDE, r.width, r.height),
        ));
    }
    if u64::from(r.width) * u64::from(r.height) > limits::MAX_PIXELS {
        return Err(ctx.err(&rspan, format!("image has more than {} pixels", limits::MAX_PIXELS)));
    }
    if r.spp == 0 || r.spp > limits::MAX_SPP {
        return Err(ctx.err(&rspan, format!("spp must be 1..={}, got {}", limits::MAX_SPP, r.spp)));
    }
    if r.max_depth == 0 || r.max_depth > limits::MAX_DEPTH {
        return Err(
            ctx.err(&rspan, format!("max_depth must be 1..={}, got {}", limits::MAX_DEPTH, r.max_depth))
        );
    }
    let diffuse_rays = match &r.diffuse_rays {
        None => 1,
        Some(n) if (1..=limits::MAX_DIFFUSE_RAYS).contains(n.get_ref()) => *n.get_ref(),
        Some(n) => {
            return Err(ctx.err(
                &n.span(),
                format!("diffuse_rays must be 1..={}, got {}", limits::MAX_DIFFUSE_RAYS, n.get_ref()),
            ))
        }
    };
    let sampler = match &r.sampler {
        None => SamplerKind::default(),
        Some(name) => SamplerKind::from_name(name.get_ref()).ok_or_else(|| {
            ctx.err(
                &name.span(),
                format!(
                    "unknown sampler {:?}: use \"stratified\", \"independent\" or \"sobol\"",
                    name.get_ref()
                ),
            )
        })?,
    };
    let background = ctx.colour(&rspan, "render.background", r.background.0)?;
    let ambient = ctx.colour(&rspan, "render.ambient", r.ambient.0)?;
    let render = RenderSettings {
        width: r.width,
        height: r.height,
        spp: r.spp,
        seed: r.seed,
        sampler,
        max_depth: r.max_depth,
        diffuse_rays,
        background,
        ambient,
    };
    let clock = raw.animation.as_ref().map(|a| keyframes::clock(&ctx, a)).transpose()?;
    let toml_camera = raw.camera.map(|c| camera(&ctx, clock.as_ref(), c)).transpose()?;
    // A scene whose camera comes from a glTF asset has no shutter of its own: its frames
    // are sharp.
    let shutter = toml_camera.as_ref().map_or((0.0, 0.0), |(c, _)| c.shutter);
    let frame = clock.as_ref().map(|c| frame.unwrap_or(c.first));
    let time = clock.as_ref().zip(frame).map(|(c, f)| FrameTime::new(f, c.fps, shutter));

    let mut v = Validator {
        ctx,
        assets,
        textures: Vec::new(),
        texture_index: BTreeMap::new(),
        materials: Vec::new(),
        material_index: BTreeMap::new(),
        emitter_material: None,
        objects: Vec::new(),
        triangles: 0,
        scans,
        clock,
        time,
        pending: None,
        object_tracks: Vec::new(),
        gltf_camera: None,
        gltf_lights: Vec::new(),
    };
    for (name, t) in &raw.textures {
        v.texture(name, &t.span(), t.get_ref())?;
    }
    for (name, m) in &raw.materials {
        v.material(name, &m.span(), m.get_ref())?;
    }
    for s in &raw.sphere {
        v.sphere(&s.span(), s.get_ref())?;
    }
    let mut planes = Vec::new();
    for p in &raw.plane {
        let span = p.span();
        let d = p.get_ref();
        let point = v.ctx.finite(&span, "plane.point", d.point.0)?;
        let normal = v.ctx.finite(&span, "plane.normal", d.normal.0)?;
        if normal.length_squared() == 0.0 {
            return Err(v.ctx.err(&span, "plane.normal must not be the zero vector"));
        }
        let material = v.material_of(&span, &d.material)?;
        planes.push(Plane { point, normal, material });
    }
    for r in &raw.rectangle {
        v.rectangle(&r.span(), r.get_ref())?;
    }
    for b in &raw.boxes {
        v.cuboid(&b.span(), b.get_ref())?;
    }
    for t in &raw.triangle {
        v.triangle(&t.span(), t.get_ref())?;
    }
    for m in &raw.mesh {
        v.mesh(&m.span(), m.get_ref())?;
    }
    for g in &raw.gltf {
        v.gltf(&g.span(), g.get_ref())?;
    }
    let (camera, camera_tracks) = match (toml_camera, v.gltf_camera) {
        (Some(c), _) => c,
        (None, Some(g)) => (gltf_camera(&v.ctx, g)?, None),
        (None, None) => {
            return Err(v
                .ctx
                .err(&(0..0), "missing table [camera] (required unless a [[gltf]] asset has a camera)"))
        }
    };
    let mut lights = Vec::new();
    let mut light_tracks_all = Vec::new();
    for l in &raw.point_light {
        let span = l.span();
        let d = l.get_ref();
        let position = v.ctx.finite(&span, "point_light.position", d.position.0)?;
        let color = v.ctx.colour(&span, "point_light.color", d.color.0)?;
        let intensity = v.ctx.number(&span, "point_light.intensity", d.intensity, 0.0..f32::MAX)?;
        lights.push(Light::Point { position, intensity: color * intensity });
        let keys = KeysDef { keys: &d.keys, interpolation: &d.interpolation };
        let names = ("position", "intensity");
        let base = (color, intensity);
        let t = light_tracks(
            &v.ctx,
            v.clock.as_ref(),
            "point_light",
            names,
            &span,
            &keys,
            lights.len() - 1,
            base,
        )?;
        light_tracks_all.extend(t);
    }
    for l in &raw.directional_light {
        let span = l.span();
        let d = l.get_ref();
        let direction = v.ctx.finite(&span, "directional_light.direction", d.direction.0)?;
        let direction = direction
            .try_normalize()
            .ok_or_else(|| v.ctx.err(&span, "directional_light.direction must not be the zero vector"))?;
        let color = v.ctx.colour(&span, "directional_light.color", d.color.0)?;
        let irradiance = v.ctx.number(&span, "directional_light.irradiance", d.irradiance, 0.0..f32::MAX)?;
        lights.push(Light::Directional { direction, irradiance: color * irradiance });
        let keys = KeysDef { keys: &d.keys, interpolation: &d.interpolation };
        let names = ("direction", "irradiance");
        let base = (color, irradiance);
        let t = light_tracks(
            &v.ctx,
            v.clock.as_ref(),
            "directional_light",
            names,
            &span,
            &keys,
            lights.len() - 1,
            base,
        )?;
        light_tracks_all.extend(t);
    }
    for l in &raw.spot_light {
        lights.push(v.spot_light(&l.span(), l.get_ref())?);
    }
    lights.append(&mut v.gltf_lights);
    let environment = raw.environment.as_ref().map(|e| v.environment(&e.span(), e.get_ref())).transpose()?;
    let mut d = Description {
        file: file.to_string(),
        render,
        camera,
        textures: v.textures,
        materials: v.materials,
        objects: v.objects,
        planes,
        lights,
        environment,
        bundle_bytes: 0,
        sequence: None,
    };
    if let (Some(clock), Some(time)) = (v.clock, v.time) {
        let tracks =
            SceneTracks { clock, objects: v.object_tracks, camera: camera_tracks, lights: light_tracks_all };
        keyframes::evaluate(&v.ctx, &mut d, &tracks, time)?;
    }
    Ok(d)
}

/// A glTF camera as the scene's camera: a pinhole, shutter fully open.
fn gltf_camera(ctx: &Ctx, g: crate::gltf::GltfCamera) -> R<Camera> {
    let forward = g.look_at - g.position;
    if !(g.position.is_finite() && g.look_at.is_finite() && g.up.is_finite())
        || forward.cross(g.up).length_squared() == 0.0
    {
        return Err(
            ctx.err(&(0..0), "the glTF camera's node places it nowhere (its transform is degenerate)")
        );
    }
    Ok(Camera {
        position: g.position,
        look_at: g.look_at,
        up: g.up,
        fov: g.yfov,
        axis: FovAxis::Vertical,
        lens_radius: 0.0,
        focus_distance: forward.length(),
        shutter: (0.0, 1.0),
    })
}

fn camera(ctx: &Ctx, clock: Option<&Clock>, c: Spanned<CameraDef>) -> R<(Camera, Option<CameraTracks>)> {
    let span = c.span();
    let c = c.into_inner();
    let position = ctx.finite(&span, "camera.position", c.position.0)?;
    let look_at = ctx.finite(&span, "camera.look_at", c.look_at.0)?;
    let up = ctx.finite(&span, "camera.up", c.up.map_or(Vec3::Y, |u| u.0))?;
    let fov = ctx.number(&span, "camera.fov (degrees)", c.fov.unwrap_or(40.0), 1e-4..179.9)?;
    let axis = match c.fov_axis.as_deref().unwrap_or("vertical") {
        "vertical" => FovAxis::Vertical,
        "horizontal" => FovAxis::Horizontal,
        other => {
            return Err(ctx.err(
                &span,
                format!("camera.fov_axis: expected \"vertical\" or \"horizontal\", got {other:?}"),
            ))
        }
    };
    let forward = look_at - position;
    if forward.length_squared() == 0.0 || forward.cross(up).length_squared() == 0.0 {
        return Err(
            ctx.err(&span, "camera.look_at must differ from camera.position and not lie along camera.up")
        );
    }
    let focus_distance = match c.focus_distance {
        Some(d) => ctx.number(&span, "camera.focus_distance", d, 1e-6..f32::MAX)?,
        None => forward.length(),
    };
    let lens_radius = match (c.aperture, c.f_number, c.focal_length) {
        (Some(a), None, None) => ctx.number(&span, "camera.aperture (lens radius)", a, 0.0..f32::MAX)?,
        (None, Some(n), Some(f)) => {
            let n = ctx.number(&span, "camera.f_number", n, 1e-3..1e6)?;
            let f = ctx.number(&span, "camera.focal_length", f, 1e-9..f32::MAX)?;
            f / (2.0 * n)
        }
        (None, None, None) => 0.0,
        _ => {
            return Err(ctx.err(
                &span,
                "camera: give `aperture` (lens radius), or `f_number` with `focal_length`, not a mix",
            ))
        }
    };
    let [open, close] = c.shutter.unwrap_or([0.0, 1.0]);
    if !(open.is_finite()
        && close.is_finite()
        && (0.0..=1.0).contains(&open)
        && (open..=1.0).contains(&close))
    {
        return Err(ctx.err(
            &span,
            format!(
                "camera.shutter must be [open, close] with 0 <= open <= close <= 1, got [{open}, {close}]"
            ),
        ));
    }
    let keys = KeysDef { keys: &c.keys, interpolation: &c.interpolation };
    let tracks = keyframes::camera_tracks(ctx, clock, &span, &keys, c.focus_distance.is_none())?;
    let camera = Camera {
        position,
        look_at,
        up,
        fov: fov.to_radians(),
        axis,
        lens_radius,
        focus_distance,
        shutter: (open, close),
    };
    Ok((camera, tracks))
}

impl Description {
    /// Parses and validates a bundle's scene, with its assets: an animated scene as it
    /// stands during its first frame.
    pub fn parse(bundle: &crate::Bundle) -> Result<Description, SceneError> {
        Self::parse_at(bundle, None)
    }

    /// The scene as it stands during frame `frame` (animation evaluated over its shutter).
    /// A still scene is the same at every frame; an animated one refuses a frame outside
    /// its range.
    pub fn parse_frame(bundle: &crate::Bundle, frame: u32) -> Result<Description, SceneError> {
        Self::parse_at(bundle, Some(frame))
    }

    /// The frame range the scene declares, if animated.
    pub fn frames(&self) -> Option<(u32, u32)> {
        self.sequence.map(|s| s.frames)
    }

    /// [`Description::parse`] (`frame` `None`) or [`Description::parse_frame`], handed the
    /// scans of mesh files already read (`crate::obj::parse_obj_scanned`): those are not
    /// read again. Everything else, and the order and words of every error, is as
    /// `parse`'s; a file missing from `scans` is scanned as usual.
    pub fn parse_scanned(
        bundle: &crate::Bundle,
        frame: Option<u32>,
        scans: MeshScans,
    ) -> Result<Description, SceneError> {
        crate::bounds::check_bundle(bundle)?;
        let mut d = validate(&bundle.name, &bundle.text, bundle, frame, scans)?;
        crate::bounds::check_referenced(bundle, &d)?;
        d.bundle_bytes = bundle.text.len() as u64
            + bundle.assets.iter().map(|(p, a)| (p.len() + a.len()) as u64).sum::<u64>();
        Ok(d)
    }

    /// The mesh files (`[[mesh]]` tables' `file`) a bundle's scene names and the bundle
    /// carries, as normalised asset paths, each once: what a reader of the meshes may read
    /// before validating. Empty for a bundle over its bounds or a text that does not parse
    /// (validation then says why); names that are not valid asset paths are left out
    /// (validation refuses them).
    pub fn mesh_files(bundle: &crate::Bundle) -> Vec<String> {
        if crate::bounds::check_bundle(bundle).is_err() {
            return Vec::new();
        }
        let Ok(raw) = toml::from_str::<SceneFile>(&bundle.text) else { return Vec::new() };
        let mut files: Vec<String> = (raw.mesh.iter())
            .filter_map(|m| crate::bundle::check_asset_path(&m.get_ref().file).ok())
            .filter(|f| bundle.assets.binary_search_by(|(p, _)| p.as_str().cmp(f)).is_ok())
            .collect();
        files.sort();
        files.dedup();
        files
    }

    fn parse_at(bundle: &crate::Bundle, frame: Option<u32>) -> Result<Description, SceneError> {
        Self::parse_scanned(bundle, frame, MeshScans::new())
    }

    /// Parses and validates a scene text whose meshes and images come from `assets`;
    /// `file` names the scene in messages.
    pub fn parse_text(file: &str, text: &str, assets: &dyn Assets) -> Result<Description, SceneError> {
        let mut d = validate(file, text, assets, None, MeshScans::new())?;
        d.bundle_bytes = text.len() as u64;
        Ok(d)
    }

    /// Applies a submission's overrides: samples per pixel, image size. The overrides are
    /// the submitter's to check against the limits.
    pub fn apply(&mut self, spp: Option<u32>, size: Option<(u32, u32)>) {
        if let Some(spp) = spp {
            self.render.spp = spp;
        }
        if let Some((w, h)) = size {
            self.render.width = w;
            self.render.height = h;
        }
    }
}
