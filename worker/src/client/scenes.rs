//! The scenes of recent jobs, built once per content hash, and a batch checked against its
//! scene; why a batch cannot be rendered here.

use std::collections::{HashMap, VecDeque};
use std::sync::Arc;

use glam::UVec2;
use tessera_proto::convert::{bundle_from_wire, settings_from_wire};
use tessera_proto::v1 as pb;
use tracing::{debug, warn};

use super::failure::Failure;
use super::preload::Preload;
use crate::render::Scene;

/// Built scenes a worker keeps at once, by content hash; the least recently used goes
/// first. A job still rendering keeps its own scene alive through its `Arc`.
const SCENE_CACHE: usize = 4;
/// Jobs whose scene and settings a worker remembers; older ones are dropped.
const JOB_CACHE: usize = 8;

/// The scenes of recent jobs. The heavy part of a scene (meshes, BVH, textures) is built
/// once per content hash and shared by every job that renders it; a job only adds its
/// settings ([`Overrides`]: spp, size, drawn in rounds), which cost nothing to apply.
pub(super) struct SceneCache {
    /// Built scenes by content hash, at the file's own settings, least recently used
    /// first; or why the scene could not be built (the same content fails the same way).
    built: VecDeque<(String, Result<Arc<Scene>, Failure>)>,
    /// Each recent job's scene hash and its scene with the job's settings applied.
    jobs: HashMap<u64, (String, Result<Arc<Scene>, Failure>)>,
    /// Recent sequences: the job's bundle, its frames and settings, to build each frame.
    sequences: HashMap<u64, Sequence>,
    /// Built frames of sequences by (content hash, frame), the job's settings applied
    /// (frames of one scene share their settings within a job), least recently used first.
    frames: VecDeque<(FrameKey, Result<Arc<Scene>, Failure>)>,
    /// Job ids, oldest first.
    order: VecDeque<u64>,
    /// The memory one scene may take (`WorkerConfig::memory`).
    memory: u64,
    /// The scene built at start (`WorkerConfig::preload`).
    preload: Option<Preload>,
}

/// A built frame's key: (job, scene hash, frame).
type FrameKey = (u64, String, u32);

/// What a worker keeps of a sequence job to build its frames.
struct Sequence {
    bundle: Arc<tessera_description::Bundle>,
    frames: (u32, u32),
    overrides: Overrides,
}

/// What a job's settings change in its scene, applied to each scene built for it.
#[derive(Debug, Clone, Copy)]
struct Overrides {
    spp: Option<u32>,
    size: Option<(u32, u32)>,
    /// A time budget or a noise target: the samples are drawn in rounds.
    progressive: bool,
}

impl Overrides {
    fn of(settings: pb::RenderSettings) -> Overrides {
        Overrides {
            spp: (settings.spp != 0).then_some(settings.spp),
            size: (settings.width != 0 && settings.height != 0).then_some((settings.width, settings.height)),
            // By the coordinator's own reading of the settings.
            progressive: settings_from_wire(settings).is_ok_and(|s| s.in_rounds()),
        }
    }

    fn apply(self, scene: &mut Scene) {
        scene.apply(self.spp, self.size);
        scene.progressive = self.progressive;
    }
}

impl SceneCache {
    pub(super) fn new(memory: u64, preload: Option<Preload>) -> SceneCache {
        SceneCache {
            built: VecDeque::new(),
            jobs: HashMap::new(),
            sequences: HashMap::new(),
            frames: VecDeque::new(),
            order: VecDeque::new(),
            memory,
            preload,
        }
    }

    /// The scene and pixels of a batch: of a sequence, its frame's scene, built here (off
    /// the async threads) the first time a batch of that frame comes.
    pub(super) async fn prepare_frame(&mut self, b: &pb::Batch) -> Result<(Arc<Scene>, Vec<UVec2>), Failure> {
        let Some(seq) = self.sequences.get(&b.job_id) else { return self.prepare(b) };
        // Checked against the job's scene first (hash, refusal).
        self.prepare(b)?;
        let (first, last) = seq.frames;
        if !(first..=last).contains(&b.frame) {
            return Err(Failure::new(format!(
                "batch names frame {}, but job {} has frames {first}-{last}",
                b.frame, b.job_id
            )));
        }
        let key = (b.job_id, b.scene_hash.clone(), b.frame);
        let scene = match self.frames.iter().position(|(k, _)| *k == key) {
            Some(i) => self.frames.remove(i).expect("found").1,
            None => {
                let (bundle, memory, frame) = (seq.bundle.clone(), self.memory, b.frame);
                let overrides = seq.overrides;
                tokio::task::spawn_blocking(move || {
                    crate::build::parse_bundle_frame_within(&bundle, Some(frame), memory)
                        .map_err(Failure::from)
                        .map(|mut scene| {
                            overrides.apply(&mut scene);
                            Arc::new(scene)
                        })
                })
                .await
                .unwrap_or_else(|e| Err(Failure::new(format!("scene building panicked: {e}"))))
            }
        };
        self.frames.push_back((key, scene.clone()));
        while self.frames.len() > SCENE_CACHE {
            self.frames.pop_front();
        }
        Self::pixels(scene?, b).map_err(Failure::new)
    }

