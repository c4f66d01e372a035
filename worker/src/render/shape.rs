//! The primitives of a scene: spheres, parallelograms (rectangles, box faces) and mesh
//! triangles, each with a material, optionally an emission (an area light) and optionally
//! a motion over the shutter.

use glam::{Affine3A, Vec2, Vec3};

use super::bvh::Aabb;
use super::geometry::{gamma, Hit, Ray, Sphere};
use super::transform::Motion;

/// A parallelogram `c + s·u + t·v`, s, t in [-1, 1]; its front faces `u × v`.
#[derive(Debug, Clone)]
pub struct Rect {
    /// Centre.
    pub c: Vec3,
    /// Half-edge vectors.
    pub u: Vec3,
    /// Half-edge vectors.
    pub v: Vec3,
    n: Vec3,
    /// Dual basis: s = du · (p - c), t = dv · (p - c).
    du: Vec3,
    dv: Vec3,
}

impl Rect {
    /// The parallelogram with centre `c` and half-edges `u`, `v` (not parallel).
    pub fn new(c: Vec3, u: Vec3, v: Vec3) -> Rect {
        let n = u.cross(v).normalize();
        let du = v.cross(n) / u.dot(v.cross(n));
        let dv = n.cross(u) / v.dot(n.cross(u));
        Rect { c, u, v, n, du, dv }
    }

    /// The front normal.
    pub fn normal(&self) -> Vec3 {
        self.n
    }

    /// Area.
    pub fn area(&self) -> f32 {
        4.0 * self.u.cross(self.v).length()
    }

    /// The point at (s, t) in [-1, 1]².
    pub fn point(&self, s: f32, t: f32) -> Vec3 {
        self.c + self.u * s + self.v * t
    }

    fn bounds(&self) -> Aabb {
        Aabb::from_points([
            self.point(-1.0, -1.0),
            self.point(1.0, -1.0),
            self.point(-1.0, 1.0),
            self.point(1.0, 1.0),
        ])
    }

    /// The hit in (0, t_max).
    pub fn intersect(&self, ray: &Ray, t_max: f32) -> Option<Hit> {
        let (t, s, tt) = self.candidate(ray, t_max)?;
        Some(self.hit_at(t, s, tt))
    }

    /// The distance and surface coordinates (s, t in [-1, 1]) of the hit in (0, t_max):
    /// all a nearest-hit search needs, [`Rect::hit_at`] completing only the nearest.
    #[inline]
    pub fn candidate(&self, ray: &Ray, t_max: f32) -> Option<(f32, f32, f32)> {
        let denom = self.n.dot(ray.dir);
        if denom == 0.0 {
            return None;
        }
        let t = self.n.dot(self.c - ray.origin) / denom;
        if !(t > 0.0 && t < t_max) {
            return None;
        }
        let d = ray.at(t) - self.c;
        let (s, tt) = (self.du.dot(d), self.dv.dot(d));
        if s.abs() > 1.0 || tt.abs() > 1.0 {
            return None;
        }
        Some((t, s, tt))
    }

    /// The hit at distance `t` and surface coordinates (`s`, `tt`) from [`Rect::candidate`].
    pub fn hit_at(&self, t: f32, s: f32, tt: f32) -> Hit {
        // Recompute the point from its surface coordinates: its error is then that of
        // a few products and sums, independent of the ray's length.
        let p = self.point(s, tt);
        let p_error = (self.c.abs() + (self.u * s).abs() + (self.v * tt).abs()) * gamma(5);
        let uv = Vec2::new((s + 1.0) * 0.5, (tt + 1.0) * 0.5);
        Hit { t, p, p_error, n: self.n, ns: self.n, uv, prim: 0 }
    }
}

/// A triangle mesh in world space (or object space, when it moves).
#[derive(Debug, Clone, Default)]
pub struct Mesh {
    /// Positions.
    pub p: Vec<Vec3>,
    /// Normals (may be empty).
    pub n: Vec<Vec3>,
    /// Texture coordinates (may be empty).
    pub uv: Vec<Vec2>,
    /// Per triangle: position, normal and uv index of each corner (`u32::MAX`: none).
    pub tris: Vec<[[u32; 3]; 3]>,
}

impl Mesh {
    /// The corners of triangle `tri`.
    pub fn corners(&self, tri: u32) -> [Vec3; 3] {
        let t = &self.tris[tri as usize];
        [self.p[t[0][0] as usize], self.p[t[1][0] as usize], self.p[t[2][0] as usize]]
    }

    /// The hit of triangle `tri` in (0, t_max) (Möller–Trumbore; degenerate triangles are
    /// never hit).
    pub fn intersect(&self, tri: u32, ray: &Ray, t_max: f32) -> Option<Hit> {
        let [p0, p1, p2] = self.corners(tri);
        let (t, b1, b2) = moller_trumbore(p0, p1 - p0, p2 - p0, ray, t_max)?;
        self.hit_at(tri, t, b1, b2)
    }

