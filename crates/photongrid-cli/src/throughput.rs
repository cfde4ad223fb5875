//! `photongrid throughput`: this machine's limits against what a render reaches.
//!
//! For a scene it measures, each on one thread and on all of them:
//! * closest-hit rays per second through the library's BVH ([`Accel`]) for the photon pass's
//!   own rays: the first `rays` rays of the real render's photon pass, recorded in path order
//!   and then traced again under the clock;
//! * shadow (occlusion) rays per second over diffuse random walks from the lights (origins on
//!   the surfaces the light reaches, cosine-distributed directions about the facing normal);
//! * kNN queries per second on the photon index ([`PhotonMap`], the classic estimate's k) at
//!   the walks' surface points, with the normal test the estimate uses;
//! * a real render of the classic pipeline (kNN, photons shown directly, no final gathering,
//!   1 spp) through [`pipeline::render`], whose phase times and ray count give the photon pass's
//!   rays per second, the index build's photons per second and the camera pass's samples per
//!   second.
//!
//! The ratio that matters is the photon pass's rays per second per core over the pure
//! closest-hit rate per core with all threads busy: how close the photon pass is to the BVH's
//! limit for the same rays.

use anyhow::{Context, Result};
use glam::Vec3;
use photongrid::accel::{Accel, ClosestHit, Hit, Origin};
use photongrid::estimate::PhotonMap;
use photongrid::photon::{trace_photons, TraceSettings};
use photongrid::pipeline::{self, RenderRequest};
use photongrid::progress::Progress;
use photongrid::sampling::{cosine_hemisphere, Rng};
use photongrid::scene::light::LightSampler;
use photongrid::scene::Scene;
use photongrid::settings::{DirectLighting, Method, Settings};
use photongrid::spatial::KnnBuffer;
use photongrid::surface::SurfacePoint;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::path::Path;
use std::sync::Mutex;
use std::time::Instant;

/// Stream of the recorded walks' random numbers (apart from the renderer's streams).
const WALK_STREAM: u64 = 0x7468_726f_7567_6870;
/// Diffuse bounces a walk continues with this probability (about the photon pass's mean
/// albedo), at most [`WALK_DEPTH`] segments.
const WALK_CONTINUE: f32 = 0.7;
const WALK_DEPTH: u32 = 8;

/// What to measure.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ThroughputOptions {
    /// Rays recorded and traced in each ray measurement.
    pub rays: usize,
    /// Photon paths of the index measurement and of the real render.
    pub photons: usize,
    /// kNN queries timed.
    pub queries: usize,
    /// Neighbours per query (the classic estimate's k).
    pub k: usize,
    /// Image size of the real render.
    pub width: u32,
    /// Image size of the real render.
    pub height: u32,
    /// Seed of the walks, photons and render.
    pub seed: u64,
}

impl Default for ThroughputOptions {
    fn default() -> Self {
        ThroughputOptions {
            rays: 1_000_000,
            photons: 1_000_000,
            queries: 200_000,
            k: Settings::default().neighbours,
            width: 320,
            height: 240,
            seed: 0,
        }
    }
}

/// A rate measured on one thread and on all of them.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Rate {
    /// Per second on one thread, alone.
    pub one_thread: f64,
    /// Per second per thread with every thread busy.
    pub per_thread_all: f64,
}

/// The phases of a real render, as rates.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct RenderRates {
    /// Photon paths emitted.
    pub paths: usize,
    /// Photons stored (and indexed).
    pub stored: usize,
    /// Closest-hit rays of the photon pass.
    pub photon_rays: usize,
    /// Phase seconds: photon pass, index build, camera pass.
    pub photons_seconds: f64,
    /// See `photons_seconds`.
    pub build_seconds: f64,
    /// See `photons_seconds`.
    pub render_seconds: f64,
    /// Photon-pass rays per second per thread.
    pub photon_rays_per_thread: f64,
    /// Photons indexed per second (all threads).
    pub build_photons_per_second: f64,
    /// Camera samples (pixels × spp, each with one kNN query at most) per second per thread.
    pub samples_per_thread: f64,
    /// Peak resident memory of the process after the render, if known.
    pub peak_bytes: Option<u64>,
}