    pub(super) async fn load(&mut self, js: pb::JobScene) {
        let job = js.job_id;
        let claimed = js.scene_hash.clone();
        let settings = js.settings.unwrap_or_default();
        let overrides = Overrides::of(settings);
        let frames = settings.frames.map(|f| (f.first, f.last));
        let started = std::time::Instant::now();
        let base = match self.bundle_of(job, &claimed, js.bundle).await {
            Err(e) => Err(e),
            Ok(bundle) => {
                if let Some(frames) = frames {
                    self.sequences.insert(job, Sequence { bundle: bundle.clone(), frames, overrides });
                }
                let memory = self.memory;
                let hashed = started.elapsed();
                // Built for an earlier job, or preloaded: nothing to build.
                let ready = match (self.take_built(&claimed), &self.preload) {
                    (Some(built), _) => Some(built),
                    (None, Some(p)) => p.take(&claimed).await,
                    (None, None) => None,
                };
                let built = match ready {
                    Some(built) => built,
                    None => {
                        let built = tokio::task::spawn_blocking(move || {
                            crate::build::parse_bundle_within(&bundle, memory)
                                .map(Arc::new)
                                .map_err(Failure::from)
                        })
                        .await
                        .unwrap_or_else(|e| Err(Failure::new(format!("scene building panicked: {e}"))));
                        // What a scene's start costs on this worker, for operators (and
                        // docs/speed.md's account of the terrain's first sample).
                        debug!(
                            job,
                            hash_ms = hashed.as_millis() as u64,
                            build_ms = (started.elapsed() - hashed).as_millis() as u64,
                            "scene hashed and built"
                        );
                        built
                    }
                };
                self.put_built(claimed, built.clone());
                built
            }
        };
        let parsed = base.map(|base| {
            let mut scene = Scene::clone(&base);
            overrides.apply(&mut scene);
            Arc::new(scene)
        });
        if let Err(e) = &parsed {
            warn!(job, scene_refused = e.scene_refused, "scene refused: {}", e.message);
        }
        self.jobs.insert(job, (js.scene_hash, parsed));
        self.order.push_back(job);
        while self.order.len() > JOB_CACHE {
            if let Some(old) = self.order.pop_front() {
                self.jobs.remove(&old);
                self.sequences.remove(&old);
            }
        }
    }

    /// The bundle of job `job`'s scene, named `claimed`: the one sent, once it hashes to
    /// that name; or, sent by hash alone (this worker's Hello said it holds the scene), the
    /// preloaded one. A scene sent by a hash this worker does not hold is refused as a
    /// scene (`scene_refused`): the farm gives the job to workers that can take it.
    async fn bundle_of(
        &self,
        job: u64,
        claimed: &str,
        sent: Option<pb::SceneBundle>,
    ) -> Result<Arc<tessera_description::Bundle>, Failure> {
        let Some(sent) = sent else {
            debug!(job, "the job's scene came by its hash alone");
            return self.preload.as_ref().and_then(|p| p.bundle(claimed)).ok_or_else(|| Failure {
                message: format!(
                    "the coordinator sent job {job}'s scene by its hash {claimed} alone, and this worker holds no scene of that hash"
                ),
                scene_refused: true,
            });
        };
        let bundle = Arc::new(bundle_from_wire(sent));
        let name = claimed.to_owned();
        // Hashing a large scene is CPU work: keep it off the async threads.
        tokio::task::spawn_blocking(move || {
            let actual = bundle.hash();
            if actual != name {
                return Err(Failure::new(format!(
                    "scene content hashes to {actual}, but the coordinator named it {name}: refusing a scene that differs from the submitted one"
                )));
            }
            Ok(bundle)
        })
        .await
        .unwrap_or_else(|e| Err(Failure::new(format!("scene loading panicked: {e}"))))
    }

