//! The environment light: radiance arriving from infinitely far away, uniform or from an
//! equirectangular image, importance-sampled by the image's luminance.
//!
//! The mapping (in the environment's own frame, before its rotation about +y): a
//! direction d = (x, y, z) has θ = acos(y) from +y and φ = atan2(x, −z), and lies at
//! image coordinates u = ½ + φ / 2π (left to right), v = θ / π (top to bottom). So the
//! top row is straight up, the bottom row straight down, the image's centre is the
//! direction −z (what the default camera, on +z looking at the origin, sees behind the
//! scene), +x is three quarters across and −x one quarter: the image seen from inside,
//! not mirrored. A rotation of α turns the environment by α about +y (right-handed:
//! −z turns towards −x for α > 0).
//!
//! Texels are looked up nearest (no filtering), so that the radiance is exactly the
//! piecewise-constant function the sampling distribution follows: weight = luminance ×
//! sin θ of the texel's row, and the solid-angle density of a direction is
//! p(u, v) / (2π² sin θ).

use std::f32::consts::PI;

use glam::{Vec2, Vec3};
use tessera_description::math;

use super::distribution::Distribution2D;

/// An environment light.
#[derive(Debug, Clone)]
pub struct Environment {
    /// Radiance, uniform or per texel.
    radiance: Radiance,
    /// sin and cos of the rotation about +y.
    rotation: (f32, f32),
}

#[derive(Debug, Clone)]
enum Radiance {
    Uniform(Vec3),
    Map { width: usize, height: usize, texels: Vec<Vec3>, distribution: Distribution2D },
}

/// A sampled direction of the environment.
#[derive(Debug, Clone, Copy)]
pub struct EnvironmentSample {
    /// Unit world direction towards the environment.
    pub wi: Vec3,
    /// Radiance arriving along `-wi`.
    pub radiance: Vec3,
    /// Solid-angle density.
    pub pdf: f32,
}

/// Luminance of linear Rec. 709 RGB.
pub fn luminance(c: Vec3) -> f32 {
    c.dot(Vec3::new(0.2126, 0.7152, 0.0722))
}

impl Environment {
    /// The same radiance from every direction.
    pub fn uniform(radiance: Vec3, rotation: f32) -> Environment {
        Environment { radiance: Radiance::Uniform(radiance), rotation: math::sin_cos(rotation) }
    }

    /// An equirectangular map, row-major from the top row, already scaled by its strength.
    pub fn map(width: usize, height: usize, texels: Vec<Vec3>, rotation: f32) -> Environment {
        assert_eq!(texels.len(), width * height, "a map of width × height texels");
        let mut weights = Vec::with_capacity(texels.len());
        for y in 0..height {
            let sin_theta = math::sin(PI * (y as f32 + 0.5) / height as f32);
            weights.extend(texels[y * width..(y + 1) * width].iter().map(|&t| luminance(t) * sin_theta));
        }
        let distribution = Distribution2D::new(&weights, width, height);
        Environment {
            radiance: Radiance::Map { width, height, texels, distribution },
            rotation: math::sin_cos(rotation),
        }
    }

    /// World direction to the environment's frame (the rotation undone).
    fn to_local(&self, d: Vec3) -> Vec3 {
        let (s, c) = self.rotation;
        Vec3::new(c * d.x - s * d.z, d.y, s * d.x + c * d.z)
    }

    /// The environment's frame to world.
    fn to_world(&self, d: Vec3) -> Vec3 {
        let (s, c) = self.rotation;
        Vec3::new(c * d.x + s * d.z, d.y, -s * d.x + c * d.z)
    }

    /// Radiance arriving from world direction `dir` (unit), i.e. seen by a ray going `dir`.
    pub fn radiance(&self, dir: Vec3) -> Vec3 {
        match &self.radiance {
            Radiance::Uniform(l) => *l,
            Radiance::Map { width, height, texels, .. } => {
                let uv = direction_to_uv(self.to_local(dir));
                let (x, y) = texel(uv, *width, *height);
                texels[y * width + x]
            }
        }
    }

