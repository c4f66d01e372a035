//! Fresnel reflectance of dielectric and conductor interfaces, shared by the smooth and rough
//! lobes and the plastic coat.

use glam::Vec3;

/// Exact unpolarised Fresnel reflectance of a dielectric interface; `cos_i` may be
/// negative (coming from inside), `eta` is inside over outside.
pub fn fresnel_dielectric(cos_i: f32, eta: f32) -> f32 {
    let (mut cos_i, mut eta) = (cos_i.clamp(-1.0, 1.0), eta);
    if cos_i < 0.0 {
        eta = 1.0 / eta;
        cos_i = -cos_i;
    }
    let sin2_t = (1.0 - cos_i * cos_i) / (eta * eta);
    if sin2_t >= 1.0 {
        return 1.0;
    }
    let cos_t = (1.0 - sin2_t).max(0.0).sqrt();
    let r_parl = (eta * cos_i - cos_t) / (eta * cos_i + cos_t);
    let r_perp = (cos_i - eta * cos_t) / (cos_i + eta * cos_t);
    (r_parl * r_parl + r_perp * r_perp) * 0.5
}

#[derive(Clone, Copy)]
struct Complex {
    re: f32,
    im: f32,
}

impl Complex {
    fn new(re: f32, im: f32) -> Self {
        Complex { re, im }
    }
    fn add(self, o: Self) -> Self {
        Complex::new(self.re + o.re, self.im + o.im)
    }
    fn sub(self, o: Self) -> Self {
        Complex::new(self.re - o.re, self.im - o.im)
    }
    fn mul(self, o: Self) -> Self {
        Complex::new(self.re * o.re - self.im * o.im, self.re * o.im + self.im * o.re)
    }
    fn div(self, o: Self) -> Self {
        let d = o.re * o.re + o.im * o.im;
        Complex::new((self.re * o.re + self.im * o.im) / d, (self.im * o.re - self.re * o.im) / d)
    }
    fn norm(self) -> f32 {
        self.re * self.re + self.im * self.im
    }
    fn sqrt(self) -> Self {
        let n = self.norm().sqrt();
        if n == 0.0 {
            return Complex::new(0.0, 0.0);
        }
        let t1 = (0.5 * (n + self.re.abs())).sqrt();
        let t2 = 0.5 * self.im / t1;
        if self.re >= 0.0 {
            Complex::new(t1, t2)
        } else {
            Complex::new(t2.abs(), t1.copysign(self.im))
        }
    }
}

/// Exact unpolarised Fresnel reflectance of a conductor with index `eta + i k` (outside
/// index 1), one channel.
fn fresnel_complex(cos_i: f32, eta: f32, k: f32) -> f32 {
    let cos_i = cos_i.clamp(0.0, 1.0);
    let eta = Complex::new(eta, k);
    let sin2_i = Complex::new(1.0 - cos_i * cos_i, 0.0);
    let sin2_t = sin2_i.div(eta.mul(eta));
    let cos_t = Complex::new(1.0, 0.0).sub(sin2_t).sqrt();
    let ci = Complex::new(cos_i, 0.0);
    let r_parl = eta.mul(ci).sub(cos_t).div(eta.mul(ci).add(cos_t));
    let r_perp = ci.sub(eta.mul(cos_t)).div(ci.add(eta.mul(cos_t)));
    (r_parl.norm() + r_perp.norm()) * 0.5
}

/// Fresnel reflectance of a conductor per channel.
pub fn fresnel_conductor(cos_i: f32, eta: Vec3, k: Vec3) -> Vec3 {
    Vec3::new(
        fresnel_complex(cos_i, eta.x, k.x),
        fresnel_complex(cos_i, eta.y, k.y),
        fresnel_complex(cos_i, eta.z, k.z),
    )
}

/// The internal diffuse Fresnel reflectance of a coat of index `eta` (Egan–Hilgeman fit,
/// as Mitsuba's `plastic`).
pub fn fresnel_diffuse_reflectance(eta: f32) -> f32 {
    let e = 1.0 / eta;
    0.0636 / e + e * (-1.4399 * e + 0.7099) + 0.6681
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fresnel_known_values() {
        // Normal incidence on glass: ((1.5 - 1) / (1.5 + 1))² = 0.04.
        assert!((fresnel_dielectric(1.0, 1.5) - 0.04).abs() < 1e-6);
        // Total internal reflection from inside past the critical angle.
        assert_eq!(fresnel_dielectric(-0.2, 1.5), 1.0);
        // Index 1: no reflection at all.
        assert!(fresnel_dielectric(0.3, 1.0) < 1e-6);
        // A conductor with k = 0 is a dielectric.
        assert!((fresnel_complex(0.7, 1.5, 0.0) - fresnel_dielectric(0.7, 1.5)).abs() < 1e-5);
        // Gold at normal incidence: ((n-1)² + k²) / ((n+1)² + k²).
        let (n, k) = (0.143f32, 3.983f32);
        let want = ((n - 1.0) * (n - 1.0) + k * k) / ((n + 1.0) * (n + 1.0) + k * k);
        assert!((fresnel_complex(1.0, n, k) - want).abs() < 1e-5);
        assert!((fresnel_diffuse_reflectance(1.5) - 0.596811).abs() < 1e-4);
    }
}
