//! Objects: spheres, rectangles, boxes, triangles and meshes, each checked with its
//! surface (material or emission) and placement (transform and motion). Meshes are scanned,
//! not read: the triangle budget is counted before anything is built, every use of a mesh
//! counted again.

use std::ops::Range;

use glam::Vec3;

use crate::bundle::{check_asset_path, unreadable};
use crate::keyframes::object_tracks;
use crate::limits;
use crate::model::{box_faces, placed_rect, Color, Location, Material, Object, Shape};
use crate::obj::scan_obj_extent;
use crate::schema::{
    BoxDef, KeysDef, MeshDef, RectangleDef, Rgb, SphereDef, TransformDef, TransformKey, TriangleDef,
};
use crate::transform::Trs;
use crate::validate::{Validator, R};

impl Validator<'_> {
    pub(crate) fn surface(
        &mut self,
        span: &Range<usize>,
        what: &str,
        material: Option<&String>,
        emission: Option<Rgb>,
    ) -> R<(u32, Option<Vec3>)> {
        let emission =
            emission.map(|e| self.ctx.colour(span, &format!("{what}.emission"), e.0)).transpose()?;
        match (material, emission) {
            (Some(_), Some(_)) => Err(self.ctx.err(
                span,
                format!("{what}: an emitter reflects nothing; give `material` or `emission`, not both"),
            )),
            (Some(m), None) => Ok((self.material_of(span, m)?, None)),
            (None, Some(e)) => {
                let black = *self.emitter_material.get_or_insert_with(|| {
                    self.materials.push(Material::Lambert { albedo: Color::Const(Vec3::ZERO) });
                    self.materials.len() as u32 - 1
                });
                Ok((black, Some(e)))
            }
            (None, None) => {
                Err(self.ctx.err(span, format!("{what} needs a `material` (or an `emission`, for a light)")))
            }
        }
    }

    fn trs(&self, span: &Range<usize>, what: &str, t: &TransformDef, base: &Trs) -> R<Trs> {
        let translate =
            t.translate.map(|v| self.ctx.finite(span, &format!("{what}.translate"), v.0)).transpose()?;
        let rotate =
            t.rotate.map(|v| self.ctx.finite(span, &format!("{what}.rotate (degrees)"), v.0)).transpose()?;
        let scale = t.scale.map(|v| self.ctx.finite(span, &format!("{what}.scale"), v.0)).transpose()?;
        if let Some(s) = scale {
            if s.abs().min_element() < 1e-12 {
                return Err(self.ctx.err(span, format!("{what}.scale must not be zero, got {s}")));
            }
        }
        let mut trs = *base;
        if let Some(v) = translate {
            trs.translate = v;
        }
        if let Some(v) = rotate {
            trs.rotate = Trs::new(Vec3::ZERO, v, Vec3::ONE).rotate;
        }
        if let Some(v) = scale {
            trs.scale = v;
        }
        Ok(trs)
    }

    /// The static transform and the motion (if any) of an object; its keys, if any, are
    /// checked into the animation of the object pushed next.
    pub(crate) fn placement(
        &mut self,
        span: &Range<usize>,
        what: &'static str,
        t: &Option<TransformDef>,
        m: &Option<TransformDef>,
        keys: KeysDef<TransformKey>,
    ) -> R<(Trs, Option<Trs>)> {
        let next = self.objects.len();
        self.pending = object_tracks(&self.ctx, self.clock.as_ref(), what, span, &keys, m.is_some(), next)?;
        let start = self.trs(span, &format!("{what}.transform"), &t.unwrap_or_default(), &Trs::default())?;
        let Some(m) = m else { return Ok((start, None)) };
        let end = self.trs(span, &format!("{what}.motion"), m, &start)?;
        if end == start {
            return Ok((start, None));
        }
        Ok((start, Some(end)))
    }

    /// Checks that an object whose points lie within `extent` (largest |coordinate| per
    /// axis) and `radius` around them stays within [`limits::MAX_COORDINATE`] of the
    /// origin wherever its placement takes it: a transform that overflows would make it
    /// vanish (or fill the image with NaN) without a word. Rotations keep lengths and a
    /// motion interpolates between its ends, so |t| + |s|·r at both ends bounds it all.
    pub(crate) fn check_reach(
        &self,
        span: &Range<usize>,
        what: &str,
        extent: Vec3,
        radius: f32,
        place: &(Trs, Option<Trs>),
    ) -> R<()> {
        // In f64: the squares of coordinates near 1e20 already overflow f32.
        let r = extent.as_dvec3().length() + f64::from(radius);
        let (start, end) = place;
        let reach = |t: &Trs| t.translate.as_dvec3().length() + f64::from(t.scale.abs().max_element()) * r;
        let far = end.as_ref().map_or(reach(start), |e| reach(start).max(reach(e)));
        let far = self.pending.as_ref().map_or(far, |p| far.max(reach(&p.reach_bound(start))));
        let matrix_finite = start.matrix().is_finite() && end.as_ref().is_none_or(|e| e.matrix().is_finite());
        if !(far <= limits::MAX_COORDINATE) || !matrix_finite {
            return Err(self.ctx.err(
                span,
                format!(
                    "{what}: its transform takes it {far:.3e} from the origin, beyond the limit of {:e}; \
                     its coordinates would overflow",
                    limits::MAX_COORDINATE
                ),
            ));
        }
        Ok(())
    }

    pub(crate) fn push(
        &mut self,
        span: &Range<usize>,
        shape: Shape,
        surface: (u32, Option<Vec3>),
        place: (Trs, Option<Trs>),
    ) {
        let at: Location = self.ctx.at(span);
        let (material, emission) = surface;
        let (transform, motion) = place;
        self.objects.push(Object { shape, material, emission, transform, motion, at });
        self.object_tracks.extend(self.pending.take());
    }

    pub(crate) fn sphere(&mut self, span: &Range<usize>, d: &SphereDef) -> R<()> {
        let center = self.ctx.finite(span, "sphere.center", d.center.0)?;
        if !(d.radius.is_finite() && d.radius > 0.0) {
            return Err(self
                .ctx
                .err(span, format!("sphere.radius must be a positive number, got {}", d.radius)));
        }
        let (material, emission) = self.surface(span, "sphere", d.material.as_ref(), d.emission)?;
        let (trs, motion) = self.placement(
            span,
            "sphere",
            &d.transform,
            &d.motion,
            KeysDef { keys: &d.keys, interpolation: &d.interpolation },
        )?;
        let uniform = |t: &Trs| {
            (t.scale.abs().max_element() - t.scale.abs().min_element()) <= 1e-6 * t.scale.abs().max_element()
        };
        if !uniform(&trs) || motion.as_ref().is_some_and(|end| !uniform(end)) {
            return Err(self
                .ctx
                .err(span, "sphere: scale must be uniform (one number); use a mesh for ellipsoids"));
        }
        if self.pending.as_ref().is_some_and(|p| !p.uniform_scale()) {
            return Err(self.ctx.err(span, "sphere.keys: scale must be uniform (one number)"));
        }
        if emission.is_some() && motion.is_some() {
            return Err(self
                .ctx
                .err(span, "sphere: lights cannot move (give `emission` or `motion`, not both)"));
        }
        self.check_reach(span, "sphere", center.abs(), d.radius, &(trs, motion))?;
        self.push(span, Shape::Sphere { center, radius: d.radius }, (material, emission), (trs, motion));
        Ok(())
    }

    /// Checks a parallelogram `(c, u, v)` as the renderer will hold it.
    fn check_rect(
        &self,
        span: &Range<usize>,
        what: &str,
        rect: (Vec3, Vec3, Vec3),
        emits: bool,
        trs: &Trs,
        moves: bool,
    ) -> R<()> {
        let (_, u, v) = placed_rect(rect, trs, moves);
        if !(u.cross(v).length_squared() > 0.0) {
            return Err(self
                .ctx
                .err(span, format!("{what}: the edges u and v must not be parallel or zero")));
        }
        if emits && moves {
            return Err(self.ctx.err(span, format!("{what}: lights cannot move")));
        }
        Ok(())
    }

    pub(crate) fn rectangle(&mut self, span: &Range<usize>, d: &RectangleDef) -> R<()> {
        let c = self.ctx.finite(span, "rectangle.center", d.center.0)?;
        let u = self.ctx.finite(span, "rectangle.u", d.u.0)?;
        let v = self.ctx.finite(span, "rectangle.v", d.v.0)?;
        let (material, emission) = self.surface(span, "rectangle", d.material.as_ref(), d.emission)?;
        let (trs, motion) = self.placement(
            span,
            "rectangle",
            &d.transform,
            &d.motion,
            KeysDef { keys: &d.keys, interpolation: &d.interpolation },
        )?;
        self.check_reach(span, "rectangle", c.abs() + u.abs() + v.abs(), 0.0, &(trs, motion))?;
        self.check_rect(span, "rectangle", (c, u, v), emission.is_some(), &trs, motion.is_some())?;
        self.push(span, Shape::Rectangle { center: c, u, v }, (material, emission), (trs, motion));
        Ok(())
    }

    pub(crate) fn cuboid(&mut self, span: &Range<usize>, d: &BoxDef) -> R<()> {
        let (lo, hi) =
            (self.ctx.finite(span, "box.min", d.min.0)?, self.ctx.finite(span, "box.max", d.max.0)?);
        if !lo.cmplt(hi).all() {
            return Err(self
                .ctx
                .err(span, format!("box.min must be below box.max on every axis, got {lo} and {hi}")));
        }
        let material = self.material_of(span, &d.material)?;
        let (trs, motion) = self.placement(
            span,
            "box",
            &d.transform,
            &d.motion,
            KeysDef { keys: &d.keys, interpolation: &d.interpolation },
        )?;
        self.check_reach(span, "box", lo.abs().max(hi.abs()), 0.0, &(trs, motion))?;
        for face in box_faces(lo, hi) {
            self.check_rect(span, "box", face, false, &trs, motion.is_some())?;
        }
        self.push(span, Shape::Box { min: lo, max: hi }, (material, None), (trs, motion));
        Ok(())
    }

    /// An emitting triangle or mesh is one light built in world space: it cannot move.
    fn check_still_light(
        &self,
        span: &Range<usize>,
        what: &str,
        surface: &(u32, Option<Vec3>),
        place: &(Trs, Option<Trs>),
    ) -> R<()> {
        if surface.1.is_some() && (place.1.is_some() || self.pending.is_some()) {
            return Err(self.ctx.err(
                span,
                format!("{what}: lights cannot move (give `emission` or `motion`/`keys`, not both)"),
            ));
        }
        Ok(())
    }

    pub(crate) fn triangle(&mut self, span: &Range<usize>, d: &TriangleDef) -> R<()> {
        let mut vertices = [Vec3::ZERO; 3];
        for (i, (slot, v)) in vertices.iter_mut().zip(&d.vertices).enumerate() {
            *slot = self.ctx.finite(span, &format!("triangle.vertices[{i}]"), v.0)?;
        }
        let surface = self.surface(span, "triangle", d.material.as_ref(), d.emission)?;
        let place = self.placement(
            span,
            "triangle",
            &d.transform,
            &d.motion,
            KeysDef { keys: &d.keys, interpolation: &d.interpolation },
        )?;
        self.check_still_light(span, "triangle", &surface, &place)?;
        let extent = vertices.iter().fold(Vec3::ZERO, |e, v| e.max(v.abs()));
        self.check_reach(span, "triangle", extent, 0.0, &place)?;
        self.count_triangles(span, 1)?;
        self.push(span, Shape::Triangle { vertices }, surface, place);
        Ok(())
    }

    pub(crate) fn mesh(&mut self, span: &Range<usize>, d: &MeshDef) -> R<()> {
        let path = check_asset_path(&d.file).map_err(|e| self.ctx.err(span, format!("mesh.file: {e}")))?;
        let bytes = (self.assets.get(&path))
            .ok_or_else(|| self.ctx.err(span, unreadable(self.assets, "mesh.file", &d.file)))?;
        let (counts, extent) = match self.scans.get(&path) {
            Some(scan) => *scan,
            None => {
                let text = std::str::from_utf8(bytes)
                    .map_err(|_| self.ctx.err(span, format!("mesh.file: {:?} is not text", d.file)))?;
                let scan = scan_obj_extent(text)
                    .map_err(|e| self.ctx.err(span, format!("mesh {:?}: {e}", d.file)))?;
                self.scans.insert(path.clone(), scan);
                scan
            }
        };
        if counts.triangles == 0 {
            // An empty mesh would draw nothing, without a word.
            return Err(self
                .ctx
                .err(span, format!("mesh {:?} has no faces (`f`): it would draw nothing", d.file)));
        }
        let surface = self.surface(span, "mesh", d.material.as_ref(), d.emission)?;
        let place = self.placement(
            span,
            "mesh",
            &d.transform,
            &d.motion,
            KeysDef { keys: &d.keys, interpolation: &d.interpolation },
        )?;
        self.check_still_light(span, "mesh", &surface, &place)?;
        self.check_reach(span, "mesh", extent, 0.0, &place)?;
        self.count_triangles(span, counts.triangles)?;
        self.push(span, Shape::Mesh { file: path, counts }, surface, place);
        Ok(())
    }

    pub(crate) fn count_triangles(&mut self, span: &Range<usize>, n: usize) -> R<()> {
        self.triangles += n;
        if self.triangles > limits::MAX_TRIANGLES {
            return Err(self
                .ctx
                .err(span, format!("the scene has more than {} triangles", limits::MAX_TRIANGLES)));
        }
        Ok(())
    }
}
