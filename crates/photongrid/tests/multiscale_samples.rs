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