/// One scene's figures.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct SceneThroughput {
    /// Scene file.
    pub scene: String,
    /// Triangles in the BVH.
    pub triangles: usize,
    /// Worker threads.
    pub threads: usize,
    /// Closest-hit rays per second, for the photon pass's own rays.
    pub closest_hit: Rate,
    /// Shadow rays (occlusion tests over half the walk segments) per second.
    pub shadow: Rate,
    /// kNN queries per second on the photon index.
    pub knn: Rate,
    /// Photons in the measured index.
    pub indexed: usize,
    /// The real render.
    pub render: RenderRates,
    /// Photon-pass rays per second per thread ÷ pure closest-hit rays per second per thread
    /// (all threads busy in both).
    pub photon_pass_ratio: f64,
    /// Seconds of the real render's three phases (photon pass, index build, camera pass).
    pub phases_seconds: f64,
    /// The same with the photon pass at the pure closest-hit rate and nothing else in it
    /// ([`floor_seconds`]).
    pub floor_seconds: f64,
}

/// Seconds of `render`'s phases if its photon pass had traced its rays at `closest_hit`'s rate
/// on `threads` threads and done nothing else (the index build and camera pass as measured):
/// no saving in the photon pass's own work can take the render below it.
pub fn floor_seconds(render: &RenderRates, closest_hit: &Rate, threads: usize) -> f64 {
    let rays_per_second = closest_hit.per_thread_all * threads.max(1) as f64;
    let photons = if rays_per_second > 0.0 {
        render.photon_rays as f64 / rays_per_second
    } else {
        f64::INFINITY
    };
    photons + render.build_seconds + render.render_seconds
}

/// A recorded ray: origin, unit direction, and the distance to what it hit (∞ for a miss).
#[derive(Clone, Copy, Debug)]
struct WalkRay {
    origin: Origin,
    dir: Vec3,
    t: f32,
}

/// The BVH answering the photon tracer and keeping every ray it is asked, in the order asked.
struct RayRecorder<'a> {
    accel: &'a Accel,
    rays: Mutex<Vec<WalkRay>>,
}

impl ClosestHit for RayRecorder<'_> {
    fn closest_hit(&self, origin: Origin, dir: Vec3, tmax: f32) -> Option<Hit> {
        let hit = self.accel.intersect_from(origin, dir, tmax);
        if let Ok(mut rays) = self.rays.lock() {
            rays.push(WalkRay {
                origin,
                dir,
                t: hit.map_or(f32::INFINITY, |h| h.t),
            });
        }
        hit
    }
}

/// The photon pass of the classic pipeline with `paths` paths (the one [`render_rates`]
/// renders, for `opts.photons`).
fn classic_trace(opts: &ThroughputOptions, paths: usize) -> TraceSettings {
    TraceSettings {
        photons: paths,
        max_depth: classic_settings(opts).photon_hits(),
        store_direct: true,
        seed: opts.seed,
        sequences: photongrid::photon::Sequences::starting(opts.seed),
        record_triangles: false,
        caustic_photons: 0,
    }
}

/// Every closest-hit ray of the classic photon pass of `paths` paths, in path order: one
/// thread traces the paths one after the other, as each thread of the real pass does with its
/// chunks. Its first rays are those of the pass [`render_rates`] renders (same seed).
fn record_photon_rays(scene: &Scene, accel: &Accel, opts: &ThroughputOptions, paths: usize) -> Result<Vec<WalkRay>> {
    let trace = classic_trace(opts, paths);
    let recorder = RayRecorder {
        accel,
        rays: Mutex::new(Vec::with_capacity(opts.rays)),
    };
    rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .context("starting a thread to record the photon pass's rays")?
        .install(|| trace_photons(scene, &recorder, &trace, &|_| {}));
    Ok(recorder.rays.into_inner().unwrap_or_else(|e| e.into_inner()))
}

/// A recorded surface point with its facing normal (a kNN query site).
type Site = (Vec3, Vec3);

/// Diffuse random walks from the lights until `n` rays are recorded: rays like the photon
/// pass's without its glass and mirrors, and the surface points the walks reached.
fn record_walks(scene: &Scene, accel: &Accel, n: usize, seed: u64) -> (Vec<WalkRay>, Vec<Site>) {
    let lights = LightSampler::new(&scene.lights);
    let (mut rays, mut sites) = (Vec::with_capacity(n), Vec::new());
    let mut path = 0u64;
    while rays.len() < n && !scene.lights.is_empty() {
        let mut rng = Rng::keyed(seed, WALK_STREAM, path);
        path += 1;
        let (l, _) = lights.sample(rng.uniform());
        let e = scene.lights[l].emit(&mut rng);
        let (mut origin, mut dir) = (e.origin, e.direction);
        for _ in 0..WALK_DEPTH {
            let hit = accel.intersect(origin, dir, f32::INFINITY);
            rays.push(WalkRay {
                origin: origin.into(),
                dir,
                t: hit.map_or(f32::INFINITY, |h| h.t),
            });
            let Some(hit) = hit else { break };
            let sp = SurfacePoint::new(scene, origin, dir, hit);
            sites.push((sp.position, sp.facing_normal));
            if rays.len() >= n || rng.uniform() >= WALK_CONTINUE {
                break;
            }
            dir = cosine_hemisphere(rng.uniform2(), sp.facing_normal);
            origin = sp.offset(dir);
        }
        if path > 64 * n as u64 + 1024 {
            break; // lights that reach nothing
        }
    }
    (rays, sites)
}

