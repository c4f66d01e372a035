//! What glTF surfaces add at a hit: the second texture coordinate set, tangents (the
//! `TANGENT` attribute, or derived per triangle from the texture coordinates), normal
//! mapping, single- and double-sided shading, alpha cut-outs.
//!
//! A mesh's extra attributes are indexed like its positions (glTF indexes every attribute
//! with one index). The nearest hit does not keep barycentrics, so shading recovers them
//! from the hit point and the triangle's corners (for a moving mesh, in its own space at
//! the hit's time): exact up to rounding, and paid only by glTF materials.

use std::collections::HashMap;

use glam::{Vec2, Vec3, Vec4};

use super::bsdf::{Bsdf, Frame};
use super::geometry::Ray;
use super::material::{pbr_covers, pbr_emission_scale, pbr_point, Material, Pbr};
use super::sampler::hash_words;
use super::shape::{Mesh, Shape};
use super::{Scene, SurfaceHit, World};

/// Vertex attributes beyond position, normal and `TEXCOORD_0`, per position index.
#[derive(Debug, Clone, Default)]
pub struct Extras {
    /// `TEXCOORD_1` (empty: none).
    pub uv1: Vec<Vec2>,
    /// `TANGENT`: xyz and the bitangent's sign w (empty: derive from the UVs).
    pub tangents: Vec<Vec4>,
}

/// The glTF side of a world.
#[derive(Debug, Default)]
pub struct Surfaces {
    /// Extra attributes of the meshes that have them, by mesh index.
    pub extras: HashMap<u32, Extras>,
    /// Per material: whether its alpha can turn a hit into no hit.
    pub alpha: Vec<bool>,
    /// Whether any material has alpha: otherwise intersection takes its plain path.
    pub any_alpha: bool,
    /// Whether every material stops light entirely (`Material::shadow_transmission` is
    /// zero): a shadow ray is then blocked by the first surface it crosses, whatever that
    /// surface is.
    pub opaque: bool,
}

impl Surfaces {
    /// The surfaces of `materials` with the meshes' `extras`.
    pub fn new(materials: &[Material], extras: HashMap<u32, Extras>) -> Surfaces {
        let alpha: Vec<bool> = materials.iter().map(Material::has_alpha).collect();
        let any_alpha = alpha.iter().any(|&a| a);
        let opaque = materials.iter().all(|m| m.shadow_transmission() == Vec3::ZERO);
        Surfaces { extras, alpha, any_alpha, opaque }
    }
}

/// Barycentrics (b0, b1, b2) of `p` in the triangle `corners` (least squares in its
/// plane).
fn barycentrics(corners: [Vec3; 3], p: Vec3) -> [f32; 3] {
    let (e1, e2, d) = (corners[1] - corners[0], corners[2] - corners[0], p - corners[0]);
    let (d11, d12, d22) = (e1.dot(e1), e1.dot(e2), e2.dot(e2));
    let (d1, d2) = (d.dot(e1), d.dot(e2));
    let det = d11 * d22 - d12 * d12;
    if !(det.abs() > 0.0) {
        return [1.0, 0.0, 0.0];
    }
    let b1 = (d22 * d1 - d12 * d2) / det;
    let b2 = (d11 * d2 - d12 * d1) / det;
    [1.0 - b1 - b2, b1, b2]
}

fn position_indices(mesh: &Mesh, tri: u32) -> [usize; 3] {
    let t = &mesh.tris[tri as usize];
    [t[0][0] as usize, t[1][0] as usize, t[2][0] as usize]
}

/// Both texture coordinate sets of triangle `tri` at barycentrics `b`; `uv0` is the
/// hit's (already `TEXCOORD_0`). A missing `TEXCOORD_1` reads set 0.
fn texcoords(mesh: &Mesh, extras: Option<&Extras>, tri: u32, b: [f32; 3], uv0: Vec2) -> [Vec2; 2] {
    let uv1 = match extras {
        Some(x) if !x.uv1.is_empty() => {
            let i = position_indices(mesh, tri);
            x.uv1[i[0]] * b[0] + x.uv1[i[1]] * b[1] + x.uv1[i[2]] * b[2]
        }
        _ => uv0,
    };
    [uv0, uv1]
}

