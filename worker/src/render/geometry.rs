//! Rays, surface hits and the shapes of a Whitted scene.

use glam::Vec3;
use tessera_description::math;

/// A ray `origin + t · dir`, `dir` of unit length.
#[derive(Debug, Clone, Copy)]
pub struct Ray {
    /// Origin.
    pub origin: Vec3,
    /// Unit direction.
    pub dir: Vec3,
}

impl Ray {
    /// A ray from `origin` along the unit vector `dir`.
    pub fn new(origin: Vec3, dir: Vec3) -> Self {
        debug_assert!(origin.is_finite() && dir.is_finite());
        Ray { origin, dir }
    }

    /// The point at parameter `t`.
    pub fn at(&self, t: f32) -> Vec3 {
        self.origin + self.dir * t
    }
}

/// Where a ray meets a surface.
#[derive(Debug, Clone, Copy)]
pub struct Hit {
    /// Ray parameter.
    pub t: f32,
    /// The hit point.
    pub p: Vec3,
    /// A conservative bound on the floating-point error of `p`, per axis.
    pub p_error: Vec3,
    /// Geometric normal, unit length, pointing out of the surface (front side).
    pub n: Vec3,
    /// Shading normal (interpolated for meshes), on the same side as `n`.
    pub ns: Vec3,
    /// Surface coordinates for textures.
    pub uv: glam::Vec2,
    /// The primitive hit (set by the scene).
    pub prim: u32,
}

/// γ(n) of floating-point error analysis: the relative error bound of n operations.
#[inline]
pub const fn gamma(n: i32) -> f32 {
    let e = f32::EPSILON * 0.5 * n as f32;
    e / (1.0 - e)
}

/// The origin of a ray leaving the surface at `p` towards `w`: `p` pushed along the normal
/// just past its error bound, to the side `w` points to, so that the new ray cannot hit
/// the surface it leaves (no acne) nor start behind another one (no leaks). The one place
/// where rays are offset; it scales with the scene instead of using a fixed epsilon.
pub fn offset_ray_origin(p: Vec3, p_error: Vec3, n: Vec3, w: Vec3) -> Vec3 {
    let d = n.abs().dot(p_error);
    // Selects, not branches: which side a ray leaves to, and the sign of each component
    // of the offset, follow the normals and are a coin toss to the branch predictor
    // (this function was 5 % of a `spheres` profile with them; without, `spheres` traces
    // about 1 % faster, docs/speed.md, twenty-third part).
    let side = if w.dot(n) < 0.0 { -1.0 } else { 1.0 };
    let offset = n * d * side;
    let po = p + offset;
    // Round away from p, so that the rounding of the addition cannot undo the offset.
    Vec3::new(nudge(po.x, offset.x), nudge(po.y, offset.y), nudge(po.z, offset.z))
}

/// `v` moved to the next float in the direction of `toward`'s sign: [`f32::next_up`]
/// where `toward` is positive, [`f32::next_down`] where it is negative, `v` where it is
/// zero or NaN. The same floats for every `v` but a NaN (whose payload may differ; a NaN
/// origin hits nothing either way), computed on the bits without a branch.
#[inline]
fn nudge(v: f32, toward: f32) -> f32 {
    const SIGN: u32 = 0x8000_0000;
    // Masks and integer arithmetic: written with `if`, LLVM made this three branches a
    // component again.
    let bits = v.to_bits();
    let magnitude = bits & !SIGN;
    let down = u32::from(toward < 0.0).wrapping_neg();
    let moved = u32::from(toward.abs() > 0.0).wrapping_neg();
    let direction = down & SIGN;
    // From ±0 the step starts at the zero of the direction's sign.
    let zero = u32::from(magnitude == 0).wrapping_neg() & moved;
    let base = (direction & zero) | (bits & !zero);
    // The magnitude grows when `base` has the direction's sign (but an infinity stays)
    // and shrinks when it has the other.
    let outwards = 1 - ((base ^ direction) >> 31);
    let infinite = u32::from(magnitude == f32::INFINITY.to_bits());
    let delta = (outwards * (2 - infinite)).wrapping_sub(1) & moved;
    f32::from_bits(base.wrapping_add(delta))
}

/// A sphere.
#[derive(Debug, Clone)]
pub struct Sphere {
    /// Centre.
    pub center: Vec3,
    /// Radius, positive.
    pub radius: f32,
}

