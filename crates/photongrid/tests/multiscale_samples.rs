//! The multiscale estimate on every sample scene at default settings (small sizes): finite
//! pixels, some light, and the same image for the same seed, so that it can serve as the
//! default method.

use photongrid::film::Film;
use photongrid::pipeline::{prepare, render_camera, select_cameras, PhaseTimes};
use photongrid::progress::Progress;
use photongrid::settings::Method;
use photongrid::Settings;

fn render(scene: &photongrid::scene::Scene, settings: &Settings) -> Film {
    let cams = select_cameras(scene, &[]).unwrap_or_else(|e| panic!("{e}"));
    let progress = Progress::quiet();
    let prepared = prepare(scene, settings, &progress, &mut PhaseTimes::default()).unwrap_or_else(|e| panic!("{e}"));
    render_camera(scene, &prepared, cams[0], settings, &progress)
}

#[test]
fn multiscale_renders_every_sample_finite_and_deterministic() {
    let dir = photongrid_testkit::repo_root().join("samples");
    let mut names: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "glb"))
        .collect();
    names.sort();
    assert!(names.len() >= 5, "samples: {names:?}");
    let settings = Settings {
        method: Method::Multiscale,
        photons: 20_000,
        caustic_photons: 10_000,
        width: Some(40),
        height: Some(30),
        spp: 1,
        gather: 2,
        seed: 3,
        ..Settings::default()
    };
    for path in &names {
        let scene = photongrid::load(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        let a = render(&scene, &settings);
        let b = render(&scene, &settings);
        let bad = a.color.iter().filter(|c| !c.is_finite()).count();
        assert_eq!(bad, 0, "{}: {bad} non-finite pixels", path.display());
        let mean: f64 = a.color.iter().map(|c| (c.x + c.y + c.z) as f64).sum::<f64>() / a.color.len() as f64;
        assert!(mean > 0.0, "{}: black image", path.display());
        let differ = a.color.iter().zip(&b.color).filter(|(x, y)| x != y).count();
        assert_eq!(
            differ,
            0,
            "{}: {differ} pixels differ between two renders of seed 3",
            path.display()
        );
    }
}

/// Mean luminance of a film.
fn mean_lum(f: &Film) -> f64 {
    f.color.iter().map(|c| photongrid::luminance(*c) as f64).sum::<f64>() / f.color.len() as f64
}

#[test]
fn aimed_gather_rays_keep_the_light_and_lower_the_noise() {
    // The Cornell box with a point light 20 cm under the ceiling: the ceiling right above it
    // is tens of times brighter than the rest, and cosine-distributed gather rays that happen
    // upon it make specks. Aimed rays (weighted by the balance heuristic) must bring the same
    // light on average and less noise: two seeds' images differ less.
    let scene = photongrid::load(&photongrid_testkit::repo_root().join("samples/cornell_glass.glb")).unwrap();
    let settings = |seed: u64, bright: f32| Settings {
        photons: 100_000,
        caustic_photons: 50_000,
        width: Some(64),
        height: Some(48),
        spp: 4,
        gather: 8,
        gather_bright: bright,
        seed,
        ..Settings::default()
    };
    let rms = |a: &Film, b: &Film| {
        let s: f64 = a
            .color
            .iter()
            .zip(&b.color)
            .map(|(x, y)| (photongrid::luminance(*x - *y) as f64).powi(2))
            .sum();
        (s / a.color.len() as f64).sqrt()
    };
    let (mut spread, mut aimed) = (Vec::new(), Vec::new());
    for seed in [1, 2] {
        spread.push(render(&scene, &settings(seed, 0.0)));
        aimed.push(render(&scene, &settings(seed, 0.5)));
    }
    for (s, a) in spread.iter().zip(&aimed) {
        // Same seed, same photons: the means differ only by the camera pass's noise.
        let ratio = mean_lum(a) / mean_lum(s);
        eprintln!("mean with aimed rays / without: {ratio:.4}");
        assert!((ratio - 1.0).abs() < 0.02, "mean with aimed rays / without: {ratio}");
    }
    let (noise_spread, noise_aimed) = (rms(&spread[0], &spread[1]), rms(&aimed[0], &aimed[1]));
    eprintln!("seed-to-seed RMS difference: {noise_aimed:.5} with aimed rays, {noise_spread:.5} without");
    assert!(
        noise_aimed < 0.92 * noise_spread,
        "seed-to-seed RMS difference: {noise_aimed} with aimed rays, {noise_spread} without"
    );
}

#[test]
fn the_grids_know_when_direct_and_caustic_photons_land_from_stratified_points() {
    // cornell_glass has a point light; cornell_area only an emitting quad, whose photons take
    // four numbers each and get the Poisson widths.
    let settings = Settings {
        photons: 5_000,
        caustic_photons: 5_000,
        width: Some(8),
        height: Some(6),
        gather: 1,
        ..Settings::default()
    };
    for (name, stratified) in [("cornell_glass.glb", true), ("cornell_area.glb", false)] {
        let scene = photongrid::load(&photongrid_testkit::repo_root().join("samples").join(name)).unwrap();
        let prepared = prepare(&scene, &settings, &Progress::quiet(), &mut PhaseTimes::default()).unwrap();
        let grids = prepared.grids.multiscale.as_ref().expect("multiscale grids");
        assert_eq!(grids.stratified, stratified, "{name}");
    }
}