/// The tangent (unit, in the mesh's space) and the bitangent's sign at barycentrics `b`:
/// the `TANGENT` attribute interpolated, else derived from the triangle's positions and
/// `TEXCOORD_0` (one tangent per triangle; MikkTSpace would average them per vertex).
/// glTF's v runs down the image and its normal maps' green points up, so a derived
/// bitangent is the one along −v.
fn tangent(mesh: &Mesh, extras: Option<&Extras>, tri: u32, b: [f32; 3], n: Vec3) -> Option<(Vec3, f32)> {
    let i = position_indices(mesh, tri);
    if let Some(x) = extras.filter(|x| !x.tangents.is_empty()) {
        let t = x.tangents[i[0]] * b[0] + x.tangents[i[1]] * b[1] + x.tangents[i[2]] * b[2];
        let w = if t.w < 0.0 { -1.0 } else { 1.0 };
        return t.truncate().try_normalize().map(|t| (t, w));
    }
    let c = &mesh.tris[tri as usize];
    if c[0][2] == u32::MAX {
        return None;
    }
    let uv = |k: usize| mesh.uv[c[k][2] as usize];
    let (dp1, dp2) = (mesh.p[i[1]] - mesh.p[i[0]], mesh.p[i[2]] - mesh.p[i[0]]);
    let (du1, du2) = (uv(1) - uv(0), uv(2) - uv(0));
    let det = du1.x * du2.y - du2.x * du1.y;
    if !(det.abs() > 0.0) {
        return None;
    }
    let t = (dp1 * du2.y - dp2 * du1.y) / det;
    let bv = (dp2 * du1.x - dp1 * du2.x) / det;
    let t = t.try_normalize()?;
    let w = if n.cross(t).dot(bv) > 0.0 { -1.0 } else { 1.0 };
    Some((t, w))
}

/// The world normal of tangent-space normal `nt` in the frame of shading normal `ns`,
/// tangent `t` (made orthogonal to `ns`, Gram–Schmidt) and bitangent `ns × t · sign`.
fn perturb(ns: Vec3, t: Vec3, sign: f32, nt: Vec3) -> Option<Vec3> {
    let t = (t - ns * ns.dot(t)).try_normalize()?;
    let bt = ns.cross(t) * sign;
    (t * nt.x + bt * nt.y + ns * nt.z).try_normalize()
}

/// A deterministic number in [0, 1) for a ray meeting primitive `prim`: the stochastic
/// coverage of `BLEND` without a sample dimension of its own.
fn coverage_threshold(ray: &Ray, prim: u32) -> f32 {
    let bits = |v: Vec3| {
        let [x, y, z] = v.to_array().map(f32::to_bits);
        u64::from(x) | (u64::from(y) << 32) ^ u64::from(z).rotate_left(17)
    };
    let h = hash_words(&[bits(ray.origin), bits(ray.dir), u64::from(prim)]);
    (h >> 40) as f32 / (1u64 << 24) as f32
}

impl World {
    /// Whether the hit of `ray` on primitive `prim` at barycentrics (b1, b2) of its
    /// triangle counts (alpha); only called for primitives whose material has alpha.
    pub(super) fn covers(&self, prim: u32, b1: f32, b2: f32, uv0: Vec2, ray: &Ray) -> bool {
        let p = &self.prims[prim as usize];
        let Material::Pbr(m) = &self.materials[p.material as usize] else { return true };
        let Shape::Triangle { mesh, tri } = p.shape else { return true };
        let mesh_ref = &self.meshes[mesh as usize];
        let uvs = texcoords(mesh_ref, self.surfaces.extras.get(&mesh), tri, [1.0 - b1 - b2, b1, b2], uv0);
        pbr_covers(m, &self.textures, &uvs, coverage_threshold(ray, prim))
    }

    /// [`World::covers`] for an inline triangle's hit, checked against its material first.
    #[inline]
    pub(super) fn covers_slot(&self, prim: u32, b1: f32, b2: f32, ray: &Ray) -> bool {
        let p = &self.prims[prim as usize];
        if !self.surfaces.alpha[p.material as usize] {
            return true;
        }
        let Shape::Triangle { mesh, tri } = p.shape else { return true };
        let m = &self.meshes[mesh as usize];
        let c = &m.tris[tri as usize];
        let uv0 = if c[0][2] != u32::MAX {
            let b0 = 1.0 - b1 - b2;
            m.uv[c[0][2] as usize] * b0 + m.uv[c[1][2] as usize] * b1 + m.uv[c[2][2] as usize] * b2
        } else {
            Vec2::new(b1, b2)
        };
        self.covers(prim, b1, b2, uv0, ray)
    }

