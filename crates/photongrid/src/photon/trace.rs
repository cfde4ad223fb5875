//! The photon pass: shoot photons from the lights in proportion to their power, follow glass
//! and mirrors, store a photon at every diffuse hit, continue by Russian roulette.

use super::caustic::SpecularTargets;
use super::store::{Photon, PhotonKind};
use crate::accel::{ClosestHit, Origin};
use crate::bsdf;
use crate::sampling::{self, stream, Rng, Sampler, Scrambles, SobolWalk, Stratified};
use crate::scene::light::LightSampler;
use crate::scene::material::MetallicRoughness;
use crate::scene::{Scene, Surface};
use crate::surface::SurfacePoint;
use crate::Rgb;
use glam::Vec3;
use rayon::prelude::*;

/// Settings of the photon pass.
#[derive(Clone, Debug, serde::Serialize)]
pub struct TraceSettings {
    /// Photons emitted (paths started).
    pub photons: usize,
    /// Surface interactions (diffuse, glass and mirror hits) after which a path stops; a photon
    /// stored at the n-th records n ([`Photon::depth`]).
    pub max_depth: u32,
    /// Keep photons of direct light (the single-map method needs them; shadow rays do not).
    pub store_direct: bool,
    /// Random seed (keys each path's own random numbers).
    pub seed: u64,
    /// Where the paths start in the Sobol sequences their first numbers come from.
    pub sequences: Sequences,
    /// Also return the triangle each photon landed on (for the plane grids).
    pub record_triangles: bool,
    /// Extra paths aimed at mirrors and glass, storing caustic photons only (0: none; also
    /// none when the scene has no specular surface).
    pub caustic_photons: usize,
}

/// Where a photon pass's paths start in the Sobol sequences that emit them, one per kind of
/// path (global, caustic), scrambled by `seed`. Progressive passes continue the sequences, so
/// that all passes' photons together spread as evenly as one pass of their number; passes
/// scrambled independently each spread evenly, but their union does not.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct Sequences {
    /// The scrambles' seed.
    pub seed: u64,
    /// The first global path's position.
    pub global: u32,
    /// The first caustic path's position.
    pub caustic: u32,
}

impl Sequences {
    /// Both sequences from their start, scrambled by `seed`.
    pub fn starting(seed: u64) -> Self {
        Sequences {
            seed,
            global: 0,
            caustic: 0,
        }
    }

    /// Where the pass after one of `stats.emitted` global and `stats.caustic_emitted` caustic
    /// paths starts.
    pub fn after(self, stats: &PhotonStats) -> Self {
        let on = |start: u32, n: usize| u32::try_from(start as usize + n).unwrap_or(u32::MAX);
        Sequences {
            seed: self.seed,
            global: on(self.global, stats.emitted),
            caustic: on(self.caustic, stats.caustic_emitted),
        }
    }

    /// The scrambles' seed and first position of a pass of `paths` paths from `start`: the
    /// sequence has 2³² positions, and a pass that would run past them starts a sequence of
    /// its own, scrambled by `pass_seed` (positions wrapping round would repeat points).
    fn place(self, start: u32, paths: usize, pass_seed: u64) -> (u64, u32) {
        if start as u64 + paths as u64 <= 1 << 32 {
            (self.seed, start)
        } else {
            (pass_seed ^ 0x5345_5155_454E_4345, 0)
        }
    }
}

/// Which photons a pass stores.
#[derive(Clone, Copy, PartialEq, Eq)]
enum PassKind {
    /// Every diffuse hit (direct ones if `store_direct`; caustic ones if `store_caustic`).
    Global { store_caustic: bool },
    /// Only the first diffuse hit after mirrors/glass; paths that hit a diffuse surface first
    /// are dropped (the global pass accounts for them).
    Caustic,
}