impl Sphere {
    /// A sphere of positive `radius` around `center`.
    pub fn new(center: Vec3, radius: f32) -> Self {
        Sphere { center, radius }
    }

    /// Both ray parameters where the ray's line meets the sphere, nearest first. The
    /// direction need not be unit length (moving objects intersect in object space).
    fn roots(&self, ray: &Ray) -> Option<(f32, f32)> {
        // In f64: the quadratic loses the digits that decide a grazing hit, and the
        // discriminant of a small, distant sphere underflows in f32.
        let oc = (ray.origin - self.center).as_dvec3();
        let d = ray.dir.as_dvec3();
        let a = d.length_squared();
        let b = oc.dot(d);
        let r = f64::from(self.radius);
        // b² - a·c in the form that avoids cancellation, by Lagrange's identity
        // a·|oc|² - b² = |oc × d|²: a·r² - |oc × d|². The cross product's terms are
        // products of two f32 values, exact in f64, so each component rounds once; and
        // unlike Ray Tracing Gems' a·(r² - |oc - d·b/a|²) it needs no division, which
        // was the start of the chain of dependent f64 steps the search waits for.
        let disc = a * (r * r) - oc.cross(d).length_squared();
        if disc < 0.0 {
            return None;
        }
        let c = oc.length_squared() - r * r;
        let q = -b - b.signum() * disc.sqrt();
        let (t0, t1) = if q == 0.0 { (0.0, 0.0) } else { (c / q, q / a) };
        let (t0, t1) = if t0 <= t1 { (t0, t1) } else { (t1, t0) };
        Some((t0 as f32, t1 as f32))
    }

    /// The hit at distance `t` (from [`Sphere::candidate`]): the one [`Sphere::intersect`]
    /// makes.
    pub(crate) fn hit_at(&self, ray: &Ray, t: f32) -> Hit {
        let p = ray.at(t);
        // Reproject onto the surface: this bounds the error by the radius, not by t.
        let local = p - self.center;
        // A sphere below the float spacing at its position collapses to its centre;
        // face the ray rather than produce a NaN normal.
        let n = local.try_normalize().unwrap_or(-ray.dir);
        let p = self.center + n * self.radius;
        let p_error = (self.center.abs() + (n * self.radius).abs()) * gamma(6);
        // UVs cost two transcendental functions: computed for the nearest hit only
        // (`sphere_uv`), not for every candidate and shadow ray.
        Hit { t, p, p_error, n, ns: n, uv: glam::Vec2::ZERO, prim: 0 }
    }

    /// The nearest hit in (0, t_max).
    pub fn intersect(&self, ray: &Ray, t_max: f32) -> Option<Hit> {
        self.candidate(ray, t_max).map(|t| self.hit_at(ray, t))
    }

    /// The distance of the nearest hit in (0, t_max): all a nearest-hit search needs,
    /// [`Sphere::hit_at`] making the hit of the nearest only.
    #[inline]
    pub fn candidate(&self, ray: &Ray, t_max: f32) -> Option<f32> {
        let (t0, t1) = self.roots(ray)?;
        let t = if t0 > 0.0 { t0 } else { t1 };
        (t > 0.0 && t < t_max).then_some(t)
    }

    /// How many times the ray crosses the sphere in (0, t_max), up to two, without making
    /// the hits: a shadow ray needs only the count.
    #[inline]
    pub fn crossings(&self, ray: &Ray, t_max: f32) -> u32 {
        self.roots(ray)
            .map_or(0, |(t0, t1)| u32::from(t0 > 0.0 && t0 < t_max) + u32::from(t1 > 0.0 && t1 < t_max))
    }
}

/// The texture coordinates of a point of a sphere with outward normal `n`: longitude
/// and latitude, v = 1 at the top.
pub fn sphere_uv(n: Vec3) -> glam::Vec2 {
    let u = 0.5 + math::atan2(n.z, n.x) * (0.5 / std::f32::consts::PI);
    let v = math::acos(n.y.clamp(-1.0, 1.0)) * std::f32::consts::FRAC_1_PI;
    glam::Vec2::new(u, 1.0 - v)
}

/// An infinite plane.
#[derive(Debug, Clone)]
pub struct Plane {
    n: Vec3,
    /// n · p for every point p of the plane.
    d: f32,
}

impl Plane {
    /// The plane through `point` with normal `normal` (any non-zero length).
    pub fn new(point: Vec3, normal: Vec3) -> Self {
        let n = normal.normalize();
        Plane { n, d: n.dot(point) }
    }