    /// Samples a direction towards the environment with the uniform pair `u`.
    pub fn sample(&self, u: Vec2) -> Option<EnvironmentSample> {
        match &self.radiance {
            Radiance::Uniform(l) => {
                let z = 1.0 - 2.0 * u.x;
                let r = (1.0 - z * z).max(0.0).sqrt();
                let phi = 2.0 * PI * u.y;
                let wi = Vec3::new(r * math::cos(phi), r * math::sin(phi), z);
                Some(EnvironmentSample { wi, radiance: *l, pdf: 1.0 / (4.0 * PI) })
            }
            Radiance::Map { width, height, texels, distribution } => {
                let (uv, pdf_uv) = distribution.sample(u);
                if pdf_uv == 0.0 {
                    return None;
                }
                let (local, sin_theta) = uv_to_direction(uv);
                if sin_theta <= 0.0 {
                    return None;
                }
                let (x, y) = texel(uv, *width, *height);
                let pdf = pdf_uv / (2.0 * PI * PI * sin_theta);
                Some(EnvironmentSample { wi: self.to_world(local), radiance: texels[y * width + x], pdf })
            }
        }
    }

    /// The solid-angle density with which `sample` picks world direction `dir`.
    pub fn pdf(&self, dir: Vec3) -> f32 {
        match &self.radiance {
            Radiance::Uniform(_) => 1.0 / (4.0 * PI),
            Radiance::Map { distribution, .. } => {
                let local = self.to_local(dir);
                let sin_theta = (1.0 - local.y * local.y).max(0.0).sqrt();
                if sin_theta <= 0.0 {
                    return 0.0;
                }
                distribution.pdf(direction_to_uv(local)) / (2.0 * PI * PI * sin_theta)
            }
        }
    }

    /// Radiant power through a disc of radius `radius` facing the environment, averaged
    /// over directions (for choosing lights by power): π r² × the mean of π L over the sphere.
    pub fn power(&self, radius: f32) -> f32 {
        let mean = match &self.radiance {
            Radiance::Uniform(l) => luminance(*l),
            Radiance::Map { distribution: _, width, height, texels } => {
                // The sin θ weights integrate the sphere: mean = Σ L sin θ ΔΩ / 4π.
                let mut sum = 0f64;
                for y in 0..*height {
                    let sin_theta = math::sin(PI * (y as f32 + 0.5) / *height as f32);
                    let row: f64 =
                        texels[y * width..(y + 1) * width].iter().map(|&t| f64::from(luminance(t))).sum();
                    sum += row * f64::from(sin_theta);
                }
                let d_omega = 2.0 * f64::from(PI) * f64::from(PI) / (*width * *height) as f64;
                (sum * d_omega / (4.0 * f64::from(PI))) as f32
            }
        };
        PI * radius * radius * PI * mean
    }
}

/// Image coordinates in [0, 1]² of a unit direction in the environment's frame.
pub fn direction_to_uv(d: Vec3) -> Vec2 {
    let theta = math::acos(d.y.clamp(-1.0, 1.0));
    let phi = math::atan2(d.x, -d.z);
    Vec2::new(0.5 + phi / (2.0 * PI), theta / PI)
}

/// The unit direction in the environment's frame at image coordinates `uv`, with sin θ.
pub fn uv_to_direction(uv: Vec2) -> (Vec3, f32) {
    let theta = uv.y * PI;
    let phi = (uv.x - 0.5) * 2.0 * PI;
    let (sin_t, cos_t) = math::sin_cos(theta);
    let (sin_p, cos_p) = math::sin_cos(phi);
    (Vec3::new(sin_t * sin_p, cos_t, -sin_t * cos_p), sin_t)
}

