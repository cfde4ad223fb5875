//! The camera pass: jittered camera rays, specular chains followed, and at diffuse points
//! direct light by shadow rays plus indirect light and caustics from the photon map.

use crate::accel::{Accel, Origin};
use crate::bsdf;
use crate::estimate::bright::{Aim, BrightSample};
use crate::estimate::density::{density_radiance, photon_density};
use crate::estimate::{Estimator, IrradianceCache, Query};
use crate::film::{Aov, Film};
use crate::grid::multiscale::MultiscaleGrids;
use crate::sampling::{self, stream, Rng};
use crate::scene::{Camera, Scene, Surface};
use crate::settings::{DirectLighting, MAX_GATHER};
use crate::spatial::KnnBuffer;
use crate::surface::SurfacePoint;
use crate::Rgb;
use emitter_edges::EmitterEdges;
use gather_lobe::GatherLobe;
use glam::{Vec2, Vec3};
use rayon::prelude::*;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

pub mod budget;
pub mod emitter_edges;
mod gather_lobe;
mod gltf;
pub mod progressive;
pub mod sppm;

/// Settings of the camera pass.
#[derive(Clone, Debug, serde::Serialize)]
pub struct RenderSettings {
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Camera rays per pixel.
    pub spp: u32,
    /// Direct light by shadow rays or photons.
    pub direct: DirectLighting,
    /// Shadow rays per emissive-light evaluation (delta lights always take one).
    pub light_samples: u32,
    /// Longest chain of mirror/glass bounces followed from the camera.
    pub max_specular_depth: u32,
    /// Up to this depth both glass branches are followed; deeper, one is chosen by Fresnel.
    pub split_depth: u32,
    /// Random seed (of this pass: [`crate::sampling::pass_seed`]).
    pub seed: u64,
    /// The render's seed, the same in every pass: it scrambles each pixel's sequence of
    /// sample positions ([`sampling::owen_sobol`]).
    pub sequence_seed: u64,
    /// Index of this pass's first sample in each pixel's sequence (the samples per pixel the
    /// earlier passes took), so that the passes together stay stratified.
    pub first_sample: u32,
    /// Final-gather rays per camera sample (0: none).
    pub gather: u32,
    /// Share of them aimed at bright surfaces ([`crate::estimate::bright`]).
    pub gather_bright: f32,
}

/// Mirror and glass bounces a final-gather ray follows.
const MAX_GATHER_DEPTH: u32 = 4;

/// How far (a share of the distance) an aimed gather ray may end from the point aimed at and
/// still count as reaching it (it lands on the plane's triangles, not on the sampled point).
const AIM_TOLERANCE: f32 = 1e-3;

/// A density per unit area at a point `t` away along `d`, where the surface has normal `n`,
/// as a density per unit solid angle.
fn solid_angle_pdf(pdf_area: f32, t: f32, d: Vec3, n: Vec3) -> f32 {
    let cos = d.dot(n).abs();
    if cos > 0.0 {
        pdf_area * t * t / cos
    } else {
        0.0
    }
}

/// Per-thread state of the camera pass.
struct Tracer<'a> {
    scene: &'a Scene,
    accel: &'a Accel,
    photons: PhotonData<'a>,
    settings: &'a RenderSettings,
    knn: KnnBuffer,
    /// Set for the ray a glTF lobe sampled (`gltf.rs`): weights the emission it finds.
    mis: Option<gltf::MisRay>,
    /// The camera ray's own emission is estimated apart ([`emitter_edges`]): leave it out.
    skip_seen_emission: bool,
    /// How the gathering point in hand chooses among bright planes (kept to reuse its memory).
    aim: Aim,
    /// Where the camera sample in hand draws its gather directions.
    gather_points: GatherPoints,
    /// Where the camera sample in hand picks the points its aimed gather rays go to.
    aimed_points: GatherPoints,
    /// The camera, for the footprint of its pixels.
    camera: &'a Camera,
    /// The pixel footprint's radius at the surface being shaded ([`Query::footprint`]; 0 past
    /// a mirror or glass, where it is not tracked).
    footprint: f32,
    /// [`CameraPass::gathering_points`], and this tracer's count, added to it when dropped
    /// (no shared counter in the shading loop).
    gathering_points: Option<&'a AtomicU64>,
    asked_to_gather: u64,
}

impl Drop for Tracer<'_> {
    fn drop(&mut self) {
        if let Some(n) = self.gathering_points {
            n.fetch_add(self.asked_to_gather, Ordering::Relaxed);
        }
    }
}

