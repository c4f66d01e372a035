//! Adaptive sampling: when a pixel has reached its noise target. Decided on merged
//! samples only, when a tile's round is merged, so that the decisions (and the image) are
//! the same for any worker count, arrival order or restart.

use tessera_description::Noise;
use tessera_film::{Framebuffer, Quad};

/// Luminance below which a pixel's noise is measured against this floor instead: black
/// pixels would otherwise never reach a relative target. (An absolute target needs none.)
pub const NOISE_FLOOR: f64 = 0.05;
/// The radius of the window over which pixels' error estimates are pooled (5×5).
const NOISE_WINDOW: u32 = 2;

/// Whether pixel `q` has reached the noise target (never without one), having taken at
/// least the target's minimum of samples (`JobSettings::adaptive`: the job's own, or
/// `Noise::default_min_samples`).
///
/// One pixel's estimate (half the difference of its even and odd halves) is a single draw
/// of the error, often far below it by chance; stopping on it would stop noisy pixels
/// early. So the errors of the pixels around it, within its own tile (whose
/// samples are all merged when its round ends, which keeps the decision deterministic), are
/// averaged in square: an estimate with about 25 degrees of freedom instead of one.
pub(crate) fn converged(fb: &Framebuffer, q: Quad, adaptive: Option<(Noise, u32)>) -> bool {
    let Some((target, min)) = adaptive else { return false };
    let count = fb.count(q.x, q.y);
    let floor = match target {
        Noise::Relative(_) => Some(NOISE_FLOOR),
        Noise::Absolute(_) => None,
    };
    if count < min {
        return false;
    }
    let tile = |v: u32, size: u32| {
        let start = v / crate::scheduler::rounds::TILE * crate::scheduler::rounds::TILE;
        (start, (start + crate::scheduler::rounds::TILE).min(size))
    };
    let ((x0, x1), (y0, y1)) = (tile(q.x, fb.width()), tile(q.y, fb.height()));
    let (mut sum, mut n) = (0.0f64, 0u32);
    for y in q.y.saturating_sub(NOISE_WINDOW).max(y0)..(q.y + NOISE_WINDOW + 1).min(y1) {
        for x in q.x.saturating_sub(NOISE_WINDOW).max(x0)..(q.x + NOISE_WINDOW + 1).min(x1) {
            if let Some(e) = fb.noise(x, y, floor) {
                sum += e * e;
                n += 1;
            }
        }
    }
    n > 0 && (sum / f64::from(n)).sqrt() <= f64::from(target.value())
}