    /// The hit of triangle `tri` at ray parameter `t` and barycentrics `b1`, `b2` found by
    /// [`moller_trumbore`]; `None` when its normal is not finite (a degenerate triangle).
    pub fn hit_at(&self, tri: u32, t: f32, b1: f32, b2: f32) -> Option<Hit> {
        let mut hit = plain_hit(self.corners(tri), t, b1, b2)?;
        let (n, b0) = (hit.n, 1.0 - b1 - b2);
        let c = &self.tris[tri as usize];
        let (n, ns) = if c[0][1] != u32::MAX {
            let s =
                self.n[c[0][1] as usize] * b0 + self.n[c[1][1] as usize] * b1 + self.n[c[2][1] as usize] * b2;
            let s = s.try_normalize().unwrap_or(n);
            // The file's normals say where outside is, whatever the winding (pbrt's rule).
            (if s.dot(n) < 0.0 { -n } else { n }, s)
        } else {
            (n, n)
        };
        if c[0][2] != u32::MAX {
            hit.uv = self.uv[c[0][2] as usize] * b0
                + self.uv[c[1][2] as usize] * b1
                + self.uv[c[2][2] as usize] * b2;
        }
        (hit.n, hit.ns) = (n, ns);
        Some(hit)
    }
}

/// The hit of the triangle with corners `p` at ray parameter `t` and barycentrics `b1`,
/// `b2`, as its mesh would complete it without normals or texture coordinates (its
/// geometric normal, uv = (b1, b2)); `None` when its normal is not finite. The one
/// completion: the mesh's and the slots' give the same bits.
#[inline]
pub fn plain_hit([p0, p1, p2]: [Vec3; 3], t: f32, b1: f32, b2: f32) -> Option<Hit> {
    let n = normal(p1 - p0, p2 - p0)?;
    let b0 = 1.0 - b1 - b2;
    let p = p0 * b0 + p1 * b1 + p2 * b2;
    let p_error = ((p0 * b0).abs() + (p1 * b1).abs() + (p2 * b2).abs()) * gamma(7);
    Some(Hit { t, p, p_error, n, ns: n, uv: Vec2::new(b1, b2), prim: 0 })
}

/// The unit normal `e1 × e2` of a triangle with edges `e1`, `e2`, if finite (a triangle
/// whose normal is not is never hit).
#[inline]
pub fn normal(e1: Vec3, e2: Vec3) -> Option<Vec3> {
    let n = e1.cross(e2).normalize();
    n.is_finite().then_some(n)
}

/// The ray parameter and barycentrics (t, b1, b2) where the ray meets the triangle with
/// corner `p0` and edges `e1`, `e2`, for t in (0, t_max) (Möller–Trumbore). The one
/// triangle test: the mesh's and the BVH-ordered copies' give the same bits.
#[inline(always)]
pub fn moller_trumbore(p0: Vec3, e1: Vec3, e2: Vec3, ray: &Ray, t_max: f32) -> Option<(f32, f32, f32)> {
    let pv = ray.dir.cross(e2);
    let det = e1.dot(pv);
    if det == 0.0 || !det.is_finite() {
        return None;
    }
    let inv = 1.0 / det;
    let tv = ray.origin - p0;
    let b1 = tv.dot(pv) * inv;
    if !(0.0..=1.0).contains(&b1) {
        return None;
    }
    let qv = tv.cross(e1);
    let b2 = ray.dir.dot(qv) * inv;
    if b2 < 0.0 || b1 + b2 > 1.0 {
        return None;
    }
    let t = e2.dot(qv) * inv;
    if !(t > 0.0 && t < t_max) {
        return None;
    }
    Some((t, b1, b2))
}

/// A shape.
#[derive(Debug, Clone)]
pub enum Shape {
    /// A sphere.
    Sphere(Sphere),
    /// A parallelogram (boxed: it is four times a triangle's size, and a mesh makes a
    /// million primitives).
    Rect(Box<Rect>),
    /// Triangle `tri` of mesh `mesh`.
    Triangle {
        /// Mesh index.
        mesh: u32,
        /// Triangle index in the mesh.
        tri: u32,
    },
}

/// A shape with what is attached to it.
#[derive(Debug, Clone)]
pub struct Primitive {
    /// The shape, in world space; in object space when `motion` is set.
    pub shape: Shape,
    /// Material index.
    pub material: u32,
    /// Area light index, when the shape emits.
    pub light: Option<u32>,
    /// Motion index, when the shape moves during the shutter.
    pub motion: Option<u32>,
}

impl Primitive {
    fn object_bounds(&self, meshes: &[Mesh]) -> Aabb {
        match &self.shape {
            Shape::Sphere(s) => {
                Aabb { min: s.center - Vec3::splat(s.radius), max: s.center + Vec3::splat(s.radius) }
            }
            Shape::Rect(r) => r.bounds(),
            Shape::Triangle { mesh, tri } => Aabb::from_points(meshes[*mesh as usize].corners(*tri)),
        }
    }