/// The final-gather directions of one camera sample. A pixel's first [`TILE_RUN`] samples
/// take their gathers from a sequence its 2^[`TILE_BITS`] × 2^[`TILE_BITS`] tile shares: one
/// Owen-scrambled Sobol sequence in Morton order of the pixels, each pixel a run of those
/// samples' gathers in turn. Each gather is a net, a pixel's run is a net, and so is every
/// aligned square of pixels' runs, so the error of an area's average falls faster than its
/// pixels' (Ahmed and Wonka 2020, screen-space blue noise from Morton-ordered pixels). Later
/// samples continue the pixel's own sequence, so a long render's gathers go on filling each
/// pixel's hemisphere (independent random directions left the smooth indirect light of a
/// concave room grainy). Neither depends on how many passes or samples the render will take,
/// so a render stopped after n passes is the n-pass render.
///
/// Each pixel visits its run in its own shuffled order (the offset within the run XORed with a
/// per-pixel hash, which keeps every aligned power-of-two part of the run a net). A render of
/// fewer samples than the run, or a gather of fewer points than its stride (some rays aimed at
/// bright planes), then leaves out parts that differ from pixel to pixel. Leaving the same part
/// out in every pixel of the tile made a block's mean of a smooth sky 5 to 20 times worse than
/// independent nets; hashed parts leave it 0.75 to 1.3 times theirs (unit test), and whole
/// runs 0.005 times. Every gather of the sample (both glass branches) reads the same points:
/// different integrands, each unbiased.
#[derive(Clone, Copy, Default)]
struct GatherPoints {
    scramble: u64,
    /// The point before this sample's first (its run's, or 0 in the pixel's own sequence),
    /// the run's shuffle (0 outside a run) and where this sample's gather starts in it.
    run_start: u32,
    shuffle: u32,
    offset: u32,
}

/// Pixels per side of a tile sharing one gather sequence, as a power of two.
const TILE_BITS: u32 = 6;

/// Samples per pixel that take their gathers from the tile's sequence: a 15 s budget's two
/// passes take about this many (docs/time_budget.md). With at most [`MAX_GATHER`] points per
/// sample, a tile's 2^12 runs fit the 32-bit point index.
const TILE_RUN: u32 = 8;

impl GatherPoints {
    /// The gather directions of sample `s` of this pass at pixel (x, y).
    fn of(settings: &RenderSettings, x: usize, y: usize, s: u32) -> Self {
        Self::at(settings, (stream::GATHER, settings.gather), x, y, s)
    }

    /// The points of the rays sample `s` aims at bright planes (at most `gather × gather_bright`).
    fn aimed(settings: &RenderSettings, x: usize, y: usize, s: u32) -> Self {
        let most = (settings.gather as f32 * settings.gather_bright).round() as u32;
        Self::at(settings, (stream::AIMED, most), x, y, s)
    }

    /// Sample `s`'s `points` for `purpose` (a [`stream`] key), from the tile's sequence or the
    /// pixel's own. The stride (points per sample) is `points` rounded up to a power of two, so
    /// each sample's points are a (0, m, 2)-net; the scrambles are keyed by it, so passes with
    /// other gather counts do not reuse the same points.
    fn at(settings: &RenderSettings, (purpose, points): (u64, u32), x: usize, y: usize, s: u32) -> Self {
        let stride = points.clamp(1, MAX_GATHER).next_power_of_two();
        let strides = u64::from(stride.trailing_zeros());
        let sample = settings.first_sample.wrapping_add(s);
        let seed = settings.sequence_seed;
        if sample >= TILE_RUN {
            let key = pixel_index(settings, x, y) | strides << 48;
            return GatherPoints {
                scramble: sampling::pixel_scramble(seed, purpose, key),
                run_start: 0,
                shuffle: 0,
                offset: sample.wrapping_mul(stride),
            };
        }
        let mask = (1 << TILE_BITS) - 1;
        let tile = (x >> TILE_BITS) as u64 | ((y >> TILE_BITS) as u64) << 16;
        // Bit 40 keeps tiles' keys apart from pixels' (pixel indices are below 2^28).
        let scramble = sampling::pixel_scramble(seed, purpose, tile | strides << 32 | 1 << 40);
        let pixel = sampling::morton2((x & mask) as u32, (y & mask) as u32);
        let length = TILE_RUN * stride;
        GatherPoints {
            scramble,
            run_start: pixel * length,
            shuffle: sampling::mix64(scramble ^ u64::from(pixel)) as u32 & (length - 1),
            offset: sample * stride,
        }
    }

    /// The `j`-th direction's point in [0,1)² (`j` below the stride).
    fn point(&self, j: u32) -> Vec2 {
        let index = self.run_start.wrapping_add(self.offset.wrapping_add(j) ^ self.shuffle);
        sampling::owen_sobol(index, self.scramble)
    }
}

impl<'a> Tracer<'a> {
    fn of(pass: CameraPass<'a>) -> Self {
        Tracer {
            scene: pass.scene,
            accel: pass.accel,
            photons: pass.photons,
            settings: pass.settings,
            knn: KnnBuffer::default(),
            mis: None,
            skip_seen_emission: false,
            aim: Aim::default(),
            gather_points: GatherPoints::default(),
            aimed_points: GatherPoints::default(),
            camera: pass.camera,
            footprint: 0.0,
            gathering_points: pass.gathering_points,
            asked_to_gather: 0,
        }
    }

    /// Whether to gather at a point whose estimate asked for it (`asked`), counted.
    fn gathers(&mut self, asked: bool) -> bool {
        self.asked_to_gather += u64::from(asked);
        asked && self.settings.gather > 0
    }
}