/// Items per second of `work` over `items`, on this thread alone and on all threads.
fn rate<T: Sync>(items: &[T], work: impl Fn(&T) -> u32 + Sync) -> Rate {
    if items.is_empty() {
        return Rate::default();
    }
    let t = Instant::now();
    let mut sink = 0u32;
    for it in items {
        sink = sink.wrapping_add(work(it));
    }
    let one = items.len() as f64 / t.elapsed().as_secs_f64().max(1e-9);
    let t = Instant::now();
    let par: u32 = items
        .par_chunks(1024)
        .map(|c| c.iter().fold(0u32, |a, it| a.wrapping_add(work(it))))
        .reduce(|| 0, u32::wrapping_add);
    let all = items.len() as f64 / t.elapsed().as_secs_f64().max(1e-9);
    std::hint::black_box(sink.wrapping_add(par));
    Rate {
        one_thread: one,
        per_thread_all: all / rayon::current_num_threads() as f64,
    }
}

/// The classic pipeline of the paper's workload at the options' size.
pub fn classic_settings(opts: &ThroughputOptions) -> Settings {
    Settings {
        method: Method::Knn,
        direct: DirectLighting::Photons,
        gather: 0,
        caustic_photons: 0,
        spp: 1,
        photons: opts.photons,
        neighbours: opts.k,
        width: Some(opts.width),
        height: Some(opts.height),
        seed: opts.seed,
        ..Settings::default()
    }
}

/// kNN queries per second on an index of the scene's photons (the classic pass's), at `sites`.
fn knn_rate(scene: &Scene, accel: &Accel, sites: &[Site], opts: &ThroughputOptions) -> (Rate, usize) {
    let settings = classic_settings(opts);
    let (photons, _, _) = trace_photons(scene, accel, &classic_trace(opts, opts.photons), &|_| {});
    let max_radius = settings.max_radius * scene.bounds.diagonal();
    let map = PhotonMap::build(photons, opts.k, scene.surface_area(), max_radius);
    let sites = &sites[..sites.len().min(opts.queries)];
    let rate = rate(sites, |&(p, n)| {
        thread_local!(static BUF: std::cell::RefCell<KnnBuffer> = Default::default());
        BUF.with(|b| map.knn(p, n, opts.k, &mut b.borrow_mut()).count as u32)
    });
    (rate, map.len())
}

/// A real render of the classic pipeline, its phases as rates.
fn render_rates(scene: &Scene, opts: &ThroughputOptions) -> Result<RenderRates> {
    let settings = classic_settings(opts);
    let camera = scene.cameras.first().context("the scene has no camera")?;
    let request = RenderRequest {
        scene,
        cameras: &[camera],
        settings: &settings,
        start: Instant::now(),
    };
    let r = pipeline::render(&request, &Progress::quiet(), None)?.report;
    let threads = r.threads.max(1) as f64;
    let per_s = |n: f64, s: f64| if s > 0.0 { n / s } else { 0.0 };
    let samples: f64 = r.cameras.iter().map(|c| c.width as f64 * c.height as f64).sum::<f64>() * settings.spp as f64;
    Ok(RenderRates {
        paths: r.photons.emitted,
        stored: r.photons.stored,
        photon_rays: r.photons.rays,
        photons_seconds: r.seconds.photons,
        build_seconds: r.seconds.build,
        render_seconds: r.seconds.render,
        photon_rays_per_thread: per_s(r.photons.rays as f64, r.seconds.photons) / threads,
        build_photons_per_second: per_s(r.photons.stored as f64, r.seconds.build),
        samples_per_thread: per_s(samples, r.seconds.render) / threads,
        peak_bytes: r.memory.peak_bytes,
    })
}

