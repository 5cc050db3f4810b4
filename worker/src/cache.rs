//! The built scenes a worker keeps between jobs: building a large scene (loading it, its BVH)
//! takes seconds, and the jobs of a farm often render the same scene (another camera, more
//! samples, another seed). A [`Scene`] depends only on the scene's bytes, so it is kept by
//! scene id, in memory, within a budget in bytes ([`Scene::memory_bytes`]); beyond it the
//! least recently used scenes are dropped. The workers of one process (`raytile cluster`)
//! share one cache, and a scene two of them need at once is built once.

use raytile_core::Scene;
use std::collections::HashMap;
use std::future::Future;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use tokio::sync::OnceCell;

/// The default budget: 2 GiB of built scenes.
pub const DEFAULT_BUDGET: usize = 2 << 30;

/// Built scenes by scene id, bounded in memory.
#[derive(Debug)]
pub struct SceneCache {
    budget: usize,
    state: Mutex<State>,
    builds: AtomicU64,
}

#[derive(Debug, Default)]
struct State {
    entries: HashMap<String, Entry>,
    /// Counts uses, to find the least recently used entry.
    clock: u64,
}

#[derive(Debug)]
struct Entry {
    /// The scene once built; waited on by everyone who asks while it is being built.
    cell: Arc<OnceCell<Arc<Scene>>>,
    /// Its size once built (0 while it is being built).
    bytes: usize,
    last_used: u64,
}

impl Default for SceneCache {
    fn default() -> Self {
        Self::new(DEFAULT_BUDGET)
    }
}

impl SceneCache {
    /// A cache keeping at most `budget` bytes of scenes (but always the scene last used, however
    /// large: a worker must hold the scene it renders anyway).
    pub fn new(budget: usize) -> Self {
        SceneCache {
            budget,
            state: Mutex::new(State::default()),
            builds: AtomicU64::new(0),
        }
    }

    /// The budget in bytes.
    pub fn budget(&self) -> usize {
        self.budget
    }

    /// How many scenes this cache has built (successfully) since it was made.
    pub fn builds(&self) -> u64 {
        self.builds.load(Ordering::Relaxed)
    }

    /// Bytes of the scenes held.
    pub fn memory_bytes(&self) -> usize {
        self.lock().entries.values().map(|e| e.bytes).sum()
    }

    /// Number of scenes held or being built.
    pub fn len(&self) -> usize {
        self.lock().entries.len()
    }

    /// Whether no scene is held.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, State> {
        // A panic while holding the lock cannot leave the map inconsistent (every update is one
        // statement), so a poisoned lock is still usable.
        self.state.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// The scene `id`: the cached one, or the one `build` makes (once, however many callers
    /// wait for it). A failed build is not kept: the next caller tries again.
    pub async fn get_or_build<F, Fut>(&self, id: &str, build: F) -> anyhow::Result<Arc<Scene>>
    where
        F: FnOnce() -> Fut,
        Fut: Future<Output = anyhow::Result<Scene>>,
    {
        let cell = {
            let mut st = self.lock();
            st.clock += 1;
            let now = st.clock;
            let e = st.entries.entry(id.to_string()).or_insert_with(|| Entry {
                cell: Arc::new(OnceCell::new()),
                bytes: 0,
                last_used: now,
            });
            e.last_used = now;
            e.cell.clone()
        };
        let built = cell
            .get_or_try_init(|| async {
                let scene = Arc::new(build().await?);
                self.builds.fetch_add(1, Ordering::Relaxed);
                Ok::<_, anyhow::Error>(scene)
            })
            .await;
        let mut st = self.lock();
        let same = |e: &Entry| Arc::ptr_eq(&e.cell, &cell);
        match built {
            Ok(scene) => {
                let scene = scene.clone();
                if let Some(e) = st.entries.get_mut(id).filter(|e| same(e)) {
                    e.bytes = scene.memory_bytes();
                }
                Self::evict(&mut st, id, self.budget);
                Ok(scene)
            }
            Err(err) => {
                if st
                    .entries
                    .get(id)
                    .is_some_and(|e| same(e) && !e.cell.initialized())
                {
                    st.entries.remove(id);
                }
                Err(err)
            }
        }
    }

