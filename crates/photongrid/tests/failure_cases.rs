//! Where the photon estimates fail: small synthetic scenes with a closed-form answer, rendered
//! in single-map mode (`direct = photons`, so the photon estimate is the whole image) and
//! compared with the direct light the photon map must reproduce. Each case is measured for
//! kNN (k = 100, k = 500), the paper's adaptive radius (k = 100) and the multiscale estimate (the
//! default) over 48 seeds (12 for the caustic case); the bias
//! (mean over seeds − truth) and the spread across seeds are printed as a table (`--nocapture`)
//! and checked against thresholds set from the measured values with a margin, so that a
//! regression fails with a message saying which case, method and quantity moved.
//!
//! `PHOTONGRID_WRITE_DOCS=1 cargo test --release --test failure_cases -- --nocapture` also
//! writes the table to `docs/failure_cases.md`.

use glam::Quat;
use photongrid::scene::Scene;
use photongrid::settings::DirectLighting;
use photongrid::Settings;
use photongrid_testkit::harness::*;
use photongrid_testkit::*;
use std::f64::consts::PI;
use std::time::Instant;

const ALBEDO: f64 = 0.5;
/// Seeds 1 to 48: the per-seed spread of a 2 cm band at a corner is about 4 %, so a bias is
/// known to ±0.5 % (one standard error) and a ±2 % bound can be judged; 12 seeds (±1.1 %) put
/// the corner at +3.1 % where 120 give +0.9 % ± 0.4 %.
const SEEDS: [u64; 48] = {
    let mut s = [0; 48];
    let mut i = 0;
    while i < 48 {
        s[i] = i as u64 + 1;
        i += 1;
    }
    s
};
/// The caustic case, the slowest (a 32 k-facet sphere, 400 k photons), takes the first 12.
const CAUSTIC_SEEDS: usize = 12;
const UP: [f64; 3] = [0.0, 1.0, 0.0];

/// Single-map settings: every photon stored at its first diffuse hit and nothing after it
/// (`max_photon_depth = 1`), so the photon map holds exactly the direct light.
fn base(photons: usize, view: &TopView) -> Settings {
    Settings {
        photons,
        neighbours: 100,
        spp: 4,
        width: Some(view.w),
        height: Some(view.h),
        direct: DirectLighting::Photons,
        max_photon_depth: 1,
        caustic_photons: 0,
        // The paper's setting: the photon map shown directly, plane grids only.
        gather: 0,
        grid: photongrid::settings::GridMode::Planes,
        ..Settings::default()
    }
}

fn build(tag: &str, g: &Gltf) -> (TempDir, Scene) {
    let dir = TempDir::new(tag);
    let path = g.write_glb(dir.path(), &format!("{tag}.glb"));
    let scene = load(&path);
    (dir, scene)
}

/// Detected planes and whether the triangles of a material are on one.
fn plane_summary(scene: &Scene) -> String {
    let set = photongrid::grid::PlaneGrids::detect(&scene.triangles, 128);
    let dims: Vec<String> = set
        .planes
        .iter()
        .map(|p| {
            format!(
                "{:.2}×{:.2} m, {}×{} cells of {:.1} mm",
                p.size_u,
                p.size_v,
                p.res_u,
                p.res_v,
                1000.0 * (p.size_u / p.res_u as f32)
            )
        })
        .collect();
    format!("{} plane(s): {}", set.planes.len(), dims.join("; "))
}

// ---------------------------------------------------------------------------------------------
// 1. Shadow edge under a box.