impl PassKind {
    /// Whether the pass stores a photon of `kind` at a diffuse hit.
    fn stores(self, kind: PhotonKind, store_direct: bool) -> bool {
        match (self, kind) {
            (PassKind::Caustic, PhotonKind::Caustic) => true,
            (PassKind::Caustic, _) => false,
            (PassKind::Global { store_caustic }, PhotonKind::Caustic) => store_caustic,
            (PassKind::Global { .. }, PhotonKind::Direct) => store_direct,
            (PassKind::Global { .. }, PhotonKind::Indirect) => true,
        }
    }
}

struct Pass {
    kind: PassKind,
    stream: u64,
    paths: usize,
    /// The scrambles' seed and the first path's position in the pass's Sobol sequence.
    sequence: (u64, u32),
}

/// Trace `pass.paths` paths in parallel chunks, appending their photons to `all` in path
/// order; photon `i` is emitted from the point `i` positions after the pass's first in its
/// scrambled Sobol sequence, in Gray-code order ([`SobolWalk`], [`Stratified`]), then follows
/// its own keyed random stream.
/// The chunks run in waves of [`WAVE`]; a wave's photons are appended while the next wave is
/// traced (one thread appends, then joins the tracing): the photons exist once, plus two
/// waves' buffers (collecting every chunk first held them twice), and no thread waits for the
/// appending.
fn run_pass(
    scene: &Scene,
    accel: &impl ClosestHit,
    settings: &TraceSettings,
    pass: &Pass,
    progress: &(dyn Fn(usize) + Sync),
    emit: &(dyn Fn(&mut Stratified) -> Option<(crate::scene::light::Emission, f32)> + Sync),
    all: &mut PassOutput,
) {
    let n = pass.paths;
    let chunks = n.div_ceil(CHUNK);
    let (sequence_seed, first) = pass.sequence;
    let scrambles = Scrambles::new(sequence_seed, pass.stream);
    let tracer = Tracer {
        scene,
        accel,
        settings,
        pass: pass.kind,
    };
    let trace_chunk = |c: usize| {
        let mut out = Out {
            photons: Vec::with_capacity(CHUNK * 2),
            triangles: Vec::new(),
            record: settings.record_triangles,
            rays: 0,
            kinds: PhotonStats::default(),
        };
        let end = ((c + 1) * CHUNK).min(n);
        let mut walk = SobolWalk::starting_at(first + (c * CHUNK) as u32);
        for i in c * CHUNK..end {
            let mut rng = Rng::keyed(settings.seed, pass.stream, i as u64);
            let emitted = emit(&mut Stratified::new(walk.next_point(), &scrambles, &mut rng));
            if let Some((e, p_light)) = emitted {
                let power = e.flux / (p_light * n as f32);
                let ray = (e.origin.into(), e.direction, power);
                tracer.path(ray, &mut rng, &mut out);
            }
        }
        progress(end - c * CHUNK);
        out
    };
    let trace_wave = |wave: usize| -> Vec<Out> {
        (wave..(wave + WAVE).min(chunks))
            .into_par_iter()
            .map(trace_chunk)
            .collect()
    };
    let mut pending = Vec::new();
    for wave in (0..chunks).step_by(WAVE) {
        let (outs, ()) = rayon::join(|| trace_wave(wave), || all.append(pending));
        if wave == 0 {
            // Room for the whole pass, from the first wave's photons per path plus an eighth:
            // growing by doubling copied the photons up to twice more (pages never written
            // are not resident).
            let stored: usize = outs.iter().map(|c| c.photons.len()).sum();
            let done = (WAVE * CHUNK).min(n);
            let expected = (stored as f64 / done as f64 * n as f64 * 1.125) as usize;
            all.photons.reserve(expected);
            if settings.record_triangles {
                all.triangles.reserve(expected);
            }
        }
        pending = outs;
    }
    all.append(pending);
}

impl PassOutput {
    /// Append chunks' outputs, in order.
    fn append(&mut self, outs: Vec<Out>) {
        for c in outs {
            self.photons.extend_from_slice(&c.photons);
            self.triangles.extend_from_slice(&c.triangles);
            self.rays += c.rays;
            self.kinds.add(&c.kinds);
        }
    }
}