    /// [`World::covers`] for a hit found without barycentrics (a generic primitive).
    pub(super) fn covers_hit(&self, prim: u32, p_world: Vec3, uv0: Vec2, ray: &Ray, time: f32) -> bool {
        let Some((b, _)) = self.triangle_point(prim, p_world, time) else { return true };
        self.covers(prim, b[1], b[2], uv0, ray)
    }

    /// The barycentrics of a world point on triangle primitive `prim`, and its mesh and
    /// triangle.
    fn triangle_point(&self, prim: u32, p_world: Vec3, time: f32) -> Option<([f32; 3], (u32, u32))> {
        let p = self.prims.get(prim as usize)?;
        let Shape::Triangle { mesh, tri } = p.shape else { return None };
        let local = match p.motion {
            Some(m) => self.motions[m as usize].frames(time).1.transform_point3(p_world),
            None => p_world,
        };
        Some((barycentrics(self.meshes[mesh as usize].corners(tri), local), (mesh, tri)))
    }

    fn texcoords_at(&self, sh: &SurfaceHit, time: f32) -> [Vec2; 2] {
        match self.triangle_point(sh.hit.prim, sh.hit.p, time) {
            Some((b, (mesh, tri))) => {
                texcoords(&self.meshes[mesh as usize], self.surfaces.extras.get(&mesh), tri, b, sh.hit.uv)
            }
            None => [sh.hit.uv; 2],
        }
    }
}

impl Scene {
    /// The BSDF and shading frame of a glTF material at a hit seen along `-wo`; `None`
    /// for the back of a single-sided opaque surface, which reflects nothing (black: it
    /// still blocks, so that closed meshes stay closed for shadows).
    pub fn pbr_shading(&self, sh: &SurfaceHit, m: &Pbr, wo: Vec3, time: f32) -> Option<(Bsdf, Frame)> {
        let w = &*self.world;
        let uvs = w.texcoords_at(sh, time);
        let point = pbr_point(m, &w.textures, &uvs);
        let transmissive = point.bsdf.transmission > 0.0;
        let back = sh.hit.n.dot(wo) < 0.0;
        if back && !m.double_sided && !transmissive {
            return None;
        }
        let mut ns = sh.hit.ns;
        if let Some(nt) = point.normal {
            if let Some(mapped) = self.mapped_normal(sh, nt, time) {
                // A mapped normal that hides the viewer would shade black: keep the
                // interpolated one there.
                let side = if back && !transmissive { -1.0 } else { 1.0 };
                if transmissive || mapped.dot(wo) * side > 0.0 {
                    ns = mapped;
                }
            }
        }
        // Double-sided: the back shades as the front with the normal reversed; a
        // transmissive surface keeps its sides (inside from outside).
        if back && !transmissive {
            ns = -ns;
        }
        Some((Bsdf::MetallicRoughness(point.bsdf), Frame::new(ns)))
    }

    /// The normal of tangent-space `nt` at a hit, in world space.
    fn mapped_normal(&self, sh: &SurfaceHit, nt: Vec3, time: f32) -> Option<Vec3> {
        let w = &*self.world;
        let (b, (mesh, tri)) = w.triangle_point(sh.hit.prim, sh.hit.p, time)?;
        let mesh_ref = &w.meshes[mesh as usize];
        let ns = sh.hit.ns;
        let (mut t, sign) = tangent(mesh_ref, w.surfaces.extras.get(&mesh), tri, b, ns)?;
        if let Some(m) = w.prims[sh.hit.prim as usize].motion {
            t = w.motions[m as usize].frames(time).0.transform_vector3(t);
        }
        perturb(ns, t, sign, nt)
    }