/// What the camera pass reads from the photon pass: the estimate over the photons shown
/// directly, and precomputed irradiance for final gathering.
#[derive(Clone, Copy)]
pub struct PhotonData<'a> {
    /// The radiance estimate over this pass's photons.
    pub estimator: Estimator<'a>,
    /// Irradiance points (final gathering).
    pub irradiance: Option<&'a IrradianceCache>,
}

/// One camera's pass: what it renders and with which photons.
#[derive(Clone, Copy)]
pub struct CameraPass<'a> {
    /// The scene.
    pub scene: &'a Scene,
    /// Its BVH.
    pub accel: &'a Accel,
    /// This pass's photons.
    pub photons: PhotonData<'a>,
    /// The camera.
    pub camera: &'a Camera,
    /// Resolution, samples, seed.
    pub settings: &'a RenderSettings,
    /// Counts the shading points whose estimate asks for final gathering, whether or not the
    /// pass has gather rays (the time budget's probe: [`crate::pipeline::plan_passes`]).
    pub gathering_points: Option<&'a AtomicU64>,
}

/// Render a camera pass into a film. `progress(rows)` is called as rows finish (each row once
/// per sample per pixel: the samples are rendered as whole-image sweeps). Without emitter
/// edges ([`emitter_edges`]): the progressive [`progressive::Accumulator`] finds and uses them.
pub fn render(pass: CameraPass<'_>, progress: &(dyn Fn(usize) + Sync)) -> Film {
    render_until(pass, progress, Cut::NONE, None)
        .expect("a render without a deadline completes")
        .film
}

/// When a camera pass gives up: at `deadline`, keeping the sweeps (one sample per pixel each)
/// already done, except that the first `required` sweeps always complete; and when it may go
/// on past its samples per pixel (`spare`).
#[derive(Clone, Copy, Debug)]
pub struct Cut {
    /// When to stop starting rows.
    pub deadline: Option<Instant>,
    /// Sweeps that complete whatever the deadline (1 for a budget's first pass: it is the image).
    pub required: u32,
    /// Time before the deadline that no other pass would use: sweeps beyond the pass's samples
    /// per pixel may take it.
    pub spare: Option<Spare>,
}

impl Cut {
    /// No deadline: every sweep completes, and no more are added.
    pub const NONE: Cut = Cut {
        deadline: None,
        required: 0,
        spare: None,
    };

    /// Whether to add one more sweep after `extra` sweeps beyond the pass's samples per pixel,
    /// the last of all taking `sweep`: while the time left to the deadline is less than the
    /// pass has taken so far (too short for another pass of its size) and the sweep should end
    /// by the deadline with [`SPARE_SWEEP_MARGIN`] to spare.
    fn spare_sweep(&self, extra: u32, sweep: Duration) -> bool {
        let (Some(deadline), Some(spare)) = (self.deadline, self.spare) else {
            return false;
        };
        let now = Instant::now();
        let left = deadline.saturating_duration_since(now);
        extra < spare.max
            && left < now.saturating_duration_since(spare.since)
            && sweep.mul_f64(SPARE_SWEEP_MARGIN) <= left
    }
}

/// Sweeps a camera pass adds beyond its samples per pixel at the end of a time budget
/// ([`Cut::spare`]): the last pass's camera takes the time left that no further pass of its
/// size would use, instead of ending early.
#[derive(Clone, Copy, Debug)]
pub struct Spare {
    /// When the pass started (its photons included).
    pub since: Instant,
    /// Most sweeps added.
    pub max: u32,
}

/// A spare sweep starts only if the last sweep's time, times this, is left before the deadline:
/// a sweep still running at the deadline is lost.
pub const SPARE_SWEEP_MARGIN: f64 = 1.1;

/// A camera pass's film and the samples per pixel it holds.
#[derive(Debug)]
pub struct Swept {
    /// Each pixel's mean over `samples` samples.
    pub film: Film,
    /// Sweeps completed (more than the settings' spp only with [`Cut::spare`]).
    pub samples: u32,
}

/// [`render`], cut at `cut.deadline`: a sweep still running then is dropped and the film holds
/// the sweeps before it (`None` if there are none), so a pass that overruns a time budget ends
/// at the deadline having lost at most one sample per pixel of work. At `edges`, the emission
/// the camera rays see is estimated by [`emitter_edges::edge_emission`].
pub fn render_until(
    pass: CameraPass<'_>,
    progress: &(dyn Fn(usize) + Sync),
    cut: Cut,
    edges: Option<&EmitterEdges>,
) -> Option<Swept> {
    let (w, h) = (pass.settings.width, pass.settings.height);
    let mut film = Film::new(w, h);
    let mut sweep = vec![Rgb::ZERO; w as usize * h as usize];
    let spp = pass.settings.spp.max(1);
    let (mut samples, mut took) = (0, Duration::ZERO);
    while samples < spp || cut.spare_sweep(samples - spp, took) {
        let s = samples;
        let deadline = cut.deadline.filter(|_| s >= cut.required);
        let started = Instant::now();
        if !render_sweep(pass, progress, (deadline, edges), s, &mut sweep, &mut film.aov) {
            break;
        }
        took = started.elapsed();
        for (c, v) in film.color.iter_mut().zip(&sweep) {
            *c += *v;
        }
        samples += 1;
    }
    if samples == 0 {
        return None;
    }
    for c in &mut film.color {
        *c /= samples as f32;
    }
    Some(Swept { film, samples })
}