    /// The hit in (0, t_max), if the ray meets the plane there.
    pub fn intersect(&self, ray: &Ray, t_max: f32) -> Option<Hit> {
        let denom = self.n.dot(ray.dir);
        if denom == 0.0 {
            return None;
        }
        let t = (self.d - self.n.dot(ray.origin)) / denom;
        if !(t > 0.0 && t < t_max) {
            return None;
        }
        // Project back onto the plane; what error remains lies in the plane, plus the
        // rounding of d and of the projection.
        let p = ray.at(t);
        let p = p - self.n * (self.n.dot(p) - self.d);
        let p_error = (p.abs() + Vec3::splat(self.d.abs())) * gamma(5);
        Some(Hit { t, p, p_error, n: self.n, ns: self.n, uv: glam::Vec2::new(p.x, p.z), prim: 0 })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The branchless nudge steps to the same float as `f32::next_up` / `next_down` for
    /// every non-NaN value: the specials, and bit patterns across the range.
    #[test]
    fn nudge_steps_as_next_up_and_next_down() {
        let mut values = vec![0.0f32, -0.0, 1.0, -1.0, f32::INFINITY, f32::NEG_INFINITY, f32::MAX, f32::MIN];
        values.extend([
            f32::MIN_POSITIVE,
            -f32::MIN_POSITIVE,
            f32::from_bits(1),
            f32::from_bits(0x8000_0001),
        ]);
        let hashed =
            (0..100_000u64).map(|k| f32::from_bits(crate::render::sampler::hash_words(&[k, 11]) as u32));
        values.extend(hashed);
        for v in values.into_iter().filter(|v| !v.is_nan()) {
            let same = |a: f32, b: f32| a.to_bits() == b.to_bits();
            assert!(same(nudge(v, 1e-30), v.next_up()), "{v:e} up");
            assert!(same(nudge(v, -3.0), v.next_down()), "{v:e} down");
            assert!(
                same(nudge(v, 0.0), v) && same(nudge(v, -0.0), v) && same(nudge(v, f32::NAN), v),
                "{v:e}"
            );
        }
    }

    /// The discriminant by Lagrange's identity has the sign of the exact one on lines a
    /// few f32 ulps of the radius from tangent, at scales from 2⁻²⁰ to 2²⁰, and the
    /// roots are those of the Ray Tracing Gems form it replaced, within an ulp where the
    /// line is not grazing. The exact sign comes from integers: every coordinate is an
    /// integer times a power of two, and the radius an f32 of 24 bits.
    #[test]
    fn sphere_discriminant_has_the_exact_sign_near_tangency() {
        use crate::render::sampler::hash_words;
        let int = |k: u64, i: u64, bits: u32| (hash_words(&[k, i]) % (2 << bits)) as i64 - (1 << bits);
        let old_roots = |s: &Sphere, ray: &Ray| {
            let (oc, d) = ((ray.origin - s.center).as_dvec3(), ray.dir.as_dvec3());
            let (a, b, r) = (d.length_squared(), oc.dot(d), f64::from(s.radius));
            let disc = a * (r * r - (oc - d * (b / a)).length_squared());
            let q = -b - b.signum() * disc.max(0.0).sqrt();
            let (t0, t1) = ((oc.length_squared() - r * r) / q, q / a);
            (t0.min(t1) as f32, t0.max(t1) as f32)
        };
        let (mut hits, mut misses) = (0, 0);
        for k in 0..6000u64 {
            let scale = [-20i32, -7, 0, 9, 20][k as usize % 5];
            // 2^scale, exactly (a normal float's exponent field).
            let unit = f32::from_bits(((127 + scale) as u32) << 23);
            let o = [int(k, 0, 20), int(k, 1, 20), int(k, 2, 20)];
            let d = [int(k, 3, 12), int(k, 4, 12), int(k, 5, 12)];
            if d == [0; 3] {
                continue;
            }
            // |oc × d|² and |d|², exact, in units of the grid (the centre is the origin).
            let cross = [o[1] * d[2] - o[2] * d[1], o[2] * d[0] - o[0] * d[2], o[0] * d[1] - o[1] * d[0]];
            let x2: i128 = cross.iter().map(|&c| i128::from(c) * i128::from(c)).sum();
            let a: i128 = d.iter().map(|&c| i128::from(c) * i128::from(c)).sum();
            let tangent = ((x2 as f64) / (a as f64)).sqrt() as f32;
            let v = |c: [i64; 3]| Vec3::from_array(c.map(|c| c as f32)) * unit;
            let ray = Ray::new(v(o), v(d));
            let mut r = tangent;
            for _ in 0..3 {
                r = r.next_down();
            }
            for _ in 0..7 {
                // r = m · 2^e exactly: the sign of a·r² − |oc × d|² in integers.
                let (m, e) =
                    (i128::from(r.to_bits() & 0x7f_ffff | 0x80_0000), (r.to_bits() >> 23) as i32 - 150);
                let exact = if e >= 0 { (a * m * m) << (2 * e) } else { a * m * m }
                    - if e >= 0 { x2 } else { x2 << (-2 * e) };
                let s = Sphere::new(Vec3::ZERO, r * unit);
                let new = s.roots(&ray);
                assert_eq!(new.is_some(), exact >= 0, "case {k}, scale 2^{scale}, r {r}: exact {exact}");
                if new.is_some() {
                    hits += 1;
                } else {
                    misses += 1;
                }
                r = r.next_up();
            }
            // A line well inside: the roots of the form replaced, within an ulp.
            let s = Sphere::new(Vec3::ZERO, 1.5 * tangent.max(1.0) * unit);
            let ulps = |x: f32, y: f32| (x.to_bits() as i64 - y.to_bits() as i64).abs();
            let ((t0, t1), old) = (s.roots(&ray).unwrap(), old_roots(&s, &ray));
            assert!(ulps(t0, old.0) <= 1 && ulps(t1, old.1) <= 1, "case {k}: {:?} {old:?}", (t0, t1));
        }
        assert!(hits > 10_000 && misses > 10_000, "{hits} hits, {misses} misses");
    }

    #[test]
    fn sphere_hit_from_outside_and_inside() {
        let s = Sphere::new(Vec3::ZERO, 1.0);
        let outside = Ray::new(Vec3::new(0.0, 0.0, 5.0), Vec3::NEG_Z);
        let h = s.intersect(&outside, f32::INFINITY).unwrap();
        assert!((h.t - 4.0).abs() < 1e-5 && (h.n - Vec3::Z).length() < 1e-6);
        let inside = Ray::new(Vec3::ZERO, Vec3::X);
        assert!((s.intersect(&inside, f32::INFINITY).unwrap().t - 1.0).abs() < 1e-6);
        assert!(s.intersect(&outside, 3.0).is_none());
    }

    /// No acne: a ray leaving a hit point by the offset origin never re-hits its surface,
    /// at any scale.
    #[test]
    fn offset_origin_escapes_the_surface_at_all_scales() {
        // A sphere of radius 1e-4 cannot be placed 1e5 away in f32 (the spacing there is
        // 8e-3), so that combination is not asked for.
        for (scale, offset) in [(1e-4f32, 0.0f32), (1.0, 0.0), (1e4, 0.0), (1.0, 1e5), (1e4, 1e5)] {
            {
                let c = Vec3::splat(offset);
                let s = Sphere::new(c, scale);
                for i in 0..200 {
                    let a = i as f32 * 0.37;
                    let dir = Vec3::new(math::cos(a), math::sin(a * 1.3), math::sin(a)).normalize();
                    let ray = Ray::new(c + dir * (3.0 * scale), -dir);
                    let Some(h) = s.intersect(&ray, f32::INFINITY) else { continue };
                    let w = (h.n + Vec3::new(0.3, 0.1, -0.2)).normalize();
                    if w.dot(h.n) <= 0.0 {
                        continue;
                    }
                    let o = offset_ray_origin(h.p, h.p_error, h.n, w);
                    assert!(o.is_finite(), "{h:?}");
                    assert!(
                        s.intersect(&Ray::new(o, w), f32::INFINITY).is_none(),
                        "scale {scale} offset {offset}"
                    );
                }
            }
        }
    }

    #[test]
    fn plane_hit_and_parallel_miss() {
        let p = Plane::new(Vec3::ZERO, Vec3::Y);
        let h = p.intersect(&Ray::new(Vec3::new(1.0, 2.0, 0.0), Vec3::NEG_Y), f32::INFINITY).unwrap();
        assert!((h.t - 2.0).abs() < 1e-6 && h.n == Vec3::Y);
        assert!(p.intersect(&Ray::new(Vec3::Y, Vec3::X), f32::INFINITY).is_none());
    }
}