    /// What the emissive texture multiplies a glTF emitter's radiance by at a hit (1
    /// elsewhere); for the light loop, which knows the radiance of emissive meshes.
    pub fn emission_scale(&self, sh: &SurfaceHit, time: f32) -> Vec3 {
        let w = &*self.world;
        match &w.materials[sh.material as usize] {
            Material::Pbr(m) if m.emissive_texture.is_some() => {
                pbr_emission_scale(m, &w.textures, &w.texcoords_at(sh, time))
            }
            _ => Vec3::ONE,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn barycentrics_recover_the_point() {
        let c = [Vec3::new(1.0, 0.0, 2.0), Vec3::new(3.0, 1.0, 2.0), Vec3::new(0.0, 4.0, 2.5)];
        let want = [0.2f32, 0.3, 0.5];
        let p = c[0] * want[0] + c[1] * want[1] + c[2] * want[2];
        let b = barycentrics(c, p);
        for k in 0..3 {
            assert!((b[k] - want[k]).abs() < 1e-5, "{b:?}");
        }
    }

    /// A quad facing +z with u to the right and v down the image (glTF): the derived
    /// tangent is +x and the bitangent (green, up in the image) +y.
    #[test]
    fn derived_tangent_follows_u_and_green_points_up_the_image() {
        let mesh = Mesh {
            p: vec![Vec3::ZERO, Vec3::X, Vec3::Y],
            n: vec![],
            uv: vec![Vec2::new(0.0, 1.0), Vec2::new(1.0, 1.0), Vec2::new(0.0, 0.0)],
            tris: vec![[[0, u32::MAX, 0], [1, u32::MAX, 1], [2, u32::MAX, 2]]],
        };
        let (t, w) = tangent(&mesh, None, 0, [0.3, 0.3, 0.4], Vec3::Z).unwrap();
        assert!((t - Vec3::X).length() < 1e-6);
        assert!((Vec3::Z.cross(t) * w - Vec3::Y).length() < 1e-6);
        // The TANGENT attribute wins, with its sign.
        let x = Extras { uv1: vec![], tangents: vec![Vec4::new(0.0, 1.0, 0.0, -1.0); 3] };
        assert_eq!(tangent(&mesh, Some(&x), 0, [0.3, 0.3, 0.4], Vec3::Z), Some((Vec3::Y, -1.0)));
        // TEXCOORD_1 interpolates; without it set 1 reads set 0.
        let x = Extras { uv1: vec![Vec2::ZERO, Vec2::X, Vec2::Y], tangents: vec![] };
        let uvs = texcoords(&mesh, Some(&x), 0, [0.5, 0.25, 0.25], Vec2::splat(9.0));
        assert_eq!(uvs, [Vec2::splat(9.0), Vec2::new(0.25, 0.25)]);
        assert_eq!(texcoords(&mesh, None, 0, [0.5, 0.25, 0.25], Vec2::ONE), [Vec2::ONE; 2]);
    }

    #[test]
    fn normal_maps_tilt_along_the_tangent_frame() {
        let ns = Vec3::new(0.0, 0.0, 1.0);
        // A flat map (texel 0.5, 0.5, 1) keeps the normal, whatever the tangent.
        let flat = Vec3::new(0.0, 0.0, 1.0);
        assert!((perturb(ns, Vec3::new(1.0, 0.0, 0.3), 1.0, flat).unwrap() - ns).length() < 1e-6);
        // Red tilts towards the tangent, green towards the bitangent (its sign).
        let red = Vec3::new(1.0, 0.0, 1.0);
        assert!(
            (perturb(ns, Vec3::X, 1.0, red).unwrap() - Vec3::new(1.0, 0.0, 1.0).normalize()).length() < 1e-6
        );
        let green = Vec3::new(0.0, 1.0, 1.0);
        assert!(
            (perturb(ns, Vec3::X, 1.0, green).unwrap() - Vec3::new(0.0, 1.0, 1.0).normalize()).length()
                < 1e-6
        );
        assert!(
            (perturb(ns, Vec3::X, -1.0, green).unwrap() - Vec3::new(0.0, -1.0, 1.0).normalize()).length()
                < 1e-6
        );
        // A tangent along the normal makes no frame.
        assert_eq!(perturb(ns, ns, 1.0, red), None);
    }

    #[test]
    fn coverage_threshold_is_uniform_and_deterministic() {
        let mut sum = 0.0;
        let n = 10_000;
        for k in 0..n {
            let ray = Ray::new(Vec3::new(k as f32, 0.5, 1.0), Vec3::Z);
            let t = coverage_threshold(&ray, 7);
            assert!((0.0..1.0).contains(&t));
            assert_eq!(t, coverage_threshold(&ray, 7));
            sum += t;
        }
        assert!((sum / n as f32 - 0.5).abs() < 0.02);
    }
}