/// Measure one scene.
pub fn measure(path: &Path, opts: &ThroughputOptions) -> Result<SceneThroughput> {
    let scene = photongrid::load(path).with_context(|| format!("loading {}", path.display()))?;
    let accel = Accel::for_scene(&scene);
    let (rays, sites) = record_walks(&scene, &accel, opts.rays, opts.seed);
    // Every path traces at least one ray: `rays` paths give at least `rays` rays.
    let mut photon_rays = record_photon_rays(&scene, &accel, opts, opts.rays)?;
    photon_rays.truncate(opts.rays);
    let closest_hit = rate(&photon_rays, |r| {
        accel
            .intersect_from(r.origin, r.dir, f32::INFINITY)
            .map_or(0, |h| h.triangle)
    });
    // Shadow rays over the first half of each segment: they traverse like a visible light
    // sample's (nothing blocks them), the camera pass's common case.
    let segments: Vec<&WalkRay> = rays.iter().filter(|r| r.t.is_finite()).collect();
    let shadow = rate(&segments, |r| accel.occluded(r.origin.point, r.dir, 0.5 * r.t) as u32);
    let (knn, indexed) = knn_rate(&scene, &accel, &sites, opts);
    let render = render_rates(&scene, opts)?;
    let photon_pass_ratio = if closest_hit.per_thread_all > 0.0 {
        render.photon_rays_per_thread / closest_hit.per_thread_all
    } else {
        0.0
    };
    let threads = rayon::current_num_threads();
    Ok(SceneThroughput {
        scene: path.display().to_string(),
        triangles: scene.triangles.len(),
        threads,
        closest_hit,
        shadow,
        knn,
        indexed,
        phases_seconds: render.photons_seconds + render.build_seconds + render.render_seconds,
        floor_seconds: floor_seconds(&render, &closest_hit, threads),
        render,
        photon_pass_ratio,
    })
}

/// `12345678.9` → `12.35 M`, `4321.0` → `0.0043 M`.
fn mega(v: f64) -> String {
    if v >= 1e5 {
        format!("{:.2} M", v / 1e6)
    } else {
        format!("{:.2e} M", v / 1e6)
    }
}

/// A Markdown table of the figures, one row per scene.
pub fn table_md(results: &[SceneThroughput]) -> String {
    let mut s = String::from(
        "| scene | triangles | closest-hit rays/s (1 thread / per thread of all) | shadow rays/s (1 / per thread) \
         | kNN queries/s (1 / per thread) | photon pass rays/s per thread | ratio | index build photons/s \
         | camera samples/s per thread | phases s (floor) |\n|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n",
    );
    for r in results {
        let name = Path::new(&r.scene)
            .file_stem()
            .map_or(r.scene.clone(), |n| n.to_string_lossy().into());
        s += &format!(
            "| {name} | {} | {} / {} | {} / {} | {} / {} | {} | {:.2} | {} | {} | {:.2} ({:.2}) |\n",
            r.triangles,
            mega(r.closest_hit.one_thread),
            mega(r.closest_hit.per_thread_all),
            mega(r.shadow.one_thread),
            mega(r.shadow.per_thread_all),
            mega(r.knn.one_thread),
            mega(r.knn.per_thread_all),
            mega(r.render.photon_rays_per_thread),
            r.photon_pass_ratio,
            mega(r.render.build_photons_per_second),
            mega(r.render.samples_per_thread),
            r.phases_seconds,
            r.floor_seconds,
        );
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_floor_traces_the_photon_rays_at_the_bvh_rate_and_keeps_the_other_phases() {
        let render = RenderRates {
            photon_rays: 12_000_000,
            photons_seconds: 2.0,
            build_seconds: 0.5,
            render_seconds: 0.25,
            ..RenderRates::default()
        };
        let bvh = Rate {
            one_thread: 7e6,
            per_thread_all: 6e6,
        };
        // 12 M rays at 2 × 6 M rays/s: 1 s.
        assert!((floor_seconds(&render, &bvh, 2) - 1.75).abs() < 1e-12);
        assert_eq!(floor_seconds(&render, &Rate::default(), 2), f64::INFINITY);
    }

    #[test]
    fn the_recorded_rays_are_the_photon_pass_rays() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../samples/cornell_glass.glb");
        let scene = photongrid::load(&path).expect("sample loads");
        let accel = Accel::for_scene(&scene);
        let opts = ThroughputOptions {
            seed: 3,
            ..ThroughputOptions::default()
        };
        let paths = 3_000;
        let rays = record_photon_rays(&scene, &accel, &opts, paths).expect("recorded");
        let (photons, _, stats) = trace_photons(&scene, &accel, &classic_trace(&opts, paths), &|_| {});
        assert_eq!(rays.len(), stats.rays);
        // Each stored photon lies where a recorded ray ended: the rays are the pass's own.
        let hits: Vec<Vec3> = rays
            .iter()
            .filter(|r| r.t.is_finite())
            .map(|r| r.origin.point + r.dir * r.t)
            .collect();
        assert!(
            hits.len() >= photons.len() && photons.len() > paths / 2,
            "{} {}",
            hits.len(),
            photons.len()
        );
        let near = |p: Vec3| hits.iter().any(|h| h.distance(p) < 1e-3);
        assert!(photons.iter().step_by(7).all(|p| near(p.pos())));
    }
}