    /// Drops least recently used built scenes, never `keep`, until the rest fit the budget.
    fn evict(st: &mut State, keep: &str, budget: usize) {
        loop {
            let total: usize = st.entries.values().map(|e| e.bytes).sum();
            if total <= budget {
                return;
            }
            let victim = st
                .entries
                .iter()
                .filter(|(k, e)| k.as_str() != keep && e.cell.initialized())
                .min_by_key(|(_, e)| e.last_used)
                .map(|(k, _)| k.clone());
            match victim {
                Some(k) => {
                    tracing::debug!(scene = %k, "scene dropped from the cache");
                    st.entries.remove(&k);
                }
                None => return,
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use raytile_core::scene::desc::*;

    /// A small scene: `n` spheres.
    fn scene(n: usize) -> Scene {
        let desc = SceneDesc {
            materials: vec![MaterialDesc::new(
                "m",
                BsdfDesc::Diffuse {
                    albedo: glam::Vec3::ONE,
                    texture: None,
                },
            )],
            objects: (0..n)
                .map(|i| ObjectDesc {
                    name: format!("s{i}"),
                    shape: ShapeDesc::Sphere {
                        center: glam::Vec3::new(i as f32, 0.0, 0.0),
                        radius: 0.4,
                    },
                    material: 0,
                    transform: glam::Mat4::IDENTITY,
                    media: None,
                })
                .collect(),
            ..Default::default()
        };
        Scene::build(&desc).unwrap()
    }

    #[tokio::test]
    async fn a_scene_is_built_once_and_the_least_recently_used_goes_first() {
        let size = scene(8).memory_bytes();
        // Room for two scenes of this size, not three.
        let cache = SceneCache::new(size * 5 / 2);
        let get = |id: &'static str| cache.get_or_build(id, || async { Ok(scene(8)) });
        let a = get("a").await.unwrap();
        let a2 = get("a").await.unwrap();
        assert!(Arc::ptr_eq(&a, &a2), "the second use takes the built scene");
        assert_eq!(cache.builds(), 1);
        get("b").await.unwrap();
        get("a").await.unwrap(); // a is now more recent than b
        get("c").await.unwrap(); // over budget: b goes
        assert_eq!((cache.builds(), cache.len()), (3, 2));
        assert!(cache.memory_bytes() <= cache.budget());
        get("a").await.unwrap();
        assert_eq!(cache.builds(), 3, "a was kept");
        get("b").await.unwrap();
        assert_eq!(cache.builds(), 4, "b was dropped and is built again");
    }

    #[tokio::test]
    async fn a_scene_larger_than_the_budget_is_kept_alone_and_failures_are_not_kept() {
        let cache = SceneCache::new(1);
        cache
            .get_or_build("big", || async { Ok(scene(2)) })
            .await
            .unwrap();
        assert_eq!(cache.len(), 1);
        cache
            .get_or_build("other", || async { Ok(scene(2)) })
            .await
            .unwrap();
        assert_eq!(cache.len(), 1, "only the scene in use stays");
        let e = cache
            .get_or_build("bad", || async { Err(anyhow::anyhow!("no such file")) })
            .await
            .unwrap_err();
        assert!(e.to_string().contains("no such file"));
        assert_eq!(cache.builds(), 2);
        let ok = cache.get_or_build("bad", || async { Ok(scene(1)) }).await;
        assert!(ok.is_ok(), "a failed build is tried again");
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn callers_at_the_same_time_share_one_build() {
        let cache = Arc::new(SceneCache::default());
        let tasks: Vec<_> = (0..4)
            .map(|_| {
                let cache = cache.clone();
                tokio::spawn(async move {
                    cache
                        .get_or_build("s", || async {
                            tokio::time::sleep(std::time::Duration::from_millis(50)).await;
                            Ok(scene(3))
                        })
                        .await
                        .unwrap()
                })
            })
            .collect();
        let mut scenes = Vec::new();
        for t in tasks {
            scenes.push(t.await.unwrap());
        }
        assert!(scenes.windows(2).all(|w| Arc::ptr_eq(&w[0], &w[1])));
        assert_eq!(cache.builds(), 1);
    }
}