/// A point light 0.8 m above the floor at the origin and a black box (x 0.2–0.4 m, 0.4 m
/// tall, long along z): the shadow of the box's top edge is the line x = 0.8 m, a step with
/// no penumbra. Across the edge: the 10–90 % width of the profile (radiance / unshadowed
/// radiance, averaged along z) against the same width of the exact pixel means (one pixel,
/// from pixel integration alone), the light leaked into the shadow and the darkening of the
/// lit side in 10 cm bands, and the error far from the edge.
fn shadow_edge(report: &mut Report) {
    let case = "shadow edge";
    let (light, cd) = ([0.0, 0.8, 0.0], 2000.0);
    let (bx0, bx1, bh) = (0.2, 0.4, 0.4);
    let x_edge = light[0] + (bx1 - light[0]) * light[1] / (light[1] - bh);
    let view = TopView {
        cx: 0.95,
        cz: 0.0,
        ymag: 0.375,
        height: 2.0,
        w: 64,
        h: 48,
    };
    let mut g = Gltf::new();
    let white = g.material(Material::lambert(ALBEDO as f32));
    let black = g.material(Material::lambert(0.0));
    add_object(&mut g, "Floor", rect_up(-1.0, 2.5, -1.5, 1.5, 0.0), white);
    add_object(
        &mut g,
        "Box",
        box_prim([bx0 as f32, 0.0, -3.0], [bx1 as f32, bh as f32, 3.0]),
        black,
    );
    add_point_light(&mut g, light.map(|v| v as f32), cd as f32);
    view.add_camera(&mut g);
    let (_dir, scene) = build("shadow_edge", &g);
    view.check_camera(&scene);

    let unshadowed = |x: f64, z: f64| point_radiance(ALBEDO, cd, light, [x, 0.0, z], UP);
    let lit = |x: f64, z: f64| if x > x_edge { unshadowed(x, z) } else { 0.0 };
    let truth = view.truth(&lit);
    let unsh = view.truth(&unshadowed);
    let photons = 400_000;
    let films = render_methods(&scene, &base(photons, &view), &SEEDS, &METHODS);

    // Profile along x: Σ over rows of the image / Σ over rows of the unshadowed radiance.
    let w = view.w as usize;
    let profile = |img: &dyn Fn(usize) -> f64| -> Vec<f64> {
        (0..w)
            .map(|px| {
                let (mut a, mut b) = (0.0, 0.0);
                for py in 0..view.h as usize {
                    a += img(py * w + px);
                    b += unsh[py * w + px];
                }
                a / b
            })
            .collect()
    };
    let xs: Vec<f64> = (0..view.w).map(|px| view.center(px, 0).0).collect();
    let width = |ratio: &[f64]| -> f64 {
        let Some(i10) = (0..w).rev().find(|&j| ratio[j] < 0.1 && xs[j] < x_edge + 0.1) else {
            return f64::NAN;
        };
        if i10 + 1 >= w {
            return f64::NAN;
        }
        let x10 = xs[i10] + (0.1 - ratio[i10]) / (ratio[i10 + 1] - ratio[i10]) * (xs[i10 + 1] - xs[i10]);
        let Some(i90) = (i10 + 1..w).find(|&j| ratio[j] >= 0.9) else {
            return f64::NAN;
        };
        let x90 = xs[i90 - 1] + (0.9 - ratio[i90 - 1]) / (ratio[i90] - ratio[i90 - 1]) * (xs[i90] - xs[i90 - 1]);
        x90 - x10
    };
    let truth_width = width(&profile(&|i| truth[i]));
    let band = |a: f64, b: f64| view.select(&|x, _| x >= x_edge + a && x < x_edge + b);
    let (shadow_near, lit_near, lit_far) = (band(-0.1, 0.0), band(0.0, 0.1), band(0.2, 0.5));
    report.note(
        case,
        format!(
            "Point light {cd} cd at (0, 0.8, 0), black box x {bx0}–{bx1} m, {bh} m tall: shadow edge at \
             x = {x_edge:.2} m. {photons} photons, {}×{} px of {:.2} cm, {} spp, max photon depth 1. \
             Width: 10–90 % rise of (radiance / unshadowed radiance) along x, averaged along z; its \
             truth is the pixel means' own width (pixel integration only). Leak: shadow-band \
             radiance / unshadowed radiance. {}.",
            view.w,
            view.h,
            100.0 * view.pixel_size(),
            base(0, &view).spp,
            plane_summary(&scene)
        ),
    );
    for (m, spec) in METHODS.iter().enumerate() {
        let f = &films[m];
        let widths: Vec<f64> = f.iter().map(|film| width(&profile(&|i| grey(film, i)))).collect();
        let widths: Vec<f64> = widths.iter().map(|w| w * 100.0).collect();
        report.add(case, "10–90 % width", spec.name, truth_width * 100.0, &widths, "cm");
        let leak: Vec<f64> = f
            .iter()
            .map(|film| sum_over(film, &shadow_near) / sum_truth(&unsh, &shadow_near))
            .collect();
        report.add(case, "shadow band 0–10 cm: leak", spec.name, 0.0, &leak, "%");
        if std::env::var("PG_PROFILE").is_ok() {
            let mean = |px: usize| -> f64 {
                let mut a = 0.0;
                for film in f.iter() {
                    for py in 0..view.h as usize {
                        a += grey(film, py * w + px);
                    }
                }
                let b: f64 = (0..view.h as usize).map(|py| truth[py * w + px]).sum();
                a / f.len() as f64 / b
            };
            let cols: Vec<String> = (0..w)
                .filter(|&px| xs[px] > x_edge - 0.03 && xs[px] < x_edge + 0.15)
                .map(|px| format!("{:.1}:{:.3}", (xs[px] - x_edge) * 100.0, mean(px)))
                .collect();
            eprintln!("PROFILE {} {}", spec.name, cols.join(" "));
        }
        report.add_rel_error(case, "lit band 0–10 cm: rel. error", spec.name, f, &truth, &lit_near);
        report.add_rel_error(case, "lit band 20–50 cm: rel. error", spec.name, f, &truth, &lit_far);
    }
}

// ---------------------------------------------------------------------------------------------
// 2. Inside corner.

/// A floor (x ≥ 0) meeting a wall (x = 0, facing +x), point light at (0.5, 0.8, 0): the floor's
/// radiance approaching the wall against the closed form, in bands of distance from the wall.
/// The wall's photons face another way and are not gathered, so the estimate sees half a disc
/// at the wall: kNN darkens there (boundary bias); nothing should leak.
fn corner(report: &mut Report) {
    let case = "corner";
    let (light, cd) = ([0.5, 0.8, 0.0], 2000.0);
    let view = TopView {
        cx: 0.25,
        cz: 0.0,
        ymag: 0.1875,
        height: 2.0,
        w: 64,
        h: 48,
    };
    let mut g = Gltf::new();
    let white = g.material(Material::lambert(ALBEDO as f32));
    add_object(&mut g, "Floor", rect_up(0.0, 2.0, -1.0, 1.0, 0.0), white);
    add_object(&mut g, "Wall", rect_px(0.0, 0.0, 1.5, -1.0, 1.0), white);
    add_point_light(&mut g, light.map(|v| v as f32), cd as f32);
    view.add_camera(&mut g);
    let (_dir, scene) = build("corner", &g);
    view.check_camera(&scene);
    let truth = view.truth(&|x, z| point_radiance(ALBEDO, cd, light, [x, 0.0, z], UP));
    let photons = 400_000;
    let films = render_methods(&scene, &base(photons, &view), &SEEDS, &METHODS);
    report.note(
        case,
        format!(
            "Floor x ∈ [0, 2] m meeting a wall at x = 0, point light {cd} cd at (0.5, 0.8, 0), \
             {photons} photons, {}×{} px of {:.2} cm, max photon depth 1 (no wall→floor bounce, \
             so the truth is the direct light). Bands by distance from the wall. {}.",
            view.w,
            view.h,
            100.0 * view.pixel_size(),
            plane_summary(&scene)
        ),
    );
    let bands = [(0.0, 0.02), (0.02, 0.06), (0.06, 0.15), (0.25, 0.5)];
    for (m, spec) in METHODS.iter().enumerate() {
        let f = &films[m];
        for &(a, z) in bands.iter() {
            let px = view.select(&|x, _| x >= a && x < z);
            let metric = format!("{:.0}–{:.0} cm from wall: rel. error", 100.0 * a, 100.0 * z);
            report.add_rel_error(case, &metric, spec.name, f, &truth, &px);
        }
    }
}