/// The photons of one pass, the triangle of each (when recorded) and the rays traced.
#[derive(Default)]
struct PassOutput {
    photons: Vec<Photon>,
    triangles: Vec<u32>,
    rays: usize,
    /// The photons' counts and power by kind ([`PhotonStats::count`]).
    kinds: PhotonStats,
}

/// What the photon pass produced.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct PhotonStats {
    /// Paths started.
    pub emitted: usize,
    /// Photons stored, all kinds.
    pub stored: usize,
    /// Paths started by the caustic pass (aimed at mirrors and glass).
    pub caustic_emitted: usize,
    /// Specular objects the caustic pass aimed at.
    pub caustic_targets: usize,
    /// Caustic-pass paths whose first hit was not a mirror or glass (aimed past them, or
    /// blocked): the aim's waste.
    pub caustic_missed: usize,
    /// Stored direct photons.
    pub direct: usize,
    /// Stored caustic photons.
    pub caustic: usize,
    /// Stored indirect photons.
    pub indirect: usize,
    /// Bytes of photon storage (of the largest pass).
    pub bytes: usize,
    /// Closest-hit rays traced by the photon passes (one per path segment), so that the
    /// photon pass's ray rate can be set against the BVH's (`photongrid throughput`).
    pub rays: usize,
    /// Wall seconds of the global pass's tracing (the time budget prices each kind of path).
    pub global_seconds: f64,
    /// Wall seconds of the caustic pass's tracing.
    pub caustic_seconds: f64,
    /// Stored power (luminance, W) of caustic photons, and of all photons: how much of the
    /// light caustics carry.
    pub caustic_power: f64,
    /// Stored power (luminance, W) of all photons.
    pub stored_power: f64,
}

impl PhotonStats {
    /// Add another pass's counts (the specular targets are the same every pass).
    pub fn add(&mut self, o: &PhotonStats) {
        self.emitted += o.emitted;
        self.stored += o.stored;
        self.caustic_emitted += o.caustic_emitted;
        self.caustic_targets = self.caustic_targets.max(o.caustic_targets);
        self.caustic_missed += o.caustic_missed;
        self.direct += o.direct;
        self.caustic += o.caustic;
        self.indirect += o.indirect;
        self.bytes = self.bytes.max(o.bytes);
        self.rays += o.rays;
        self.global_seconds += o.global_seconds;
        self.caustic_seconds += o.caustic_seconds;
        self.caustic_power += o.caustic_power;
        self.stored_power += o.stored_power;
    }
}

/// Paths per parallel work item: large enough to amortise scheduling, small for balance.
const CHUNK: usize = 2048;
/// Chunks per wave of [`run_pass`]: enough for balance between the threads, few enough that
/// one wave's buffers are small beside the photons.
const WAVE: usize = 128;

