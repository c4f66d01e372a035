//! glam's SIMD types against its scalar ones, bit for bit, on every operation of them the
//! renderer uses (docs/determinism.md). glam's `Vec3` and `Mat3` have one implementation
//! on every target; `Vec3A`, `Mat3A`, `Affine3A`, `Vec4` and `Mat4` run SSE2 (NEON, WASM)
//! code unless glam's `scalar-math` is on. Both paths are in this one binary, so this
//! runs in every test run; `tests/simd_levels.rs` renders every scene with a second,
//! scalar build. An operation whose SIMD code sums in another order (Quat and Vec4
//! `dot`/`normalize`, `Vec3A::normalize`, ...) is not used by the renderer and kept out by
//! `worker/clippy.toml`.

use glam::{Affine3A, Mat3, Mat3A, Mat4, Quat, Vec3, Vec3A, Vec4};
use tessera_description::math;

/// Reproducible values over many magnitudes and both signs, with zeros among them.
struct Values(u64);

impl Values {
    fn next(&mut self) -> f32 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        let unit = (self.0 >> 40) as f32 / (1u64 << 24) as f32;
        match self.0 % 8 {
            0 => 0.0,
            1 => unit - 0.5,
            2 => (unit - 0.5) * 1e4,
            3 => (unit - 0.5) * 1e-4,
            _ => (unit - 0.5) * 4.0,
        }
    }
    fn vec3(&mut self) -> Vec3 {
        Vec3::new(self.next(), self.next(), self.next())
    }
    fn vec4(&mut self) -> Vec4 {
        Vec4::new(self.next(), self.next(), self.next(), self.next())
    }
    fn unit_quat(&mut self) -> Quat {
        let q = Quat::from_xyzw(self.next(), self.next(), self.next(), self.next() + 0.1);
        math::quat_normalize(q)
    }
}

fn bits3(v: Vec3) -> [u32; 3] {
    v.to_array().map(f32::to_bits)
}

fn bits4(v: Vec4) -> [u32; 4] {
    v.to_array().map(f32::to_bits)
}

fn same3(a: impl Into<Vec3>, b: Vec3, what: &str) {
    let a = a.into();
    assert_eq!(bits3(a), bits3(b), "{what}: SIMD {a} against scalar {b}");
}

const N: usize = 20_000;

// shape.rs, build/shapes.rs: normals, error bounds and points of transformed shapes.
#[test]
fn vec3a_and_mat3a_give_the_scalar_bits() {
    let mut v = Values(0x9e37_79b9_7f4a_7c15);
    for _ in 0..N {
        let (a, b) = (v.vec3(), v.vec3());
        let (sa, sb) = (Vec3A::from(a), Vec3A::from(b));
        assert_eq!(sa.dot(sb).to_bits(), a.dot(b).to_bits(), "dot {a} {b}");
        assert_eq!(sa.length().to_bits(), a.length().to_bits(), "length {a}");
        same3(sa.cross(sb), a.cross(b), "cross");
        same3(sa.abs(), a.abs(), "abs");
        same3(sa * sb + sa / 3.0 - sb, a * b + a / 3.0 - b, "lane-wise arithmetic");
        let m = Mat3::from_cols(v.vec3(), v.vec3(), v.vec3());
        let ma = Mat3A::from(m);
        same3(ma * sa, m * a, "Mat3A * Vec3A");
        let (inv, inv_a) = (m.inverse(), ma.inverse());
        for (c, ca) in [(inv.x_axis, inv_a.x_axis), (inv.y_axis, inv_a.y_axis), (inv.z_axis, inv_a.z_axis)] {
            same3(ca, c, "inverse");
        }
        let (t, ta) = (m.transpose(), ma.transpose());
        same3(ta.x_axis, t.x_axis, "transpose");
        same3(ta.z_axis, t.z_axis, "transpose");
        let abs_a = Mat3A::from_cols(ma.x_axis.abs(), ma.y_axis.abs(), ma.z_axis.abs());
        let abs = Mat3::from_cols(m.x_axis.abs(), m.y_axis.abs(), m.z_axis.abs());
        same3(abs_a * sb, abs * b, "|M| * v");
    }
}