/// A step: a tread 20 cm up (the top of a block, x ≥ 0) ending at its nose (x = 0) above a
/// lower floor, point light at (0.3, 1.0, 0): the tread's radiance approaching the nose against
/// the closed form, in bands of distance from the nose. The tread's plane ends at the nose, so
/// a gather disc there lies half over nothing: kNN darkens the nose (divided by the whole
/// disc), an estimate that knows the tread's area does not.
fn step_nose(report: &mut Report) {
    let case = "step nose";
    let (light, cd, rise) = ([0.3, 1.0, 0.0], 2000.0, 0.2);
    let view = TopView {
        cx: 0.15,
        cz: 0.0,
        ymag: 0.1875,
        height: 2.0,
        w: 64,
        h: 48,
    };
    let mut g = Gltf::new();
    let white = g.material(Material::lambert(ALBEDO as f32));
    add_object(&mut g, "Floor", rect_up(-1.0, 0.0, -1.0, 1.0, 0.0), white);
    add_object(
        &mut g,
        "Step",
        box_prim([0.0, 0.0, -1.0], [2.0, rise as f32, 1.0]),
        white,
    );
    add_point_light(&mut g, light.map(|v| v as f32), cd as f32);
    view.add_camera(&mut g);
    let (_dir, scene) = build("step_nose", &g);
    view.check_camera(&scene);
    // The lower floor (x < 0) is not scored: only its truth's shape matters for the film.
    let floor_lit = |x: f64| x < light[0] + (0.0 - light[0]) * light[1] / (light[1] - rise);
    let truth = view.truth(&|x, z| {
        if x >= 0.0 {
            point_radiance(ALBEDO, cd, light, [x, rise, z], UP)
        } else if floor_lit(x) {
            point_radiance(ALBEDO, cd, light, [x, 0.0, z], UP)
        } else {
            0.0
        }
    });
    let photons = 400_000;
    let films = render_methods(&scene, &base(photons, &view), &SEEDS, &METHODS);
    report.note(
        case,
        format!(
            "Tread x ∈ [0, 2] m, {rise} m above a lower floor, ending at its nose x = 0; point \
             light {cd} cd at (0.3, 1.0, 0), {photons} photons, {}×{} px of {:.2} cm, max photon \
             depth 1 (the truth is the direct light). Bands on the tread by distance from the \
             nose. {}.",
            view.w,
            view.h,
            100.0 * view.pixel_size(),
            plane_summary(&scene)
        ),
    );
    let bands = [(0.0, 0.02), (0.02, 0.06), (0.06, 0.15), (0.25, 0.4)];
    for (m, spec) in METHODS.iter().enumerate() {
        let f = &films[m];
        for &(a, z) in bands.iter() {
            let px = view.select(&|x, _| x >= a && x < z);
            let metric = format!("{:.0}–{:.0} cm from nose: rel. error", 100.0 * a, 100.0 * z);
            report.add_rel_error(case, &metric, spec.name, f, &truth, &px);
        }
    }
}

// ---------------------------------------------------------------------------------------------
// 3. A plane smaller than a grid cell.