/// Trace `settings.photons` photon paths. Deterministic for a seed, whatever the thread count.
/// Returns the photons, the triangle of each (empty unless `record_triangles`), and counts.
pub fn trace_photons(
    scene: &Scene,
    accel: &impl ClosestHit,
    settings: &TraceSettings,
    progress: &(dyn Fn(usize) + Sync),
) -> (Vec<Photon>, Vec<u32>, PhotonStats) {
    let lights = LightSampler::new(&scene.lights);
    let targets = if settings.caustic_photons > 0 {
        SpecularTargets::find(scene)
    } else {
        SpecularTargets::default()
    };
    let caustic_pass = !targets.is_empty();
    let pick_light = |rng: &mut Stratified| lights.sample(rng.uniform());
    // The global pass; when the caustic pass runs, it owns every light → specular → diffuse
    // photon and the global pass must not store them too.
    let n = settings.photons;
    let t0 = std::time::Instant::now();
    let global = Pass {
        kind: PassKind::Global {
            store_caustic: !caustic_pass,
        },
        stream: stream::PHOTONS,
        paths: n,
        sequence: settings.sequences.place(settings.sequences.global, n, settings.seed),
    };
    let mut out = PassOutput::default();
    run_pass(
        scene,
        accel,
        settings,
        &global,
        progress,
        &|rng| {
            let (l, p) = pick_light(rng);
            let e = scene.lights[l].emit(rng);
            Some((e, p))
        },
        &mut out,
    );
    let global_seconds = t0.elapsed().as_secs_f64();
    let nc = if caustic_pass { settings.caustic_photons } else { 0 };
    if nc > 0 {
        let aims: Vec<_> = scene.lights.iter().map(|l| targets.aim(l)).collect();
        let pass = Pass {
            kind: PassKind::Caustic,
            stream: stream::CAUSTIC_PHOTONS,
            paths: nc,
            sequence: settings.sequences.place(settings.sequences.caustic, nc, settings.seed),
        };
        run_pass(
            scene,
            accel,
            settings,
            &pass,
            &|_| {},
            &|rng| {
                let (l, p) = pick_light(rng);
                targets.emit(&scene.lights[l], &aims[l], rng).map(|e| (e, p))
            },
            &mut out,
        );
    }
    out.photons.shrink_to_fit();
    out.triangles.shrink_to_fit();
    let (photons, triangles, rays) = (out.photons, out.triangles, out.rays);
    let mut stats = PhotonStats {
        emitted: n,
        caustic_emitted: nc,
        caustic_targets: targets.targets.len(),
        stored: photons.len(),
        rays,
        bytes: photons.len() * std::mem::size_of::<Photon>(),
        global_seconds,
        caustic_seconds: t0.elapsed().as_secs_f64() - global_seconds,
        ..Default::default()
    };
    stats.add(&out.kinds);
    (photons, triangles, stats)
}

impl PhotonStats {
    /// Count a stored photon by kind, with its power.
    fn count(&mut self, p: &Photon) {
        let power = crate::luminance(p.power()) as f64;
        self.stored_power += power;
        match p.kind() {
            PhotonKind::Direct => self.direct += 1,
            PhotonKind::Caustic => {
                self.caustic += 1;
                self.caustic_power += power;
            }
            PhotonKind::Indirect => self.indirect += 1,
        }
    }
}

/// Per-thread output of the tracer.
struct Out {
    photons: Vec<Photon>,
    triangles: Vec<u32>,
    record: bool,
    /// Closest-hit rays traced.
    rays: usize,
    /// Counts by kind, added in chunk order (the same sums whatever the thread count).
    kinds: PhotonStats,
}

impl Out {
    fn push(&mut self, p: Photon, triangle: u32) {
        self.kinds.count(&p);
        self.photons.push(p);
        if self.record {
            self.triangles.push(triangle);
        }
    }

    /// Store a photon of `power` that arrived along `dir` at `sp` after `depth` interactions.
    fn store(&mut self, sp: &SurfacePoint, dir: Vec3, power: Rgb, kind: PhotonKind, depth: u32, rng: &mut Rng) {
        // Stochastic rounding of the power: the photons share a few exact powers, which nearest
        // rounding would bias all alike (see `rgbe_encode_dithered`). One uniform for all
        // channels: each is unbiased, and grey stays grey.
        let dither = Vec3::splat(rng.uniform());
        let p = Photon::dithered(sp.position, power, sp.facing_normal, -dir, kind, dither).with_depth(depth);
        self.push(p, sp.triangle);
    }
}

/// Specular interactions of one emitted photon, its spawned branches included, that follow
/// both Fresnel branches ([`bsdf::split_specular`]); later ones choose a branch by chance. Four
/// cover the two crossings of a slab or a solid and a reflection, and bound the branches one
/// emitted photon can spawn.
const SPLIT_SPECULAR: u32 = 4;

/// A photon leaving a surface: where from, where to, its power and kind, and the surface
/// interactions behind it.
#[derive(Clone, Copy)]
struct Leg {
    origin: Origin,
    dir: Vec3,
    power: Rgb,
    kind: PhotonKind,
    depth: u32,
}