/// Sample `s` of every pixel into `sweep` (and the first-hit AOVs when `s` is 0); false if
/// `deadline` passed before every row was done.
fn render_sweep(
    pass: CameraPass<'_>,
    progress: &(dyn Fn(usize) + Sync),
    (deadline, edges): (Option<Instant>, Option<&EmitterEdges>),
    s: u32,
    sweep: &mut [Rgb],
    aov: &mut [Aov],
) -> bool {
    let (camera, settings) = (pass.camera, pass.settings);
    let w = settings.width as usize;
    let late = AtomicBool::new(false);
    sweep
        .par_chunks_mut(w)
        .zip(aov.par_chunks_mut(w))
        .enumerate()
        .for_each_init(
            || Tracer::of(pass),
            |tracer, (y, (row, aovs))| {
                if late.load(Ordering::Relaxed) || deadline.is_some_and(|d| Instant::now() >= d) {
                    late.store(true, Ordering::Relaxed);
                    return;
                }
                for x in 0..w {
                    let (o, d, mut rng) = camera_ray(camera, settings, x, y, s);
                    tracer.gather_points = GatherPoints::of(settings, x, y, s);
                    tracer.aimed_points = GatherPoints::aimed(settings, x, y, s);
                    let mut first = (s == 0).then_some(&mut aovs[x]);
                    let edge = edges.is_some_and(|e| e.contains(x, y));
                    tracer.skip_seen_emission = edge;
                    row[x] = tracer.radiance(o.into(), d, 0, &mut rng, &mut first);
                    if edge {
                        row[x] += emitter_edges::edge_emission(&pass, x, y, settings.first_sample.wrapping_add(s));
                    }
                    if s == 0 {
                        aovs[x].depth *= d.dot(camera.forward()); // along the axis, see Aov
                    }
                }
                progress(1);
            },
        );
    !late.into_inner()
}

/// The emission leaving `sp` towards the ray that found it (its emissive texture; zero on the
/// back of a one-sided emitter).
pub(crate) fn seen_emission(scene: &Scene, sp: &SurfacePoint) -> Rgb {
    let material = &scene.materials[sp.material as usize];
    if material.is_emissive() && (material.double_sided || !sp.backface) {
        material.emission_at(&scene.textures, sp.uv)
    } else {
        Rgb::ZERO
    }
}

/// The photon-estimate query at a surface point whose pixel footprint has radius `footprint`.
fn query_at(sp: &SurfacePoint, footprint: f32) -> Query {
    Query {
        position: sp.position,
        facing_normal: sp.facing_normal,
        geometric_normal: sp.geometric_normal,
        triangle: sp.triangle,
        footprint,
        glossy: false,
    }
}

/// The key of pixel (x, y) in the per-pixel streams and sequences.
fn pixel_index(settings: &RenderSettings, x: usize, y: usize) -> u64 {
    (y * settings.width as usize + x) as u64
}

/// The ray of sample `s` of this pass at pixel (x, y), and the random stream the rest of its
/// path uses (keyed by pixel and sample: independent of threads).
fn camera_ray(camera: &Camera, settings: &RenderSettings, x: usize, y: usize, s: u32) -> (Vec3, Vec3, Rng) {
    let (w, h) = (settings.width, settings.height);
    let spp = settings.spp.max(1) as u64;
    let pixel = pixel_index(settings, x, y);
    let rng = if u64::from(s) < spp {
        Rng::keyed(settings.seed, stream::CAMERA, pixel * spp + u64::from(s))
    } else {
        // A spare sweep ([`Cut::spare`]): `pixel * spp + s` is the next pixel's sample.
        Rng::keyed(settings.seed, stream::SPARE_CAMERA, pixel << 32 | (u64::from(s) - spp))
    };
    let scramble = sampling::pixel_scramble(settings.sequence_seed, stream::PIXEL, pixel);
    let index = settings.first_sample.wrapping_add(s);
    let film_pos = Vec2::new(x as f32, y as f32) + sampling::owen_sobol(index, scramble);
    let (o, d) = camera.generate_ray(film_pos, w, h);
    (o, d, rng)
}