/// A 1.5 cm square quad floating 5 cm above a 2.56 m floor (grid cells of 2 cm), point light
/// 0.6 m above the floor: the quad catches only ~16 photons, so a k = 100 (or 500) gather is
/// mostly floor photons 5 cm below (same normal, accepted): the quad's mean radiance against
/// the closed form. The quad is far below the plane detector's minimum area, so the adaptive
/// method falls back to kNN there.
fn tiny_plane(report: &mut Report) {
    let case = "tiny plane";
    let (light, cd) = ([0.0, 0.6, 0.0], 2000.0);
    let (qx, qh, half) = (0.3, 0.05, 0.0075);
    let view = TopView {
        cx: qx,
        cz: 0.0,
        ymag: 0.015,
        height: 0.3,
        w: 64,
        h: 48,
    };
    let mut g = Gltf::new();
    let white = g.material(Material::lambert(ALBEDO as f32));
    add_object(&mut g, "Floor", rect_up(-1.28, 1.28, -1.28, 1.28, 0.0), white);
    add_object(
        &mut g,
        "Tiny",
        rect_up(
            (qx - half) as f32,
            (qx + half) as f32,
            -half as f32,
            half as f32,
            qh as f32,
        ),
        white,
    );
    add_point_light(&mut g, light.map(|v| v as f32), cd as f32);
    view.add_camera(&mut g);
    let (_dir, scene) = build("tiny_plane", &g);
    view.check_camera(&scene);
    let truth = view.truth(&|x, z| point_radiance(ALBEDO, cd, light, [x, qh, z], UP));
    let hp = 0.5 * view.pixel_size();
    let on_quad = view.select(&|x, z| (x - qx).abs() + hp <= half && z.abs() + hp <= half);
    let photons = 400_000;
    // Photons expected on the quad: N · (cos θ / d²) · area / 4π.
    let d2 = qx * qx + (light[1] - qh).powi(2);
    let expected = photons as f64 * ((light[1] - qh) / d2.sqrt() / d2) * (2.0 * half).powi(2) / (4.0 * PI);
    let set = photongrid::grid::PlaneGrids::detect(&scene.triangles, 128);
    let tiny_is_plane = scene
        .triangles
        .iter()
        .enumerate()
        .any(|(i, t)| t.p[0].y > 0.01 && set.plane_of_triangle[i] != photongrid::grid::planes::NO_PLANE);
    assert!(
        !tiny_is_plane,
        "the 1.5 cm quad became a plane: the case no longer tests the fallback"
    );
    let films = render_methods(&scene, &base(photons, &view), &SEEDS, &METHODS);
    report.note(
        case,
        format!(
            "A {:.1} cm square quad {:.0} cm above a 2.56 m floor (floor cells {:.1} cm), point light \
             {cd} cd 0.6 m above the floor; {photons} photons, about {expected:.0} of them on the quad. \
             The quad is not a detected plane ({}), so adaptive = kNN there. Metric: mean radiance over \
             the {} pixels fully on the quad.",
            200.0 * half,
            100.0 * qh,
            100.0 * 2.56 / 128.0,
            plane_summary(&scene),
            on_quad.len()
        ),
    );
    for (m, spec) in METHODS.iter().enumerate() {
        let f = &films[m];
        report.add_rel_error(case, "quad mean radiance: rel. error", spec.name, f, &truth, &on_quad);
    }
    // Adaptive falls back to kNN on the quad: identical pixels there.
    for s in 0..SEEDS.len() {
        let same = on_quad.iter().all(|&i| films[0][s].color[i] == films[2][s].color[i]);
        if !same {
            report.fail(format!(
                "tiny plane: adaptive differs from kNN on the quad (seed {})",
                SEEDS[s]
            ));
        }
    }
}

// ---------------------------------------------------------------------------------------------
// 4. Grazing sun.

/// A 2 m plane under a sun 80° from the normal: uniform irradiance E = (lux/683)·cos 80°;
/// the photons arrive at grazing incidence and only ~11 % of the sun's disc hits the plane.
fn grazing_sun(report: &mut Report) {
    let case = "grazing sun";
    let lux = 50_000.0;
    let angle = 80f64.to_radians();
    let view = TopView {
        cx: 0.0,
        cz: 0.0,
        ymag: 0.375,
        height: 2.0,
        w: 64,
        h: 48,
    };
    let mut g = Gltf::new();
    let white = g.material(Material::lambert(ALBEDO as f32));
    add_object(&mut g, "Plane", rect_up(-1.0, 1.0, -1.0, 1.0, 0.0), white);
    let q = Quat::from_rotation_z(angle as f32) * Quat::from_array(look_down());
    let l = g.light(Light::directional(lux as f32));
    g.root(Node {
        name: Some("Sun".into()),
        transform: Transform::tr([0.0, 3.0, 0.0], q.to_array()),
        light: Some(l),
        ..Default::default()
    });
    view.add_camera(&mut g);
    let (_dir, scene) = build("grazing", &g);
    view.check_camera(&scene);
    let e = lux / 683.0 * angle.cos();
    let truth = view.truth(&|_, _| ALBEDO / PI * e);
    let all = view.select(&|_, _| true);
    let photons = 400_000;
    let films = render_methods(&scene, &base(photons, &view), &SEEDS, &METHODS);
    report.note(
        case,
        format!(
            "2 m plane, sun {lux} lx at 80° from the normal (E = {e:.2} W/m²), {photons} photons of which \
             about 11 % hit the plane; region: the central 1 × 0.75 m. {}.",
            plane_summary(&scene)
        ),
    );
    for (m, spec) in METHODS.iter().enumerate() {
        let f = &films[m];
        let r = report.add_rel_error(case, "region mean: rel. error", spec.name, f, &truth, &all);
        let noise = r.pixel.unwrap().1;
        if noise > [0.15, 0.08, 0.15, 0.15][m] {
            report.fail(format!(
                "grazing sun: {} pixel noise {:.1} % too high",
                spec.name,
                100.0 * noise
            ));
        }
    }
}

// ---------------------------------------------------------------------------------------------
// 5. A bright small caustic.

/// Unpolarised Fresnel reflectance (as the renderer's).
fn fresnel(cos_i: f64, eta: f64) -> f64 {
    let s2 = eta * eta * (1.0 - cos_i * cos_i);
    if s2 >= 1.0 {
        return 1.0;
    }
    let ct = (1.0 - s2).sqrt();
    let rs = (eta * cos_i - ct) / (eta * cos_i + ct);
    let rp = (cos_i - eta * ct) / (cos_i + eta * ct);
    0.5 * (rs * rs + rp * rp)
}