    /// A box holding the shape over the whole shutter.
    pub fn bounds(&self, meshes: &[Mesh], motions: &[Motion]) -> Aabb {
        let b = self.object_bounds(meshes);
        let Some(m) = self.motion else { return b };
        // Any rotation keeps the shape inside its bounding ball.
        motions[m as usize].swept_ball(b.centroid(), (b.max - b.min).length() * 0.5)
    }

    /// The hit in (0, t_max) at shutter fraction `time`.
    pub fn intersect(
        &self,
        ray: &Ray,
        t_max: f32,
        time: f32,
        meshes: &[Mesh],
        motions: &[Motion],
    ) -> Option<Hit> {
        match self.motion {
            None => self.intersect_local(ray, t_max, meshes),
            Some(m) => {
                let (world_from_object, object_from_world) = motions[m as usize].frames(time);
                let local = to_object(ray, &object_from_world);
                let hit = self.intersect_local(&local, t_max, meshes)?;
                Some(to_world(&hit, &world_from_object))
            }
        }
    }

    /// Whether the ray hits the surface in (0, t_max): [`Primitive::intersect`]'s answer,
    /// a still shape's decided by its candidate test without completing the hit.
    pub fn is_hit(&self, ray: &Ray, t_max: f32, time: f32, meshes: &[Mesh], motions: &[Motion]) -> bool {
        match (&self.shape, self.motion) {
            (Shape::Sphere(s), None) => s.candidate(ray, t_max).is_some(),
            (Shape::Rect(r), None) => r.candidate(ray, t_max).is_some(),
            _ => self.intersect(ray, t_max, time, meshes, motions).is_some(),
        }
    }

    /// How many times the ray's segment (0, t_max) crosses the surface: for shadow rays,
    /// which multiply the transmission of every crossing.
    pub fn crossings(&self, ray: &Ray, t_max: f32, time: f32, meshes: &[Mesh], motions: &[Motion]) -> u32 {
        // A still shape's crossings are decided by its distances alone: no hit is made.
        match (&self.shape, self.motion) {
            (Shape::Sphere(s), None) => s.crossings(ray, t_max),
            (Shape::Rect(r), None) => u32::from(r.candidate(ray, t_max).is_some()),
            (Shape::Sphere(_), Some(_)) => {
                let Some(first) = self.intersect(ray, t_max, time, meshes, motions) else { return 0 };
                let beyond = Ray::new(ray.at(first.t), ray.dir);
                1 + u32::from(self.intersect(&beyond, t_max - first.t, time, meshes, motions).is_some())
            }
            _ => u32::from(self.intersect(ray, t_max, time, meshes, motions).is_some()),
        }
    }

    fn intersect_local(&self, ray: &Ray, t_max: f32, meshes: &[Mesh]) -> Option<Hit> {
        match &self.shape {
            Shape::Sphere(s) => s.intersect(ray, t_max),
            Shape::Rect(r) => r.intersect(ray, t_max),
            Shape::Triangle { mesh, tri } => meshes[*mesh as usize].intersect(*tri, ray, t_max),
        }
    }
}

/// The ray in object space with its parameter kept: the object-space direction is not
/// normalised, so that t means the same distance in both spaces.
#[inline]
pub(crate) fn to_object(ray: &Ray, object_from_world: &Affine3A) -> Ray {
    Ray {
        origin: object_from_world.transform_point3(ray.origin),
        dir: object_from_world.transform_vector3(ray.dir),
    }
}

pub(crate) fn to_world(hit: &Hit, m: &Affine3A) -> Hit {
    let normal_matrix = m.matrix3.inverse().transpose();
    let p = m.transform_point3(hit.p);
    let a = m.matrix3;
    // Error of the transformed point: the transformed object-space bound plus the
    // rounding of the transform itself.
    let abs_m = glam::Mat3A::from_cols(a.x_axis.abs(), a.y_axis.abs(), a.z_axis.abs());
    let p_error = Vec3::from(abs_m * glam::Vec3A::from(hit.p_error)) * (1.0 + gamma(3))
        + (Vec3::from(abs_m * glam::Vec3A::from(hit.p.abs())) + Vec3::from(m.translation.abs())) * gamma(3);
    // Normalised as `Vec3`: `Vec3A::normalize` divides by the length on SSE2 but multiplies
    // by its reciprocal on the scalar path, so the bits would depend on the build
    // (docs/determinism.md).
    let n = Vec3::from(normal_matrix * glam::Vec3A::from(hit.n)).normalize();
    let ns = Vec3::from(normal_matrix * glam::Vec3A::from(hit.ns)).normalize();
    Hit { t: hit.t, p, p_error, n, ns, uv: hit.uv, prim: hit.prim }
}
