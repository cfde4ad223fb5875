//! The time budget's logic on a real scene, without timing anything: a budget sizes the passes
//! from a probe and reports why, a pass still running at the deadline is dropped, and a
//! budgeted render gives a complete image. (Whether `--time T` ends at T on the public scenes
//! is measured by `bench/time_budget.sh`, not asserted here: CI machines are shared.)

use photongrid::pipeline::{render, RenderRequest};
use photongrid::progress::Progress;
use photongrid::render::budget::{GLOBAL_BOOST_MAX, SAMPLE_BOOST_MAX};
use photongrid::render::progressive::Stop;
use photongrid::Settings;
use std::time::{Duration, Instant};

fn scene() -> photongrid::scene::Scene {
    photongrid::load(&photongrid_testkit::repo_root().join("samples/cornell_glass.glb")).unwrap()
}

/// A 32×24 camera pass of `spp` samples and `gather` gather rays with `settings`' options.
fn render_settings(settings: &Settings, spp: u32, gather: u32) -> photongrid::render::RenderSettings {
    photongrid::render::RenderSettings {
        width: 32,
        height: 24,
        spp,
        direct: settings.direct,
        light_samples: settings.light_samples,
        max_specular_depth: settings.max_specular_depth,
        split_depth: settings.split_depth,
        seed: 1,
        sequence_seed: 1,
        first_sample: 0,
        gather,
        gather_bright: settings.gather_bright,
    }
}

fn small() -> Settings {
    Settings {
        width: Some(64),
        height: Some(48),
        photons: 200_000,
        caustic_photons: 100_000,
        ..Settings::default()
    }
}

/// cornell_glass with [`small`] settings and its first pass's photons, for one camera pass.
fn prepared_small() -> (photongrid::scene::Scene, Settings, photongrid::pipeline::Prepared) {
    let (scene, settings) = (scene(), small());
    let prepared = photongrid::prepare(&scene, &settings, &Progress::quiet(), &mut Default::default()).unwrap();
    (scene, settings, prepared)
}

#[test]
fn a_budget_sizes_passes_from_a_probe_and_says_why() {
    let scene = scene();
    let cameras: Vec<_> = scene.cameras.iter().collect();
    let settings = Settings {
        time: Some(3600.0),
        passes: Some(2),
        ..small()
    };
    let request = RenderRequest {
        scene: &scene,
        cameras: &cameras,
        settings: &settings,
        start: Instant::now(),
    };
    let r = render(&request, &Progress::quiet(), None).unwrap();
    let b = r.report.budget.expect("a budgeted render reports its plan");
    assert!(b.costs.per_path > 0.0 && b.costs.per_sample > 0.0, "{b:?}");
    assert_eq!(b.costs.pixels, 64 * 48);
    // An hour is plenty: the requested pass is kept (with more global photons where they
    // are cheap beside the camera's side, at most GLOBAL_BOOST_MAX times), and the pass count
    // still applies.
    assert_eq!(b.plan.size, b.requested);
    let c = &b.costs;
    let expected = if !c.planes_count_photons() {
        1.0
    } else {
        let global = settings.photons as f64 * c.per_path;
        let r = &b.requested;
        let camera = c.pixels as f64 * r.spp as f64 * (c.per_sample + r.gather as f64 * c.per_gather_ray);
        (camera / (2.0 * global)).clamp(1.0, GLOBAL_BOOST_MAX)
    };
    let photons = (settings.photons as f64 * expected).floor() as usize;
    assert!(
        b.requested.photons.abs_diff(photons) <= 1,
        "{b:?}: expected {photons} global photons"
    );
    // More samples instead where the planes count few photons.
    let spp = if !c.planes_count_photons() {
        settings.spp * SAMPLE_BOOST_MAX
    } else {
        settings.spp
    };
    assert_eq!(b.plan.size.spp, spp);
    assert!(b.plan.reason.contains("fits"), "{}", b.plan.reason);
    // Gathering is priced at the requested photons per gather ray and at fewer: never cheaper.
    let ladder: Vec<f64> = std::iter::once(c.per_gather_ray)
        .chain(c.per_gather_ray_sparser)
        .collect();
    assert!(ladder.is_sorted() && ladder[0] >= 0.0, "{ladder:?}");
    let requested_rays = (settings.spp * settings.effective_gather()) as f64;
    assert_eq!(c.photons_per_gather_ray, settings.photons as f64 / requested_rays);
    assert_eq!(r.report.passes.count, 2);
    assert_eq!(r.report.passes.stopped_by, Some(Stop::Passes));
    assert!(r.report.seconds.probe > 0.0);
}