/// Power [W] landing on the floor (y = 0) within `radii` of the axis, for a point light of
/// `watts_per_sr` at height `hc + dist` above a glass sphere (radius `r`, IOR `ior`, centre
/// height `hc`): rays in one meridional plane traced through the exact sphere (refraction in,
/// then up to two internal reflections, Fresnel-weighted), integrated over the cone the sphere
/// subtends with weight 2π sin θ dθ.
fn caustic_power(watts_per_sr: f64, r: f64, hc: f64, dist: f64, ior: f64, radii: &[f64]) -> Vec<f64> {
    let n = 200_000;
    let tmax = (r / dist).asin();
    let mut out = vec![0.0; radii.len()];
    let (lx, ly) = (0.0f64, hc + dist);
    for i in 0..n {
        let th = (i as f64 + 0.5) / n as f64 * tmax;
        let dw = 2.0 * PI * th.sin() * tmax / n as f64;
        let mut d = (th.sin(), -th.cos());
        // Entry.
        let (ox, oy) = (lx, ly - hc);
        let b = ox * d.0 + oy * d.1;
        let c = ox * ox + oy * oy - r * r;
        if b * b - c < 0.0 {
            continue;
        }
        let t = -b - (b * b - c).sqrt();
        let mut p = (lx + t * d.0, ly + t * d.1);
        let nn = (p.0 / r, (p.1 - hc) / r);
        let ci = -(d.0 * nn.0 + d.1 * nn.1);
        let eta = 1.0 / ior;
        let mut w = 1.0 - fresnel(ci, eta);
        let ct = (1.0 - eta * eta * (1.0 - ci * ci)).sqrt();
        d = (eta * d.0 + (eta * ci - ct) * nn.0, eta * d.1 + (eta * ci - ct) * nn.1);
        for _bounce in 0..3 {
            let (ox, oy) = (p.0, p.1 - hc);
            let b = ox * d.0 + oy * d.1;
            let c = ox * ox + oy * oy - r * r;
            let t = -b + (b * b - c).max(0.0).sqrt();
            p = (p.0 + t * d.0, p.1 + t * d.1);
            let no = (p.0 / r, (p.1 - hc) / r);
            let ci = d.0 * no.0 + d.1 * no.1;
            let f = fresnel(ci, ior);
            if f < 1.0 {
                let ct = (1.0 - ior * ior * (1.0 - ci * ci)).sqrt();
                let dt = (ior * d.0 - (ior * ci - ct) * no.0, ior * d.1 - (ior * ci - ct) * no.1);
                if dt.1 < 0.0 {
                    let x = (p.0 + dt.0 * (-p.1 / dt.1)).abs();
                    for (k, &rad) in radii.iter().enumerate() {
                        if x <= rad {
                            out[k] += watts_per_sr * w * (1.0 - f) * dw;
                        }
                    }
                }
            }
            d = (d.0 - 2.0 * ci * no.0, d.1 - 2.0 * ci * no.1);
            w *= f;
        }
    }
    out
}

/// A glass sphere (r = 0.2 m, IOR 1.5, 128 × 256 facets) 0.08 m above a small floor that lies
/// entirely in its shadow, point light 1 m above the sphere's centre: the floor receives only
/// the caustic (a bright spot of ~3 cm). The power the estimate puts inside discs of 2 cm and
/// 8 cm around the focus (π/albedo · ∫ L dA) against the power the exact sphere sends there.
/// The camera sits below the sphere (orthographic rays start at its height), so it sees the
/// floor directly.
fn caustic(report: &mut Report) {
    let case = "caustic";
    let (r, hc, dist, ior, cd): (f64, f64, f64, f64, f64) = (0.2, 0.28, 1.0, 1.5, 1000.0);
    let half = 0.18;
    let view = TopView {
        cx: 0.0,
        cz: 0.0,
        ymag: 0.09,
        height: 0.04,
        w: 64,
        h: 48,
    };
    let umbra = (hc + dist) * (r / dist).asin().tan();
    assert!(half * 2f64.sqrt() < umbra, "the floor must lie in the sphere's shadow");
    let mut g = Gltf::new();
    let white = g.material(Material::lambert(ALBEDO as f32));
    let glass = g.material(Material::glass(Some(ior as f32)));
    add_object(
        &mut g,
        "Floor",
        rect_up(-half as f32, half as f32, -half as f32, half as f32, 0.0),
        white,
    );
    add_object(
        &mut g,
        "Ball",
        uv_sphere([0.0, hc as f32, 0.0], r as f32, 128, 256),
        glass,
    );
    add_point_light(&mut g, [0.0, (hc + dist) as f32, 0.0], cd as f32);
    view.add_camera(&mut g);
    let (_dir, scene) = build("caustic", &g);
    view.check_camera(&scene);
    let radii = [0.02, 0.08];
    let exact = caustic_power(cd / 683.0, r, hc, dist, ior, &radii);
    let through = caustic_power(cd / 683.0, r, hc, dist, ior, &[10.0])[0];
    let settings = Settings {
        photons: 100_000,
        caustic_photons: 300_000,
        max_photon_depth: 4,
        ..base(0, &view)
    };
    // The photons themselves (no density estimate): how much of the estimate's error is the
    // photon pass's.
    let mut photon_power: Vec<f64> = Vec::new();
    let films = render_methods_with(
        &scene,
        &settings,
        &SEEDS[..CAUSTIC_SEEDS],
        &METHODS,
        &mut |_, prepared| {
            let within: f64 = prepared
                .map
                .photons()
                .iter()
                .filter(|p| (p.pos().x as f64).hypot(p.pos().z as f64) <= radii[1])
                .map(|p| p.power().x as f64)
                .sum();
            photon_power.push(within / exact[1] - 1.0);
        },
    );
    let row = report.add(
        case,
        "photons within 8 cm: rel. error",
        "(photon pass)",
        0.0,
        &photon_power,
        "%",
    );
    report.check_bias(&row, -0.02, 0.02, "caustic: photon power within 8 cm of the axis");
    report.note(
        case,
        format!(
            "Glass sphere r = {r} m (IOR {ior}, 128 × 256 facets) with its bottom {:.0} cm above a \
             {:.0} cm floor lying in its shadow (umbra radius {:.0} cm), point light {cd} cd 1 m above \
             its centre. 100 000 global + 300 000 caustic photons, max depth 4 (no floor → sphere → \
             floor bounce). Exact: {:.4} W through the sphere to the floor, {:.4} W within 2 cm and \
             {:.4} W within 8 cm of the axis (exact sphere, Fresnel at both surfaces, up to two \
             internal reflections). Estimate: π/albedo · Σ L · pixel area · disc coverage.",
            100.0 * (hc - r),
            200.0 * half,
            100.0 * umbra,
            through,
            exact[0],
            exact[1]
        ),
    );
    let area = view.pixel_size().powi(2);
    for (m, spec) in METHODS.iter().enumerate() {
        for (k, &rad) in radii.iter().enumerate() {
            let cover = view.truth(&|x, z| if x * x + z * z <= rad * rad { 1.0 } else { 0.0 });
            let px = view.select(&|x, z| x.hypot(z) <= rad + view.pixel_size());
            let vals: Vec<f64> = films[m]
                .iter()
                .map(|f| {
                    let phi: f64 = px.iter().map(|&i| grey(f, i) * cover[i] * area).sum::<f64>() * PI / ALBEDO;
                    phi / exact[k] - 1.0
                })
                .collect();
            let metric = format!("power within {:.0} cm: rel. error", 100.0 * rad);
            report.add(case, &metric, spec.name, 0.0, &vals, "%");
        }
    }
}