    /// Takes the built scene of `hash` out of the cache, if there.
    fn take_built(&mut self, hash: &str) -> Option<Result<Arc<Scene>, Failure>> {
        let i = self.built.iter().position(|(h, _)| h == hash)?;
        self.built.remove(i).map(|(_, s)| s)
    }

    /// Puts a built scene back as the most recently used, dropping the least recent.
    fn put_built(&mut self, hash: String, scene: Result<Arc<Scene>, Failure>) {
        self.built.push_back((hash, scene));
        while self.built.len() > SCENE_CACHE {
            self.built.pop_front();
        }
    }

    /// The scene and pixels of a batch, checked against each other.
    fn prepare(&self, b: &pb::Batch) -> Result<(Arc<Scene>, Vec<UVec2>), Failure> {
        let (hash, scene) = self
            .jobs
            .get(&b.job_id)
            .ok_or_else(|| Failure::new(format!("no scene received for job {}", b.job_id)))?;
        if *hash != b.scene_hash {
            return Err(Failure::new(format!(
                "batch names scene {}, but job {} has scene {hash}",
                b.scene_hash, b.job_id
            )));
        }
        let scene = scene.clone()?;
        Self::pixels(scene, b).map_err(Failure::new)
    }

    /// The batch's pixels, checked against its scene.
    fn pixels(scene: Arc<Scene>, b: &pb::Batch) -> Result<(Arc<Scene>, Vec<UVec2>), String> {
        if !b.pixels.len().is_multiple_of(2) {
            return Err("pixel list has an odd number of coordinates".into());
        }
        if b.sample_start >= b.sample_end || b.sample_end > tessera_description::limits::MAX_SPP {
            return Err(format!("bad sample range {}..{}", b.sample_start, b.sample_end));
        }
        let pixels: Vec<UVec2> = b.pixels.chunks_exact(2).map(|p| UVec2::new(p[0], p[1])).collect();
        if let Some(p) = pixels.iter().find(|p| p.x >= scene.width || p.y >= scene.height) {
            return Err(format!(
                "pixel {},{} is outside the {}x{} image",
                p.x, p.y, scene.width, scene.height
            ));
        }
        Ok((scene, pixels))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tessera_description::bundle::Bundle;

    const SCENE: &str =
        "[render]\nwidth = 8\nheight = 6\n[camera]\nposition = [0, 0, 5]\nlook_at = [0, 0, 0]\n\
                         [materials.red]\ncolor = 1\n[[sphere]]\nmaterial = \"red\"\n";

    fn job(job_id: u64, text: &str, spp: u32, size: (u32, u32)) -> pb::JobScene {
        let bundle = Bundle { name: "t.toml".into(), text: text.into(), assets: vec![], refused: vec![] };
        pb::JobScene {
            job_id,
            scene_hash: bundle.hash(),
            bundle: Some(pb::SceneBundle { name: bundle.name, text: bundle.text, assets: vec![] }),
            settings: Some(pb::RenderSettings { spp, width: size.0, height: size.1, ..Default::default() }),
        }
    }

    fn scene_of(cache: &SceneCache, job: u64) -> Arc<Scene> {
        cache.jobs[&job].1.clone().unwrap()
    }

    #[tokio::test]
    async fn jobs_of_one_scene_share_its_world_with_their_own_settings() {
        let mut cache = SceneCache::new(u64::MAX, None);
        cache.load(job(1, SCENE, 0, (0, 0))).await;
        cache.load(job(2, SCENE, 5, (40, 30))).await;
        let (a, b) = (scene_of(&cache, 1), scene_of(&cache, 2));
        assert!(Arc::ptr_eq(&a.world, &b.world));
        assert_eq!((a.width, a.height, a.spp), (8, 6, 16));
        assert_eq!((b.width, b.height, b.spp), (40, 30, 5));
        assert_eq!(cache.built.len(), 1);
        // Jobs in rounds draw a pattern whose prefixes are stratified.
        assert!(!a.progressive && !b.progressive);
        for (id, settings) in [
            (3, pb::RenderSettings { time_limit_seconds: 2.0, ..Default::default() }),
            (4, pb::RenderSettings { noise: 0.05, ..Default::default() }),
        ] {
            cache.load(pb::JobScene { settings: Some(settings), ..job(id, SCENE, 0, (0, 0)) }).await;
            assert!(scene_of(&cache, id).progressive, "job {id}");
        }
    }

    #[tokio::test]
    async fn the_cache_keeps_a_few_scenes_and_refuses_a_misnamed_one() {
        let mut cache = SceneCache::new(u64::MAX, None);
        for i in 0..SCENE_CACHE as u64 + 2 {
            cache.load(job(i, &format!("{SCENE}# {i}\n"), 0, (0, 0))).await;
        }
        assert_eq!(cache.built.len(), SCENE_CACHE);
        // The first scene was dropped: loading it again builds a new world.
        let first = scene_of(&cache, 0);
        cache.load(job(100, &format!("{SCENE}# 0\n"), 0, (0, 0))).await;
        assert!(!Arc::ptr_eq(&first.world, &scene_of(&cache, 100).world));
        let mut wrong = job(101, SCENE, 0, (0, 0));
        wrong.scene_hash = "0".repeat(64);
        cache.load(wrong).await;
        assert!(cache.jobs[&101].1.as_ref().unwrap_err().message.contains("refusing a scene that differs"));
    }

    #[tokio::test]
    async fn a_scene_sent_by_hash_alone_is_the_held_one_and_no_other() {
        let held = Bundle { name: "t.toml".into(), text: SCENE.into(), assets: vec![], refused: vec![] };
        let hash = held.hash();
        let mut cache = SceneCache::new(u64::MAX, Some(Preload::start(Arc::new(held), u64::MAX)));
        let by_hash = |job_id: u64, hash: &str| pb::JobScene {
            job_id,
            scene_hash: hash.to_owned(),
            bundle: None,
            settings: Some(pb::RenderSettings { spp: 3, ..Default::default() }),
        };
        cache.load(by_hash(1, &hash)).await;
        assert_eq!(scene_of(&cache, 1).spp, 3);
        // The cache drops the build; a later job sent by hash is built again from the
        // bundle the preload kept.
        for i in 0..SCENE_CACHE as u64 {
            cache.load(job(10 + i, &format!("{SCENE}# {i}\n"), 0, (0, 0))).await;
        }
        assert!(cache.built.iter().all(|(h, _)| *h != hash));
        cache.load(by_hash(2, &hash)).await;
        assert_eq!((scene_of(&cache, 2).width, scene_of(&cache, 2).spp), (8, 3));
        // A hash this worker does not hold: the job's scene is refused, never guessed.
        cache.load(by_hash(3, &"0".repeat(64))).await;
        let e = cache.jobs[&3].1.as_ref().unwrap_err();
        assert!(e.scene_refused && e.message.contains("holds no scene of that hash"), "{e:?}");
        // Nor is a scene without its bundle taken by a worker that preloaded nothing.
        let mut plain = SceneCache::new(u64::MAX, None);
        plain.load(by_hash(4, &hash)).await;
        assert!(plain.jobs[&4].1.as_ref().unwrap_err().scene_refused);
    }

    #[tokio::test]
    async fn a_scene_over_the_worker_s_memory_is_refused_for_every_batch_of_its_job() {
        let mut cache = SceneCache::new(100, None);
        let js = job(7, SCENE, 0, (0, 0));
        let hash = js.scene_hash.clone();
        cache.load(js).await;
        let batch = pb::Batch {
            job_id: 7,
            scene_hash: hash,
            sample_start: 0,
            sample_end: 1,
            pixels: vec![0, 0],
            ..Default::default()
        };
        let e = cache.prepare(&batch).unwrap_err();
        assert!(e.scene_refused);
        assert!(e.message.starts_with("t.toml: the scene needs about "), "{}", e.message);
        assert!(
            e.message.ends_with(
                "bytes to build (0 triangles, 0 textures), more than this worker's 100 (--memory)"
            ),
            "{}",
            e.message
        );
        // A bad batch of a good scene is an ordinary failure.
        let mut roomy = SceneCache::new(u64::MAX, None);
        roomy.load(job(8, SCENE, 0, (0, 0))).await;
        let e = roomy.prepare(&pb::Batch { job_id: 8, scene_hash: "0".repeat(64), ..batch }).unwrap_err();
        assert!(!e.scene_refused && e.message.starts_with("batch names scene"), "{e:?}");
    }
}