// description/transform.rs and render/transform.rs: world_from_object of objects, also
// at each sample's time under motion; its inverse takes rays into object space.
#[test]
fn affine3a_gives_the_scalar_bits() {
    let mut v = Values(0x2545_f491_4f6c_dd1d);
    for _ in 0..N {
        let (s, q, t) = (v.vec3(), v.unit_quat(), v.vec3());
        let a = Affine3A::from_scale_rotation_translation(s, q, t);
        let r = Mat3::from_quat(q);
        let m = Mat3::from_cols(r.x_axis * s.x, r.y_axis * s.y, r.z_axis * s.z);
        same3(a.matrix3.x_axis, m.x_axis, "from_scale_rotation_translation");
        same3(a.matrix3.y_axis, m.y_axis, "from_scale_rotation_translation");
        same3(a.matrix3.z_axis, m.z_axis, "from_scale_rotation_translation");
        let p = v.vec3();
        same3(a.transform_point3(p), m * p + t, "transform_point3");
        same3(a.transform_vector3(p), m * p, "transform_vector3");
        if m.determinant() != 0.0 {
            let inv = a.inverse();
            let mi = m.inverse();
            same3(inv.matrix3 * Vec3A::from(p), mi * p, "inverse's matrix");
            same3(inv.translation, -(mi * t), "inverse's translation");
        }
        let b = Affine3A::from_scale_rotation_translation(v.vec3(), v.unit_quat(), v.vec3());
        let ab = a * b;
        same3(ab.matrix3.x_axis, m * Vec3::from(b.matrix3.x_axis), "product");
        same3(ab.translation, m * Vec3::from(b.translation) + t, "product's translation");
    }
}

// texture.rs: bilinear lookups of RGBA texels; gltf/nodes.rs: node matrices composed.
#[test]
fn vec4_and_mat4_give_the_scalar_bits() {
    let mut v = Values(0x1234_5678_9abc_def1);
    for _ in 0..N {
        let (a, b, s) = (v.vec4(), v.vec4(), v.next());
        let lerp = |x: f32, y: f32| x * (1.0 - s) + y * s;
        let want = Vec4::new(lerp(a.x, b.x), lerp(a.y, b.y), lerp(a.z, b.z), lerp(a.w, b.w));
        assert_eq!(bits4(a.lerp(b, s)), bits4(want), "lerp {a} {b} {s}");
        assert_eq!(bits4(a.truncate().extend(a.w)), bits4(a));
        let m = Mat4::from_cols(v.vec4(), v.vec4(), v.vec4(), v.vec4());
        let c = v.vec4();
        let col = |k: usize| {
            let (x, y, z, w) = (m.x_axis[k], m.y_axis[k], m.z_axis[k], m.w_axis[k]);
            x * c.x + y * c.y + z * c.z + w * c.w
        };
        assert_eq!(bits4(m * c), bits4(Vec4::new(col(0), col(1), col(2), col(3))), "Mat4 * Vec4");
        let (s3, q, t) = (v.vec3(), v.unit_quat(), v.vec3());
        let srt = Mat4::from_scale_rotation_translation(s3, q, t);
        let a3 = Affine3A::from_scale_rotation_translation(s3, q, t);
        same3(srt.x_axis.truncate(), a3.matrix3.x_axis.into(), "Mat4 from_scale_rotation_translation");
        same3(srt.z_axis.truncate(), a3.matrix3.z_axis.into(), "Mat4 from_scale_rotation_translation");
        same3(srt.w_axis.truncate(), a3.translation.into(), "Mat4 from_scale_rotation_translation");
    }
}