impl Leg {
    /// A photon leaving `sp`, its `depth`-th interaction, along `dir`.
    fn leaving(sp: &SurfacePoint, depth: u32, dir: Vec3, power: Rgb, kind: PhotonKind) -> Self {
        Leg {
            origin: sp.leave(dir),
            dir,
            power,
            kind,
            depth,
        }
    }
}

/// What a photon pass traces with; follows photon paths.
struct Tracer<'a, A> {
    scene: &'a Scene,
    accel: &'a A,
    settings: &'a TraceSettings,
    pass: PassKind,
}

impl<A: ClosestHit> Tracer<'_, A> {
    /// Follow one photon emitted from `origin` along `dir` with `power`, storing its photons in
    /// `out`.
    fn path(&self, (origin, dir, power): (Origin, Vec3, Rgb), rng: &mut Rng, out: &mut Out) {
        let leg = Leg {
            origin,
            dir,
            power,
            kind: PhotonKind::Direct,
            depth: 0,
        };
        let mut splits = SPLIT_SPECULAR;
        self.follow(leg, &mut splits, rng, out);
    }

    /// Follow a photon from `leg` until it is absorbed, leaves the scene or reaches the depth
    /// limit; `splits` is what is left of [`SPLIT_SPECULAR`] for its emitted photon.
    fn follow(&self, mut leg: Leg, splits: &mut u32, rng: &mut Rng, out: &mut Out) {
        let (scene, settings, pass) = (self.scene, self.settings, self.pass);
        for depth in leg.depth + 1..=settings.max_depth {
            let (dir, power, kind) = (leg.dir, leg.power, leg.kind);
            if !(power.max_element() > 0.0 && power.is_finite()) {
                return; // a continued or spawned branch alike
            }
            out.rays += 1;
            let Some(hit) = self.accel.closest_hit(leg.origin, dir, f32::INFINITY) else {
                out.kinds.caustic_missed += usize::from(depth == 1 && pass == PassKind::Caustic);
                return;
            };
            let sp = SurfacePoint::new(scene, leg.origin.point, dir, hit);
            let material = &scene.materials[sp.material as usize];
            if depth == 1 && pass == PassKind::Caustic && !material.is_specular() {
                out.kinds.caustic_missed += 1;
            }
            let next = match &material.surface {
                Surface::Lambert { .. } => {
                    let albedo = sp.albedo(scene);
                    if albedo.max_element() <= 0.0 {
                        return;
                    }
                    if pass.stores(kind, settings.store_direct) {
                        out.store(&sp, dir, power, kind, depth, rng);
                    }
                    if pass == PassKind::Caustic {
                        return; // the caustic pass ends at the first diffuse surface
                    }
                    // Russian roulette on the largest channel keeps the photon power nearly constant.
                    let q = albedo.max_element().min(1.0);
                    if rng.uniform() >= q {
                        return;
                    }
                    // A normal map shadows the light it came with as in the camera pass.
                    let power = power * albedo / q * bsdf::bump::at(&sp, -dir);
                    let dir = sampling::cosine_hemisphere(rng.uniform2(), sp.facing_shading_normal);
                    if dir.dot(sp.facing_normal) <= 0.0 {
                        return; // shading normal sent it below the surface
                    }
                    Some(Leg::leaving(&sp, depth, dir, power, PhotonKind::Indirect))
                }
                Surface::Gltf(m) => self.gltf_step(m, (&sp, hit.t, depth), &leg, rng, out),
                surface if *splits > 0 => {
                    *splits -= 1;
                    let Some((s, other)) = bsdf::split_specular(surface, dir, &sp, hit.t, rng) else {
                        return;
                    };
                    if let Some(branch) = other.and_then(|o| specular_leg(&sp, depth, &leg, o, o.weight)) {
                        self.follow(branch, splits, rng, out);
                    }
                    specular_leg(&sp, depth, &leg, s, s.weight)
                }
                surface => {
                    let Some(s) = bsdf::sample_specular(surface, dir, &sp, hit.t, rng) else {
                        return;
                    };
                    let Some(w) = specular_roulette(s.weight, rng) else {
                        return;
                    };
                    specular_leg(&sp, depth, &leg, s, w)
                }
            };
            let Some(next) = next else {
                return;
            };
            leg = next;
        }
    }

    /// The photon of `arriving` at a glTF surface `sp` (after `distance`, its `depth`-th
    /// interaction): stored if the surface has a lobe rendered from photons, then continued by
    /// sampling the BSDF with Russian roulette; None where the path ends.
    fn gltf_step(
        &self,
        m: &MetallicRoughness,
        (sp, distance, depth): (&SurfacePoint, f32, u32),
        arriving: &Leg,
        rng: &mut Rng,
        out: &mut Out,
    ) -> Option<Leg> {
        let Leg { dir, power, kind, .. } = *arriving;
        let (stored, s) = bsdf::gltf_photon_step(self.scene, m, dir, sp, distance, rng);
        if stored && self.pass.stores(kind, self.settings.store_direct) {
            out.store(sp, dir, power, kind, depth, rng);
        }
        let s = s?;
        // The caustic pass follows light through traced lobes only; a photon leaving by a stored
        // lobe belongs to the global pass.
        if self.pass == PassKind::Caustic && !s.traced {
            return None;
        }
        let c = bsdf::adjoint_shading_correction(-dir, s.direction, sp.facing_normal, sp.facing_shading_normal)?;
        // Russian roulette by the sampled throughput keeps the power nearly constant.
        let q = s.weight.max_element().min(1.0);
        if !(q > 0.0) || rng.uniform() >= q {
            return None;
        }
        let kind = match (s.traced, kind) {
            (true, PhotonKind::Direct) => PhotonKind::Caustic,
            (true, k) => k,
            (false, _) => PhotonKind::Indirect,
        };
        Some(Leg::leaving(sp, depth, s.direction, power * (s.weight / q * c), kind))
    }
}