// ---------------------------------------------------------------------------------------------
// 6. A region no light reaches.

/// A floor split by a black wall (x 0–2 cm, 1 m tall) with a point light 0.6 m high on the −x
/// side: the +x side gets no photon at all. Its radiance must be exactly 0 beyond the largest
/// gather radius from the wall; closer, the gather reaches through the wall to the lit floor's
/// photons (same plane orientation, accepted) and leaks light: how much and how far.
fn empty_region(report: &mut Report) {
    let case = "empty region";
    let (light, cd) = ([-0.5, 0.6, 0.0], 2000.0);
    let wall = 0.02;
    let view = TopView {
        cx: 0.15,
        cz: 0.0,
        ymag: 0.375,
        height: 2.0,
        w: 64,
        h: 48,
    };
    let mut g = Gltf::new();
    let white = g.material(Material::lambert(ALBEDO as f32));
    let black = g.material(Material::lambert(0.0));
    add_object(&mut g, "Floor", rect_up(-1.0, 1.5, -1.0, 1.0, 0.0), white);
    add_object(
        &mut g,
        "Wall",
        box_prim([0.0, 0.0, -1.5], [wall as f32, 1.0, 1.5]),
        black,
    );
    add_point_light(&mut g, light.map(|v| v as f32), cd as f32);
    view.add_camera(&mut g);
    let (_dir, scene) = build("empty", &g);
    view.check_camera(&scene);
    let max_radius = 0.05 * scene.bounds.diagonal() as f64;
    let unshadowed = |x: f64, z: f64| point_radiance(ALBEDO, cd, light, [x, 0.0, z], UP);
    let truth = view.truth(&|x, z| if x < 0.0 { unshadowed(x, z) } else { 0.0 });
    let photons = 400_000;
    let films = render_methods(&scene, &base(photons, &view), &SEEDS, &METHODS);
    let lit_band = view.select(&|x, _| (-0.05..0.0).contains(&x));
    let lit_ref = sum_truth(&truth, &lit_band) / lit_band.len() as f64;
    let dark = |a: f64, b: f64| view.select(&|x, _| x >= wall + a && x < wall + b);
    let hp = 0.5 * view.pixel_size();
    let far = view.select(&|x, _| x - hp > wall + max_radius);
    report.note(
        case,
        format!(
            "Floor with a black wall (x 0–{:.0} cm, 1 m tall), point light {cd} cd at (−0.5, 0.6, 0): no \
             photon reaches x > {:.0} cm. Largest gather radius {:.1} cm (5 % of the scene diagonal). Leak: \
             mean radiance in a band on the dark side / mean radiance of the lit 5 cm next to the wall. \
             Reach: farthest dark pixel with any light. The {} dark pixels farther than the largest \
             gather radius must be exactly 0 (checked).",
            100.0 * wall,
            100.0 * wall,
            100.0 * max_radius,
            far.len()
        ),
    );
    assert!(far.len() > 500, "{}", far.len());
    for (m, spec) in METHODS.iter().enumerate() {
        let f = &films[m];
        for (a, b) in [(0.0, 0.05), (0.05, 0.15)] {
            let px = dark(a, b);
            let leak: Vec<f64> = f
                .iter()
                .map(|film| sum_over(film, &px) / px.len() as f64 / lit_ref)
                .collect();
            let metric = format!("dark {:.0}–{:.0} cm: leak / lit", 100.0 * a, 100.0 * b);
            report.add(case, &metric, spec.name, 0.0, &leak, "%");
        }
        let reach: Vec<f64> = f
            .iter()
            .map(|film| {
                view.select(&|x, _| x > wall)
                    .into_iter()
                    .filter(|&i| grey(film, i) > 0.0)
                    .map(|i| view.center(i as u32 % view.w, i as u32 / view.w).0 - wall + hp)
                    .fold(0.0, f64::max)
                    * 100.0
            })
            .collect();
        report.add(case, "leak reach", spec.name, 0.0, &reach, "cm");
        report.add(
            case,
            "lit 0–5 cm at wall: rel. error",
            spec.name,
            0.0,
            &rel_errors(f, &truth, &lit_band),
            "%",
        );
        for (s, film) in f.iter().enumerate() {
            let worst = far.iter().map(|&i| grey(film, i)).fold(0.0, f64::max);
            if worst != 0.0 {
                report.fail(format!(
                    "empty region: {} seed {}: radiance {worst} beyond the largest gather radius, must be exactly 0",
                    spec.name, SEEDS[s]
                ));
            }
        }
    }
}

// ---------------------------------------------------------------------------------------------