impl Tracer<'_> {
    fn radiance(&mut self, o: Origin, d: Vec3, depth: u32, rng: &mut Rng, aov: &mut Option<&mut Aov>) -> Rgb {
        let mis = self.mis.take();
        let Some(hit) = self.accel.intersect_from(o, d, f32::INFINITY) else {
            return Rgb::ZERO; // black world, as the reference scenes
        };
        let sp = SurfacePoint::new(self.scene, o.point, d, hit);
        let material = &self.scene.materials[sp.material as usize];
        if depth == 0 {
            first_hit_aov(aov, &sp, hit.t);
        }
        self.footprint = if depth == 0 {
            self.camera.pixel_footprint(hit.t, self.settings.height)
        } else {
            0.0
        };
        let mut l = Rgb::ZERO;
        if !(depth == 0 && self.skip_seen_emission) {
            l += seen_emission(self.scene, &sp) * self.emission_weight(mis, &sp, &hit, d);
        }
        if let Surface::Lambert { .. } = material.surface {
            return l + self.diffuse(&sp, rng, aov);
        }
        if let Surface::Gltf(m) = &material.surface {
            return l + self.gltf(m, &sp, (d, hit.t, depth), rng, aov);
        }
        if depth >= self.settings.max_specular_depth {
            return l;
        }
        let next = |tr: &mut Self, s: bsdf::Scatter, rng: &mut Rng, aov: &mut Option<&mut Aov>| {
            s.weight * tr.radiance(sp.leave(s.direction), s.direction, depth + 1, rng, aov)
        };
        if depth < self.settings.split_depth {
            // Near the camera both glass branches are followed: less noise where it shows most.
            if let Some((r, t)) = bsdf::specular_branches(&material.surface, d, &sp, hit.t) {
                match t {
                    Some(t) => {
                        l += next(self, t, rng, aov);
                        l += next(self, r, rng, &mut None);
                    }
                    None => l += next(self, r, rng, aov),
                }
            }
        } else if let Some(s) = bsdf::sample_specular(&material.surface, d, &sp, hit.t, rng) {
            l += next(self, s, rng, aov);
        }
        l
    }

    /// Radiance leaving a Lambert surface towards the camera.
    fn diffuse(&mut self, sp: &SurfacePoint, rng: &mut Rng, aov: &mut Option<&mut Aov>) -> Rgb {
        let albedo = sp.albedo(self.scene);
        if albedo.max_element() <= 0.0 {
            return Rgb::ZERO;
        }
        let mut l = Rgb::ZERO;
        if self.settings.direct == DirectLighting::ShadowRays {
            l += bsdf::lambert(albedo) * self.direct_irradiance(sp, rng);
        }
        let g = self
            .photons
            .estimator
            .gather(&query_at(sp, self.footprint), &mut self.knn);
        // Photons carry no direction here: a normal map's shadowing as for even light.
        l += density_radiance(albedo * bsdf::bump::mean_sample(sp, rng), g.flux, g.r2);
        if self.gathers(g.needs_gathering) {
            l += albedo * self.final_gather(sp, GatherLobe::Cosine, rng);
        }
        if let Some(a) = aov.take() {
            a.albedo = albedo;
            a.density = photon_density(g.count as f32, g.r2);
            a.radius = g.r2.sqrt();
        }
        l
    }

    /// Radiance arriving over the hemisphere from other surfaces, read from precomputed
    /// irradiance at the first diffuse surface each gather ray reaches through mirrors and glass,
    /// weighted as `lobe` says: with [`GatherLobe::Cosine`] the cosine-weighted mean (indirect
    /// radiance = albedo × this), with [`GatherLobe::Stored`] the radiance the stored lobes
    /// reflect. Some rays ([`RenderSettings::gather_bright`]) are aimed at bright texels of the
    /// planes ([`crate::estimate::bright`]); every ray is weighted by the balance heuristic over
    /// both kinds, whose denominators count the rays (no division by their number after).
    fn final_gather(&mut self, sp: &SurfacePoint, lobe: GatherLobe<'_>, rng: &mut Rng) -> Rgb {
        let n = self.settings.gather;
        let bright = self.photons.estimator.bright();
        let mut aim = std::mem::take(&mut self.aim);
        let aimed = match bright {
            Some((_, texels)) if n > 1 => {
                texels.aim(sp.position, sp.facing_shading_normal, &mut aim);
                if aim.any() {
                    texels.aimed_rays(n, self.settings.gather_bright)
                } else {
                    0
                }
            }
            _ => 0,
        };
        let rays = (n - aimed, aimed);
        let mut sum = Rgb::ZERO;
        let points = self.gather_points;
        for j in 0..rays.0 {
            let Some(s) = lobe.sample(sp, points.point(j), rng) else {
                continue;
            };
            let (l, pdf_aimed) =
                self.gather_ray_first(sp.leave(s.direction), s.direction, (aimed > 0).then_some(&aim), rng);
            sum += l * lobe.weight(&s, pdf_aimed, rays);
        }
        if let Some((grids, texels)) = bright {
            for k in 0..aimed {
                // Stratified: the texel's choice and one coordinate in it.
                let u = self.aimed_points.point(k);
                let Some(s) = texels.sample(&aim, u.x, Vec2::new(u.y, rng.uniform())) else {
                    break;
                };
                if let Some((l, d, pdf_aimed)) = self.aimed_ray(sp, &s, grids) {
                    sum += l * lobe.weight(&lobe.eval(sp, d), pdf_aimed, rays);
                }
            }
        }
        self.aim = aim;
        sum
    }

    /// A cosine-distributed gather ray: the radiance it brings and, where it lands on a
    /// Lambert surface of a plane and some rays are aimed (from where `aim` was made), the
    /// solid-angle density with which an aimed ray picks that point (0 elsewhere: aimed rays
    /// never bring light from there).
    fn gather_ray_first(&mut self, o: Origin, d: Vec3, aim: Option<&Aim>, rng: &mut Rng) -> (Rgb, f32) {
        let Some(hit) = self.accel.intersect_from(o, d, f32::INFINITY) else {
            return (Rgb::ZERO, 0.0);
        };
        let sp = SurfacePoint::new(self.scene, o.point, d, hit);
        let pdf = match (self.photons.estimator.bright(), aim) {
            (Some((grids, texels)), Some(aim)) if self.is_lambert(&sp) => {
                grids.plane_facing(sp.triangle, sp.facing_normal).map_or(0.0, |k| {
                    solid_angle_pdf(texels.pdf_area(aim, k, sp.position), hit.t, d, sp.facing_normal)
                })
            }
            _ => 0.0,
        };
        (self.gather_at(&sp, d, hit.t, 0, rng), pdf)
    }

    /// An aimed gather ray towards `s`: the radiance it brings, its direction and the
    /// solid-angle density of the aim; None where the point is behind `sp`, faces away,
    /// is hidden, or is not a Lambert surface of that plane (cosine-distributed rays bring
    /// the light of all those).
    fn aimed_ray(&mut self, sp: &SurfacePoint, s: &BrightSample, grids: &MultiscaleGrids) -> Option<(Rgb, Vec3, f32)> {
        let to = s.point - sp.position;
        let dist = to.length();
        let d = to / dist;
        let cos = d.dot(sp.facing_shading_normal);
        if !(cos > 0.0 && d.dot(sp.facing_normal) > 0.0 && -d.dot(s.normal) > 0.0) {
            return None;
        }
        let o = sp.offset(d);
        let hit = self.accel.intersect(o, d, f32::INFINITY)?;
        let z = SurfacePoint::new(self.scene, o, d, hit);
        // The ray must end at the point aimed at, on its plane: short of it, something hides it.
        let there = (hit.t - dist).abs() <= AIM_TOLERANCE * dist + 4.0 * z.eps;
        if !there || grids.plane_facing(z.triangle, z.facing_normal) != Some(s.plane) {
            return None;
        }
        let l = self.lambert_radiance(&z)?;
        Some((l, d, solid_angle_pdf(s.pdf_area, hit.t, d, s.normal)))
    }

    fn is_lambert(&self, sp: &SurfacePoint) -> bool {
        matches!(
            self.scene.materials[sp.material as usize].surface,
            Surface::Lambert { .. }
        )
    }

    /// Radiance leaving a Lambert surface where a gather ray landed (read from precomputed
    /// irradiance); None for other surfaces.
    fn lambert_radiance(&mut self, sp: &SurfacePoint) -> Option<Rgb> {
        self.is_lambert(sp)
            .then(|| bsdf::lambert(sp.albedo(self.scene)) * self.gathered_irradiance(sp))
    }

    /// Radiance leaving the first diffuse surface along a gather ray, emission excluded (direct
    /// light is counted by shadow rays, light through glass by caustic photons).
    fn gather_ray(&mut self, o: Origin, d: Vec3, depth: u32, rng: &mut Rng) -> Rgb {
        let Some(hit) = self.accel.intersect_from(o, d, f32::INFINITY) else {
            return Rgb::ZERO;
        };
        let sp = SurfacePoint::new(self.scene, o.point, d, hit);
        self.gather_at(&sp, d, hit.t, depth, rng)
    }

    /// Radiance leaving `sp`, where a gather ray along `d` landed after `t`.
    fn gather_at(&mut self, sp: &SurfacePoint, d: Vec3, t: f32, depth: u32, rng: &mut Rng) -> Rgb {
        if let Some(l) = self.lambert_radiance(sp) {
            return l;
        }
        let surface = &self.scene.materials[sp.material as usize].surface;
        if let Surface::Gltf(m) = surface {
            return self.gather_gltf(m, sp, (d, t, depth), rng);
        }
        if depth >= MAX_GATHER_DEPTH {
            return Rgb::ZERO;
        }
        match bsdf::sample_specular(surface, d, sp, t, rng) {
            Some(s) => s.weight * self.gather_ray(sp.leave(s.direction), s.direction, depth + 1, rng),
            None => Rgb::ZERO,
        }
    }

    /// Precomputed irradiance at a surface a gather ray reached (grids, else the cache).
    fn gathered_irradiance(&mut self, sp: &SurfacePoint) -> Rgb {
        match self
            .photons
            .estimator
            .grid_irradiance(sp.triangle, sp.position, sp.facing_normal)
        {
            Some(e) => e,
            None => match self.photons.irradiance {
                Some(cache) => cache.lookup(sp.position, sp.facing_normal, &mut self.knn),
                None => Rgb::ZERO,
            },
        }
    }

    /// Irradiance from all lights by shadow rays.
    fn direct_irradiance(&self, sp: &SurfacePoint, rng: &mut Rng) -> Rgb {
        let mut e = Rgb::ZERO;
        for light in &self.scene.lights {
            let samples = if light.is_delta() {
                1
            } else {
                self.settings.light_samples.max(1)
            };
            let mut sum = Rgb::ZERO;
            for _ in 0..samples {
                let Some(inc) = light.incident(sp.position, rng) else {
                    continue;
                };
                let cos = inc.wi.dot(sp.facing_shading_normal);
                if cos <= 0.0 || inc.wi.dot(sp.facing_normal) <= 0.0 {
                    continue;
                }
                let origin = sp.offset(inc.wi);
                let tmax = sp.shadow_tmax(inc.distance, self.scene.bounds.diagonal());
                if !self.accel.occluded(origin, inc.wi, tmax) {
                    sum += inc.irradiance * (cos * bsdf::bump::at(sp, inc.wi));
                }
            }
            e += sum / samples as f32;
        }
        e
    }
}

