//! A scene built before any job asks for it (`tessera worker --preload SCENE`).
//!
//! Building a big scene is most of a job's start: on the 1M-triangle terrain a worker
//! spends about 0.9 s reading the OBJ and building the BVH, after the coordinator has spent
//! half a second validating the same scene. A worker told which scene is coming builds it
//! at start, while it connects and while the coordinator validates; when a job of that
//! content hash arrives the build is taken as it is (awaited if still running), once: from
//! then on the scene cache keeps it as any built scene. `tessera render` starts its local
//! worker so. Nothing is trusted for it: the build is the worker's own (the same
//! validation as any scene it receives), and a job gets it only under its own content hash.
//!
//! The worker also names the preloaded scene's hash in its Hello (`held_scenes`), and the
//! coordinator then sends that job's scene by hash alone: the terrain's 36 MB are not
//! encoded, sent, decoded and hashed again just to find the build already here (0.16
//! CPU-s of its start, docs/speed.md, thirteenth part). So the preload keeps the bundle
//! for the worker's life: a later job of that scene, or a rebuild after the cache dropped
//! it, needs the content the coordinator no longer sends.

use std::sync::{Arc, Mutex};
use std::time::Instant;

use tessera_description::Bundle;
use tokio::sync::watch;
use tracing::info;

use super::failure::Failure;
use crate::render::Scene;

/// What the build gave, until a job takes it.
type Built = Arc<Mutex<Option<Result<Arc<Scene>, Failure>>>>;

/// The scene being built (or built) at start, by content hash. Cloning shares the build.
#[derive(Clone)]
pub(super) struct Preload {
    hash: String,
    bundle: Arc<Bundle>,
    /// Becomes true when the build has ended (`built` then holds its result).
    done: watch::Receiver<bool>,
    built: Built,
}

impl Preload {
    /// Starts building `bundle` within `memory` (the worker's limit for one scene), on a
    /// thread of its own: not tokio's blocking pool, whose threads the runtime waits for at
    /// exit, so a worker told to stop (SIGTERM) leaves at once even mid-build. Hashes the
    /// bundle first, here: 20 ms for the terrain's 36 MB.
    pub(super) fn start(bundle: Arc<Bundle>, memory: u64) -> Preload {
        let hash = bundle.hash();
        let (tx, done) = watch::channel(false);
        let built: Built = Arc::default();
        let slot = built.clone();
        let kept = bundle.clone();
        let short = hash.chars().take(12).collect::<String>();
        let spawned = std::thread::Builder::new().name("preload".into()).spawn(move || {
            let started = Instant::now();
            let scene = crate::build::parse_bundle_within(&bundle, memory).map(Arc::new).map_err(Failure::from);
            match &scene {
                Ok(_) => info!(scene = %bundle.name, hash = %short, seconds = started.elapsed().as_secs_f32(), "preloaded"),
                // Info, not a warning: a job of this scene is refused the same way, and says so.
                Err(e) => info!(scene = %bundle.name, "preloading failed: {}", e.message),
            }
            *slot.lock().unwrap_or_else(|e| e.into_inner()) = Some(scene);
            // Nobody may be waiting yet; the flag stays for whoever asks.
            tx.send_replace(true);
        });
        if let Err(e) = spawned {
            // The sender is dropped with the closure: `take` then answers `None` and the
            // job builds its scene as any other.
            info!("no thread to preload the scene on: {e}");
        }
        Preload { hash, bundle: kept, done, built }
    }

    /// The preloaded scene's content hash, which the worker's Hello names.
    pub(super) fn hash(&self) -> &str {
        &self.hash
    }

    /// The preloaded bundle if it is the one hashing to `hash`: what a job sent by hash
    /// alone renders.
    pub(super) fn bundle(&self, hash: &str) -> Option<Arc<Bundle>> {
        (self.hash == hash).then(|| self.bundle.clone())
    }

    /// The preloaded scene if it is the one hashing to `hash`, once built, and only the
    /// first time: the job's scene cache keeps it from then on (and drops it when it drops
    /// the scene), so the preload does not hold a scene for the worker's lifetime. `None`
    /// for any other scene, or once taken.
    pub(super) async fn take(&self, hash: &str) -> Option<Result<Arc<Scene>, Failure>> {
        if self.hash != hash {
            return None;
        }
        let mut done = self.done.clone();
        // An error means the build's thread is gone without finishing (it panicked).
        done.wait_for(|d| *d).await.ok()?;
        let taken = self.built.lock().unwrap_or_else(|e| e.into_inner()).take();
        taken
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bundle(text: &str) -> Arc<Bundle> {
        Arc::new(Bundle { name: "preload.toml".into(), text: text.into(), assets: vec![], refused: vec![] })
    }

    const SCENE: &str = "[render]\nwidth = 8\nheight = 6\nspp = 2\n[camera]\nposition = [0, 0, 3]\nlook_at = [0, 0, 0]\n[materials.m]\ntype = \"lambert\"\nalbedo = 0.5\n[[sphere]]\ncenter = [0, 0, 0]\nradius = 1\nmaterial = \"m\"\n";

    #[tokio::test]
    async fn the_preloaded_scene_is_given_to_its_hash_only() {
        let b = bundle(SCENE);
        let preload = Preload::start(b.clone(), u64::MAX);
        assert!(preload.take("not the hash").await.is_none());
        preload.take(&b.hash()).await.expect("its own hash").expect("builds");
        // Taken once: the scene cache keeps it from then on, the preload no longer does.
        assert!(preload.clone().take(&b.hash()).await.is_none());
    }

    #[tokio::test]
    async fn a_scene_that_cannot_be_built_is_refused_as_it_would_be_when_sent() {
        let b = bundle("[render]\nwidth = 0\n");
        let preload = Preload::start(b.clone(), u64::MAX);
        let sent = crate::build::parse_bundle_within(&b, u64::MAX).map(|_| ()).map_err(Failure::from);
        let preloaded = preload.take(&b.hash()).await.expect("its own hash").map(|_| ());
        assert!(preloaded.is_err());
        assert_eq!(preloaded, sent);
        // Over the worker's memory: refused, and marked so (the farm sends the job elsewhere).
        let small = Preload::start(bundle(SCENE), 1);
        let refused = small.take(&bundle(SCENE).hash()).await.unwrap().unwrap_err();
        assert!(refused.scene_refused, "{refused:?}");
    }
}