/// The bands beside an edge whose bias the default estimate must keep within
/// [`EDGE_BAND_BIAS`] (issue 13: "edge, corner and step-nose bias within ±2 %").
const EDGE_BANDS: [(&str, &str); 3] = [
    ("shadow edge", "lit band 0–10 cm: rel. error"),
    ("corner", "0–2 cm from wall: rel. error"),
    ("step nose", "0–2 cm from nose: rel. error"),
];
const EDGE_BAND_BIAS: f64 = 0.02;

/// Biases measured when the thresholds were set (release build, the seeds of [`SEEDS`]), per case and
/// metric, for knn k=100, knn k=500, adaptive k=100 and multiscale (METHODS order), in the metric's unit
/// (fractions for "%", cm for widths and reach). A bias may grow to 1.5 × this plus a floor of
/// 2 % (1 cm), at least 3 standard errors; see `Report::check_measured`. Re-measure with
/// `PHOTONGRID_PRINT_BASELINE=1 cargo test --release --test failure_cases -- --nocapture`.
const BASELINE: &[(&str, &str, [f64; 4])] = &[
    ("shadow edge", "10–90 % width", [9.2630, 20.1557, 9.0969, 0.0175]),
    (
        "shadow edge",
        "shadow band 0–10 cm: leak",
        [0.1841, 0.2677, 0.1841, 0.0000],
    ),
    (
        "shadow edge",
        "lit band 0–10 cm: rel. error",
        [-0.0862, -0.2486, -0.0784, -0.0051],
    ),
    (
        "shadow edge",
        "lit band 20–50 cm: rel. error",
        [0.0030, 0.0069, 0.0031, 0.0057],
    ),
    (
        "corner",
        "0–2 cm from wall: rel. error",
        [-0.2920, -0.3900, -0.2725, 0.0035],
    ),
    (
        "corner",
        "2–6 cm from wall: rel. error",
        [-0.0120, -0.1542, -0.0098, 0.0021],
    ),
    (
        "corner",
        "6–15 cm from wall: rel. error",
        [0.0021, -0.0022, 0.0024, 0.0028],
    ),
    (
        "corner",
        "25–50 cm from wall: rel. error",
        [-0.0006, -0.0035, -0.0001, -0.0016],
    ),
    (
        "step nose",
        "0–2 cm from nose: rel. error",
        [-0.3196, -0.4097, -0.2915, 0.0043],
    ),
    (
        "step nose",
        "2–6 cm from nose: rel. error",
        [-0.0194, -0.1714, -0.0150, -0.0004],
    ),
    (
        "step nose",
        "6–15 cm from nose: rel. error",
        [-0.0048, -0.0073, -0.0041, -0.0003],
    ),
    (
        "step nose",
        "25–40 cm from nose: rel. error",
        [0.0028, -0.0008, 0.0035, 0.0006],
    ),
    (
        "tiny plane",
        "quad mean radiance: rel. error",
        [-0.8488, -0.5562, -0.8488, -0.1188],
    ),
    (
        "grazing sun",
        "region mean: rel. error",
        [-0.0020, -0.0018, -0.0020, -0.0027],
    ),
    (
        "caustic",
        "power within 2 cm: rel. error",
        [0.0392, 0.0365, 0.0184, 0.0191],
    ),
    (
        "caustic",
        "power within 8 cm: rel. error",
        [0.0466, 0.0783, 0.0087, 0.0082],
    ),
    (
        "empty region",
        "dark 0–5 cm: leak / lit",
        [0.1384, 0.2333, 0.1384, 0.0000],
    ),
    (
        "empty region",
        "dark 5–15 cm: leak / lit",
        [0.0177, 0.0204, 0.0177, 0.0000],
    ),
    ("empty region", "leak reach", [9.8750, 9.8750, 9.8750, 0.0000]),
    (
        "empty region",
        "lit 0–5 cm at wall: rel. error",
        [-0.0755, -0.2164, -0.0615, -0.0013],
    ),
];