/// The AOVs of the first surface a camera sample meets: its normal and distance.
fn first_hit_aov(aov: &mut Option<&mut Aov>, sp: &SurfacePoint, t: f32) {
    if let Some(a) = aov.as_deref_mut() {
        a.normal = sp.facing_shading_normal;
        a.depth = t;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A pass's settings with `gather` rays per gather and the render's sequences keyed by
    /// `seed`.
    fn pass(gather: u32, seed: u64) -> RenderSettings {
        RenderSettings {
            width: 256,
            height: 256,
            spp: 1,
            direct: DirectLighting::ShadowRays,
            light_samples: 1,
            max_specular_depth: 8,
            split_depth: 2,
            seed,
            sequence_seed: seed,
            first_sample: 0,
            gather,
            gather_bright: 0.0,
        }
    }

    /// Whether `points` (2^m of them) hold one point in each cell of every 2^a × 2^(m-a) grid.
    fn is_net(points: &[Vec2]) -> bool {
        let m = points.len().trailing_zeros();
        (0..=m).all(|a| {
            let (nx, ny) = (1u32 << a, 1u32 << (m - a));
            let mut seen = vec![false; points.len()];
            points.iter().all(|u| {
                let c = ((u.y * ny as f32) as u32 * nx + (u.x * nx as f32) as u32) as usize;
                !std::mem::replace(&mut seen[c], true)
            })
        })
    }

    /// Points `0..count` of samples `samples` at each pixel of `pixels`, of `kind` (the
    /// gather's directions or the aimed rays').
    fn points_of(
        kind: fn(&RenderSettings, usize, usize, u32) -> GatherPoints,
        rs: &RenderSettings,
        pixels: &[(usize, usize)],
        samples: std::ops::Range<u32>,
        count: u32,
    ) -> Vec<Vec2> {
        let mut out = Vec::new();
        for &(x, y) in pixels {
            for s in samples.clone() {
                let p = kind(rs, x, y, s);
                out.extend((0..count).map(|j| p.point(j)));
            }
        }
        out
    }

    fn points(rs: &RenderSettings, pixels: &[(usize, usize)], samples: std::ops::Range<u32>, count: u32) -> Vec<Vec2> {
        points_of(GatherPoints::of, rs, pixels, samples, count)
    }

    fn block(x0: usize, y0: usize, side: usize) -> Vec<(usize, usize)> {
        (0..side * side).map(|i| (x0 + i % side, y0 + i / side)).collect()
    }

    #[test]
    fn gathers_samples_runs_and_blocks_of_pixels_are_nets() {
        let run = 0..TILE_RUN;
        for (gather, stride) in [(8u32, 8u32), (5, 8), (16, 16)] {
            let rs = pass(gather, 3);
            // Each gather, in the tile's run and in the pixel's own sequence after it.
            for s in [0, 1, 7, 8, 9, 1001] {
                assert!(is_net(&points(&rs, &[(77, 140)], s..s + 1, stride)), "{gather} {s}");
            }
            // A pixel's run, and its own sequence's next samples.
            assert!(is_net(&points(&rs, &[(77, 140)], run.clone(), stride)), "{gather}");
            assert!(is_net(&points(&rs, &[(77, 140)], 8..16, stride)), "{gather}");
            // A 2×2 and an 8×8 block of pixels together, whole runs.
            assert!(
                is_net(&points(&rs, &block(76, 140, 2), run.clone(), stride)),
                "{gather}"
            );
            assert!(
                is_net(&points(&rs, &block(64, 136, 8), run.clone(), stride)),
                "{gather}"
            );
        }
        let first = |x, y, s, gather| GatherPoints::of(&pass(gather, 3), x, y, s).point(0);
        assert_ne!(first(1, 0, 0, 8), first(2, 0, 0, 8));
        assert_ne!(first(1, 0, 0, 8), first(1, 0, 1, 8));
        assert_ne!(first(1, 0, 8, 8), first(2, 0, 8, 8));
        // Another tile is scrambled anew; so is another gather count (another pass's plan).
        let tile = |x| GatherPoints::of(&pass(8, 3), x, 0, 0).scramble;
        assert_ne!(tile(1), tile(65));
        assert_ne!(first(1, 0, 0, 8), first(1, 0, 0, 16));
        // A sample's points do not depend on how the samples are split into passes.
        let later = RenderSettings {
            first_sample: 6,
            ..pass(8, 3)
        };
        for s in 0..4 {
            assert_eq!(
                points(&later, &[(9, 9)], s..s + 1, 8),
                points(&pass(8, 3), &[(9, 9)], s + 6..s + 7, 8)
            );
        }
        // The aimed rays' points (one per sample at an eighth of 8 rays): a pixel's run, a block.
        let rs = RenderSettings {
            gather_bright: 0.125,
            ..pass(8, 3)
        };
        let aimed = |pixels: &[(usize, usize)]| points_of(GatherPoints::aimed, &rs, pixels, run.clone(), 1);
        assert!(is_net(&aimed(&[(77, 140)])));
        assert!(is_net(&aimed(&block(64, 136, 8))));
        assert_ne!(aimed(&[(77, 140)]), points(&rs, &[(77, 140)], run.clone(), 1));
    }

    /// What sharing a tile's sequence is for: the average of an 8×8 block of pixels gathering
    /// the same smooth light over whole runs is far less noisy than if each pixel's gathers
    /// were a net of its own (another tile's: independent scrambles), and unbiased; over parts
    /// of runs it is about as noisy.
    #[test]
    fn a_blocks_shared_gathers_average_out_faster_than_independent_ones() {
        let radiance = |d: Vec3| 1.0 + d.x + 0.5 * d.y * d.y;
        let truth = 1.0 + 0.5 * 0.25;
        let mean_of = |points: &[Vec2]| {
            points
                .iter()
                .map(|&u| radiance(sampling::cosine_hemisphere(u, Vec3::Z)) as f64)
                .sum::<f64>()
                / points.len() as f64
        };
        let trials = 200;
        // Whole runs, and renders of a half, a quarter and an eighth of a run.
        for samples in [TILE_RUN, 4, 2, 1] {
            let (mut se_shared, mut se_own, mut sum_shared) = (0.0, 0.0, 0.0);
            for t in 0..trials {
                let rs = pass(8, t);
                let shared = mean_of(&points(&rs, &block(0, 0, 8), 0..samples, 8));
                // The first pixel of 64 other tiles.
                let own: Vec<Vec2> = (1..=64)
                    .flat_map(|i| points(&rs, &[(64 * i, 0)], 0..samples, 8))
                    .collect();
                sum_shared += shared;
                se_shared += (shared - truth).powi(2);
                se_own += (mean_of(&own) - truth).powi(2);
            }
            let mean = sum_shared / trials as f64;
            let sd = (se_shared / trials as f64).sqrt();
            assert!(
                (mean - truth).abs() < 4.0 * sd / (trials as f64).sqrt() + 1e-6,
                "{samples}: mean {mean}"
            );
            // Whole runs: far better; parts of runs: about as good, never much worse.
            let most = if samples == TILE_RUN { 0.1 } else { 2.0 };
            assert!(se_shared < most * se_own, "{samples}: shared {se_shared}, own {se_own}");
        }
    }

    /// What the stratification is for: the cosine-weighted mean of a smooth radiance over the
    /// hemisphere (a sky brighter towards one side), estimated with 8 directions, is unbiased
    /// and far less noisy than with independent directions.
    #[test]
    fn stratified_gathers_are_unbiased_and_less_noisy_than_independent_ones() {
        let n = Vec3::Z;
        let radiance = |d: Vec3| 1.0 + d.x + 0.5 * d.y * d.y;
        // ∫ L cos dω / π: the odd term vanishes, E[y²] under the cosine density is 1/4.
        let truth = 1.0 + 0.5 * 0.25;
        let (mut se_strat, mut se_rand, mut sum_strat) = (0.0f64, 0.0f64, 0.0f64);
        let trials = 4000;
        let mut rng = Rng::keyed(1, 2, 3);
        for t in 0..trials {
            let p = GatherPoints::of(&pass(8, 9), 64 * t as usize, 0, 0); // a tile each
            let strat: f32 = (0..8)
                .map(|j| radiance(sampling::cosine_hemisphere(p.point(j), n)))
                .sum::<f32>()
                / 8.0;
            let rand: f32 = (0..8)
                .map(|_| radiance(sampling::cosine_hemisphere(rng.uniform2(), n)))
                .sum::<f32>()
                / 8.0;
            sum_strat += strat as f64;
            se_strat += ((strat - truth) as f64).powi(2);
            se_rand += ((rand - truth) as f64).powi(2);
        }
        let mean = sum_strat / trials as f64;
        let sd = (se_strat / trials as f64).sqrt();
        assert!(
            (mean - truth as f64).abs() < 4.0 * sd / (trials as f64).sqrt(),
            "mean {mean}, truth {truth}"
        );
        assert!(
            se_strat < 0.25 * se_rand,
            "stratified {se_strat}, independent {se_rand}"
        );
    }
}