#[test]
fn a_budget_already_spent_still_gives_one_complete_pass_and_no_more() {
    let scene = scene();
    let cameras: Vec<_> = scene.cameras.iter().collect();
    let settings = Settings {
        time: Some(1.0),
        ..small()
    };
    // The budget started long ago: the probe plans the smallest pass, which runs to the end
    // (the first pass is never dropped), and no second pass starts.
    let request = RenderRequest {
        scene: &scene,
        cameras: &cameras,
        settings: &settings,
        start: Instant::now() - Duration::from_secs(60),
    };
    let r = render(&request, &Progress::quiet(), None).unwrap();
    let b = r.report.budget.expect("plan");
    assert!(b.plan.over_budget, "{b:?}");
    assert_eq!(b.plan.size.spp, 1);
    assert_eq!(r.report.passes.count, 1);
    assert_eq!(r.report.passes.dropped, 0);
    assert_eq!(r.report.passes.stopped_by, Some(Stop::Time));
    let film = &r.films[0];
    assert!(
        film.mean().iter().all(|c| c.is_finite() && *c > 0.0),
        "{:?}",
        film.mean()
    );
    assert_eq!(film.nonfinite(), 0);
}

/// Call `f` with a 32×24 camera pass of `spp` samples and 2 gather rays on the small sample's
/// photons (pass 0).
fn with_small_pass(spp: u32, f: impl FnOnce(photongrid::render::CameraPass<'_>)) {
    use photongrid::estimate::Estimator;
    use photongrid::render::{CameraPass, PhotonData};
    let (scene, settings, prepared) = prepared_small();
    let surfaces = photongrid::estimate::Surfaces::new(&scene, &prepared.accel, &settings);
    let rs = render_settings(&settings, spp, 2);
    f(CameraPass {
        scene: &scene,
        accel: &prepared.accel,
        photons: PhotonData {
            estimator: Estimator::for_pass(&settings, 0, &prepared.map, prepared.grids.view(), &surfaces),
            irradiance: prepared.irradiance.as_ref(),
        },
        camera: &scene.cameras[0],
        settings: &rs,
        gathering_points: None,
    });
}

#[test]
fn a_camera_pass_past_its_deadline_keeps_its_required_sweeps_only() {
    use photongrid::render::{render, render_until, Cut};
    with_small_pass(3, |pass| {
        let past = Some(Instant::now() - Duration::from_millis(1));
        let cut = |deadline, required| Cut {
            deadline,
            required,
            spare: None,
        };
        assert!(
            render_until(pass, &|_| {}, cut(past, 0), None).is_none(),
            "nothing required: dropped"
        );
        let first = render_until(pass, &|_| {}, cut(past, 1), None).expect("the first sweep is required");
        assert_eq!(first.samples, 1);
        assert!(first.film.mean()[1] > 0.0);
        let later = Some(Instant::now() + Duration::from_secs(3600));
        let whole = render_until(pass, &|_| {}, cut(later, 1), None).expect("in time");
        assert_eq!(whole.samples, 3);
        // Sweeps add up to the same image as a pass without a deadline, and one sweep differs.
        let plain = render(pass, &|_| {});
        assert_eq!(whole.film.color, plain.color);
        assert_ne!(first.film.color, plain.color);
    });
}

#[test]
fn spare_sweeps_take_only_time_no_other_pass_would_use_and_keep_the_pass_weight() {
    use photongrid::estimate::Accumulation;
    use photongrid::render::progressive::Accumulator;
    use photongrid::render::{render_until, CameraPass, Cut, Spare};
    with_small_pass(2, |pass| {
        let two = pass.settings.clone();
        let hour = Duration::from_secs(3600);
        let cut = |since: Instant| Cut {
            deadline: Some(Instant::now() + hour),
            required: 1,
            spare: Some(Spare { since, max: 3 }),
        };
        // An hour left after a pass that began just now: another pass fits, no spare sweep.
        let planned = render_until(pass, &|_| {}, cut(Instant::now()), None).unwrap();
        assert_eq!(planned.samples, 2);
        // The pass began two hours ago: the hour left is too short for another such pass, so the
        // pass goes on, up to `max` more sweeps.
        let long_ago = Instant::now() - 2 * hour;
        let spared = render_until(pass, &|_| {}, cut(long_ago), None).unwrap();
        assert_eq!(spared.samples, 5);
        assert_eq!(spared.film.nonfinite(), 0);
        assert_ne!(spared.film.color, planned.film.color);
        let (a, b) = (spared.film.mean(), planned.film.mean());
        assert!((a[1] / b[1] - 1.0).abs() < 0.1, "{a:?} vs {b:?}");
        // In the average of passes a pass with spare sweeps weighs what its planned samples do.
        let average = |second: Cut| {
            let mut acc = Accumulator::new(Accumulation::Average, 32, 24, 2);
            assert_eq!(acc.add_pass(pass, &|_| {}, Cut::NONE, 1.0), 2);
            let next = CameraPass {
                settings: &photongrid::render::RenderSettings {
                    first_sample: 2,
                    ..two.clone()
                },
                ..pass
            };
            let added = acc.add_pass(next, &|_| {}, second, 1.0);
            (acc.film(), added)
        };
        let (with_spare, added) = average(cut(long_ago));
        assert_eq!(added, 5);
        let second = render_until(
            CameraPass {
                settings: &photongrid::render::RenderSettings {
                    first_sample: 2,
                    ..two.clone()
                },
                ..pass
            },
            &|_| {},
            cut(long_ago),
            None,
        )
        .unwrap();
        assert_eq!(second.samples, 5);
        for ((got, a), b) in with_spare.color.iter().zip(&planned.film.color).zip(&second.film.color) {
            let want = (*a + *b) * 0.5;
            assert!(
                (*got - want).abs().max_element() <= 1e-5 * want.max_element().max(1.0),
                "{got:?} vs {want:?}"
            );
        }
    });
}

#[test]
fn the_points_that_ask_for_gathering_are_counted_with_or_without_gather_rays() {
    use photongrid::estimate::Estimator;
    use photongrid::render::{render, CameraPass, PhotonData};
    use std::sync::atomic::{AtomicU64, Ordering};
    let (scene, settings, prepared) = prepared_small();
    let surfaces = photongrid::estimate::Surfaces::new(&scene, &prepared.accel, &settings);
    let estimator = Estimator::for_pass(&settings, 0, &prepared.map, prepared.grids.view(), &surfaces);
    assert!(estimator.weighs_gather_rays(), "the default estimate");
    let count = |gather: u32, rays: f32| {
        let rs = render_settings(&settings, 1, gather);
        let n = AtomicU64::new(0);
        let pass = CameraPass {
            scene: &scene,
            accel: &prepared.accel,
            photons: PhotonData {
                estimator: estimator.with_gather_rays(rays),
                irradiance: prepared.irradiance.as_ref(),
            },
            camera: &scene.cameras[0],
            settings: &rs,
            gathering_points: Some(&n),
        };
        drop(render(pass, &|_| {}));
        n.load(Ordering::Relaxed)
    };
    // With no gather rays to weigh, the photons serve wherever their kernels hold enough; with
    // very many, gathering is asked for on every diffuse point: fewer photons per ray, more.
    let (few, many) = (count(0, 0.0), count(0, 1e9));
    assert!(few < many && many >= 32 * 24 / 2, "{few} {many}");
    // Whether the pass gathers does not change what is asked for (up to the paths glass
    // splits differently once gathering has drawn its random numbers).
    let gathered = count(2, 1e9);
    assert!(gathered.abs_diff(many) * 20 <= many, "{gathered} {many}");
}