#[test]
fn failure_cases() {
    let start = Instant::now();
    let mut report = Report::default();
    type Case = (&'static str, fn(&mut Report));
    let cases: [Case; 7] = [
        ("shadow edge", shadow_edge),
        ("corner", corner),
        ("step nose", step_nose),
        ("tiny plane", tiny_plane),
        ("grazing sun", grazing_sun),
        ("caustic", caustic),
        ("empty region", empty_region),
    ];
    for (name, run) in cases {
        let t = Instant::now();
        run(&mut report);
        eprintln!("{name}: {:.1} s", t.elapsed().as_secs_f64());
    }
    let seconds = start.elapsed().as_secs_f64();
    eprintln!("\n{}", report.text());
    eprintln!("total {seconds:.1} s");
    if std::env::var("PHOTONGRID_PRINT_BASELINE").is_ok_and(|v| v == "1") {
        eprintln!("BASELINE:\n{}", report.baseline_source());
    }
    for row in report.rows.clone() {
        let Some(m) = METHODS.iter().position(|m| m.name == row.method) else {
            continue;
        };
        match BASELINE.iter().find(|b| b.0 == row.case && b.1 == row.metric) {
            Some(b) => {
                let floor = if row.unit == "%" { 0.02 } else { 1.0 };
                report.check_measured(&row, b.2[m], floor, &row.metric);
            }
            None => report.fail(format!("{}: no baseline for `{}`", row.case, row.metric)),
        }
    }
    // Whatever the baselines allow, the default estimate keeps the light beside a shadow's
    // edge, a corner's wall and a step's nose within 2 % of the truth.
    for row in &report.rows.clone() {
        let band = EDGE_BANDS.iter().any(|(c, m)| row.case == *c && row.metric == *m);
        if band && row.method == "multiscale" && row.bias().abs() > EDGE_BAND_BIAS {
            report.fail(format!(
                "{}: multiscale {}: {:+.2} % is beyond ±{} % of the truth",
                row.case,
                row.metric,
                100.0 * row.bias(),
                100.0 * EDGE_BAND_BIAS
            ));
        }
    }
    if std::env::var("PHOTONGRID_WRITE_DOCS").is_ok_and(|v| v == "1") {
        let path = photongrid_testkit::repo_root().join("docs/failure_cases.md");
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::write(&path, docs(&report)).unwrap();
        eprintln!("wrote {}", path.display());
    }
    assert!(
        report.failures.is_empty(),
        "{} check(s) failed:\n{}",
        report.failures.len(),
        report.failures.join("\n")
    );
}

fn docs(report: &Report) -> String {
    format!(
        "# Where the photon estimates fail\n\n\
         Generated by `tests/failure_cases.rs`:\n\n\
         ```sh\nPHOTONGRID_WRITE_DOCS=1 cargo test --release --test failure_cases -- --nocapture\n```\n\n\
         Small synthetic scenes with an exact answer, rendered in single-map mode (`direct = photons`: \
         the photon estimate is the whole image) for kNN with k = 100 and k = 500, the paper's \
         adaptive radius with k = 100 (defaults otherwise: 128 cells, Haar, universal threshold, \
         α = 0.1, shadow count 2) and the multiscale estimate (the default). Seeds 1–48 (the caustic case: 1–{CAUSTIC_SEEDS}); each seed traces one photon map shared by the four \
         methods. **bias** = mean over seeds − truth; **σ across seeds** = standard deviation of the \
         metric over the seeds (the variance part). Per pixel, over the metric's pixels and relative \
         to their mean truth: **pixel RMS bias** = RMS of (mean over seeds − truth) (includes σ²/n of \
         noise with n seeds), **pixel RMS σ** = RMS of the per-pixel standard deviation across seeds. \
         Relative errors are Σ estimate / Σ truth − 1 over the region. The test fails when a bias \
         grows beyond 1.5 × the bias measured when the thresholds were set (`BASELINE` in the test) \
         plus a floor of 2 % (1 cm for lengths) or 3 standard errors, whichever is larger; a bias \
         that shrinks passes. The renderer is deterministic for a seed, so the same code gives the \
         same table.\n\n\
         ## What the table shows\n\n\
         - **The adaptive radius behaves like kNN with the same k** in every case, within a few \
         tenths of the noise: in shadows and dark regions the shadow fallback returns the kNN \
         gather itself (bit for bit, see `tests/grid_method.rs`), on tiny and curved receivers no \
         plane exists, and elsewhere r ≈ 0.9 r_a + 0.1 r_k with r_a ≈ r_k. Its per-pixel noise is \
         that of kNN with k = 100 (a fixed-radius estimate holding ~k photons has the same \
         1/√k relative noise). No leak at corners: the wall's photons face another way and are \
         never gathered.\n\
         - **Boundaries darken** (half of the gather disc has no photons): at a corner, next to a \
         wall, at a step's nose (where the tread's plane ends: −34 % within 2 cm for k = 100) and \
         on the lit side of a shadow edge; k = 500 darkens more and farther than k = 100.\n\
         - **The multiscale estimate** (the default) knows each plane's covered area and finds \
         dark cells (no direct or caustic photon where the light around says dozens should be), \
         so it divides light by the surface it falls on, and it takes a direct-light cell on a \
         shadow's edge as lit by the share its photons' flux says against the cells around it: \
         every edge band within ±1.3 % of the truth (48 seeds): +0.79 % ± 0.07 % within 2 cm \
         of a corner's wall, +0.43 % ± 0.06 % within 2 cm of a step's nose, −1.26 % ± 0.17 % \
         within 10 cm on the lit side of a shadow edge (whose outline is drawn between the \
         cells' centres, so the per-pixel bias there is 1.9 %, 5.5 % cell by cell), +0.06 % ± \
         0.10 % beside the empty region's wall; no leak, a shadow edge as wide as the truth \
         (the test fails if any of the first three is beyond ±2 %). (Before photons were emitted from \
         stratified points, twelve seeds had put the corner at +3.1 % ± 1.1 % and 120 seeds at \
         +0.9 % ± 0.4 % within 2 cm.) Direct-light kernels stop at a wall only where the plane \
         runs on behind it, so at a corner they widen up to the wall: per-pixel σ within 2 cm \
         of it 2.3 % (kNN k = 100: 1.3 %), 0.8 % at 2–6 cm (kNN: 1.5 %).\n\
         - **Photons from stratified points** (every light here is a point light or a sun): the \
         spread across seeds is that of the emission points' scrambles, far below independent \
         photons' (kNN k = 100's per-pixel σ on a shadow edge's lit band was 9.7 %, now 1.4 %).\n\
         - **Shadows and walls leak**: the gather reaches photons of the same orientation on the \
         other side of an occluder (same plane, same normal), so light spreads into the shadow by \
         about the gather radius and reaches, ever weaker, up to the largest gather radius \
         (5 % of the scene diagonal); beyond it the dark region is exactly 0.\n\
         - **Receivers smaller than the gather disc** (a 1.5 cm quad with ~16 photons) take in \
         the surface below and come out several times too dark.\n\
         - **Caustic**: the photons carry the right power into the disc; the density estimate \
         adds a few % inside it, because kNN estimates have heavy tails (points of the dim halo \
         gather the bright focus's photons).\n\
         - **Grazing light** (sun at 80°) is unbiased.\n\n{}",
        report.markdown()
    )
}
