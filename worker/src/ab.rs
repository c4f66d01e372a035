//! A switch for measuring a change to the renderer against the code it replaces, in one
//! process (`tessera bench rays --ab`, `tessera bench samples --ab`, built with the `ab`
//! feature). On a shared machine two builds run one after the other drift apart by 10 %
//! and more within minutes, which hides the 1–3 % a change to the walk or the sampler
//! makes; the same process timing both sides a few milliseconds at a time, the side that
//! goes first alternating, puts the drift on both alike (docs/speed.md, forty-first part).
//!
//! An experiment reads [`on`] where the two codes part: `if ab::on() { new } else { old }`.
//! Built without the feature, [`on`] is the constant `false`, so the branch and the new
//! code compile away and no release build carries either. With the feature and no
//! experiment wired in, `--ab` times the same code on both sides: the measurement's floor.

#[cfg(feature = "ab")]
static ON: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

/// Whether this build has the switch (the `ab` feature).
pub const BUILT: bool = cfg!(feature = "ab");

/// Whether the side being measured is the change (B) rather than the code it replaces (A).
#[inline(always)]
pub fn on() -> bool {
    #[cfg(feature = "ab")]
    return ON.load(std::sync::atomic::Ordering::Relaxed);
    #[cfg(not(feature = "ab"))]
    false
}

/// Chooses the side the next work runs (`true`: B). Without the feature it changes
/// nothing; `tessera bench … --ab` refuses to run in such a build.
pub fn set(b: bool) {
    #[cfg(feature = "ab")]
    ON.store(b, std::sync::atomic::Ordering::Relaxed);
    #[cfg(not(feature = "ab"))]
    let _ = b;
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_switch_reads_what_was_set_where_it_is_built() {
        set(true);
        assert_eq!(on(), BUILT);
        set(false);
        assert!(!on());
    }
}