/// The texel at `uv`, clamped into the image.
fn texel(uv: Vec2, width: usize, height: usize) -> (usize, usize) {
    let x = ((uv.x * width as f32) as usize).min(width - 1);
    let y = ((uv.y * height as f32) as usize).min(height - 1);
    (x, y)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A `w × h` map of radiance 0.01 with one texel of radiance `bright`.
    fn one_bright(w: usize, h: usize, at: (usize, usize), bright: f32, rotation: f32) -> Environment {
        let mut texels = vec![Vec3::splat(0.01); w * h];
        texels[at.1 * w + at.0] = Vec3::splat(bright);
        Environment::map(w, h, texels, rotation)
    }

    /// A uniform pair from a simple low-discrepancy sequence (deterministic).
    fn pair(i: u32, n: u32) -> Vec2 {
        Vec2::new(
            (i as f32 + 0.5) / n as f32,
            ((f64::from(i) + 0.5) * 0.754_877_666_246_692_7).fract() as f32,
        )
    }

    #[test]
    fn the_mapping_puts_the_centre_at_minus_z_and_round_trips() {
        assert!((direction_to_uv(-Vec3::Z) - Vec2::new(0.5, 0.5)).length() < 1e-6);
        assert!((direction_to_uv(Vec3::X) - Vec2::new(0.75, 0.5)).length() < 1e-6);
        assert!((direction_to_uv(-Vec3::X) - Vec2::new(0.25, 0.5)).length() < 1e-6);
        assert!(direction_to_uv(Vec3::Y).y.abs() < 1e-6);
        for i in 0..50 {
            let uv = Vec2::new((i as f32 * 0.37).fract() * 0.98 + 0.01, (i as f32 + 0.5) / 50.0);
            let (d, _) = uv_to_direction(uv);
            assert!((direction_to_uv(d) - uv).length() < 1e-4, "{uv} -> {d}");
        }
        // A rotation of 90° turns −z (the centre) to −x.
        let env = one_bright(8, 4, (4, 2), 1.0, 0.0);
        let turned = Environment::map(8, 4, vec![Vec3::ONE; 32], std::f32::consts::FRAC_PI_2);
        assert!((turned.to_world(-Vec3::Z) + Vec3::X).length() < 1e-6);
        assert!(
            (env.to_local(env.to_world(Vec3::new(0.3, 0.4, -0.2))) - Vec3::new(0.3, 0.4, -0.2)).length()
                < 1e-6
        );
    }

    #[test]
    fn samples_land_in_the_bright_texel_at_the_predicted_fraction() {
        let (w, h) = (16, 8);
        let at = (11, 3);
        for rotation in [0.0, 1.0] {
            let env = one_bright(w, h, at, 1000.0, rotation);
            // The predicted fraction: the texel's weight over all weights.
            let sin = |y: usize| math::sin(PI * (y as f32 + 0.5) / h as f32);
            let total: f32 =
                (0..h).map(|y| sin(y) * 0.01 * w as f32).sum::<f32>() + sin(at.1) * (1000.0 - 0.01);
            let predicted = sin(at.1) * 1000.0 / total;
            let n = 20_000;
            let mut inside = 0;
            for i in 0..n {
                let s = env.sample(pair(i, n)).unwrap();
                let (x, y) = texel(direction_to_uv(env.to_local(s.wi)), w, h);
                if (x, y) == at {
                    inside += 1;
                    assert_eq!(s.radiance, Vec3::splat(1000.0));
                }
                assert!((s.pdf - env.pdf(s.wi)).abs() <= 1e-3 * s.pdf, "{} vs {}", s.pdf, env.pdf(s.wi));
            }
            let got = inside as f32 / n as f32;
            assert!(
                (got - predicted).abs() < 0.01,
                "rotation {rotation}: {got} in the texel, predicted {predicted}"
            );
        }
    }

    #[test]
    fn the_sample_histogram_follows_the_pdf() {
        // A smooth map: the chi-square of a histogram over texels against the pdf.
        let (w, h) = (12, 6);
        let texels: Vec<Vec3> = (0..w * h)
            .map(|i| Vec3::splat(0.2 + math::sin((i % w) as f32 * 0.5).abs() + (i / w) as f32 * 0.3))
            .collect();
        let env = Environment::map(w, h, texels, 0.3);
        let n = 50_000u32;
        let mut hist = vec![0f64; w * h];
        let mut rng = 0x2545_f491_4f6c_dd1du64;
        let mut next = || {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            (rng >> 40) as f32 / (1u64 << 24) as f32
        };
        for _ in 0..n {
            let s = env.sample(Vec2::new(next(), next())).unwrap();
            let (x, y) = texel(direction_to_uv(env.to_local(s.wi)), w, h);
            hist[y * w + x] += 1.0;
        }
        let mut chi2 = 0.0;
        for y in 0..h {
            for x in 0..w {
                let (d, _) =
                    uv_to_direction(Vec2::new((x as f32 + 0.5) / w as f32, (y as f32 + 0.5) / h as f32));
                // The pdf is constant over a texel in (u, v); in solid angle it follows 1/sin θ,
                // so integrate it over the texel exactly: p_uv × Δu Δv.
                let p_uv =
                    env.pdf(env.to_world(d)) * 2.0 * PI * PI * math::sin(PI * (y as f32 + 0.5) / h as f32);
                let expected = f64::from(p_uv) / (w * h) as f64 * f64::from(n);
                let d = hist[y * w + x] - expected;
                chi2 += d * d / expected;
            }
        }
        // 71 degrees of freedom: the 99.9th percentile is about 112.
        assert!(chi2 < 112.0, "chi-square {chi2}");
    }

    #[test]
    fn the_pdf_integrates_to_one_over_the_sphere() {
        let env = one_bright(16, 8, (3, 6), 50.0, 2.0);
        // A fine grid over the sphere in (θ, φ): dΩ = sin θ dθ dφ (the density's 1 / sin θ
        // cancels, leaving a step function the midpoint rule integrates well).
        let (nt, nphi) = (400, 800);
        let mut integral = 0f64;
        for i in 0..nt {
            let theta = PI * (i as f32 + 0.5) / nt as f32;
            let (sin_t, cos_t) = math::sin_cos(theta);
            for j in 0..nphi {
                let phi = 2.0 * PI * (j as f32 + 0.5) / nphi as f32;
                let d = Vec3::new(sin_t * math::cos(phi), cos_t, sin_t * math::sin(phi));
                integral += f64::from(env.pdf(d) * sin_t);
            }
        }
        integral *= 2.0 * f64::from(PI) * f64::from(PI) / f64::from(nt * nphi);
        assert!((integral - 1.0).abs() < 0.01, "{integral}");
        let uniform = Environment::uniform(Vec3::ONE, 0.0);
        assert!((uniform.pdf(Vec3::X) * 4.0 * PI - 1.0).abs() < 1e-6);
    }

    #[test]
    fn the_estimate_of_irradiance_matches_the_integral() {
        // E at a surface facing +y under a map: ∫ L cos θ dΩ, by sampling and by a grid.
        let env = one_bright(16, 8, (5, 2), 200.0, 0.0);
        let n = 40_000;
        let mut estimate = 0.0f64;
        for i in 0..n {
            let s = env.sample(pair(i, n)).unwrap();
            estimate += f64::from(luminance(s.radiance) * s.wi.y.max(0.0) / s.pdf);
        }
        estimate /= f64::from(n);
        let (nz, nphi) = (400, 800);
        let mut exact = 0f64;
        for i in 0..nz {
            let z = (i as f32 + 0.5) / nz as f32;
            let r = (1.0 - z * z).sqrt();
            for j in 0..nphi {
                let phi = 2.0 * PI * (j as f32 + 0.5) / nphi as f32;
                let d = Vec3::new(r * math::cos(phi), z, r * math::sin(phi));
                exact += f64::from(luminance(env.radiance(d)) * z);
            }
        }
        exact *= 2.0 * f64::from(PI) / f64::from(nz * nphi);
        assert!((estimate - exact).abs() < 0.02 * exact, "{estimate} vs {exact}");
    }
}