/// The photon of `arriving` leaving a mirror or glass at `sp` (its `depth`-th interaction) by
/// branch `s` with weight `w`, a caustic from then on; None where the shading normal forbids
/// the branch.
fn specular_leg(sp: &SurfacePoint, depth: u32, arriving: &Leg, s: bsdf::Scatter, w: Rgb) -> Option<Leg> {
    // Interpolated normals: Veach's adjoint weight (photons travel against the direction the
    // camera pass traces), and no path through the surface.
    let c = bsdf::adjoint_shading_correction(-arriving.dir, s.direction, sp.facing_normal, s.normal)?;
    let kind = match arriving.kind {
        PhotonKind::Direct => PhotonKind::Caustic,
        k => k,
    };
    Some(Leg::leaving(sp, depth, s.direction, arriving.power * w * c, kind))
}

/// Russian roulette where a specular weight is below one keeps the power nearly constant:
/// the factor to apply to the power, or None when the path ends. A random number is drawn
/// only when the weight is below one.
fn specular_roulette(weight: Rgb, rng: &mut Rng) -> Option<Rgb> {
    let q = weight.max_element().min(1.0);
    if q < 1.0 {
        if rng.uniform() >= q {
            return None;
        }
        Some(weight / q)
    } else {
        Some(weight)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_pass_that_would_run_past_the_sequence_starts_its_own() {
        let s = Sequences::starting(5);
        assert_eq!(s.place(0, 1000, 9), (5, 0));
        let late = u32::MAX - 999;
        assert_eq!(s.place(late, 1000, 9), (5, late), "the last position is still free");
        let (seed, first) = s.place(late, 1001, 9);
        assert_eq!(first, 0);
        assert_ne!(seed, 5);
        assert_ne!(seed, s.place(late, 1001, 10).0, "each pass scrambles its own");
        let stats = PhotonStats {
            emitted: usize::MAX / 2,
            caustic_emitted: 10,
            ..Default::default()
        };
        let next = s.after(&stats);
        assert_eq!((next.global, next.caustic), (u32::MAX, 10), "saturates");
    }
}
