//! A small harness for error measurements on synthetic scenes: geometry helpers on top of the
//! glTF builder, a top-down orthographic view with its exact pixel → world mapping, renders of
//! several methods over several seeds sharing one photon map per seed, and bias/variance
//! statistics collected into a table (stderr and Markdown) with threshold checks.
#![allow(dead_code)]

use super::*;
use photongrid::film::Film;
use photongrid::pipeline::{prepare, render_camera, select_cameras, PhaseTimes, Prepared};
use photongrid::progress::Progress;
use photongrid::scene::Scene;
use photongrid::settings::Method;
use photongrid::Settings;
use std::fmt::Write as _;

// ---------------------------------------------------------------------------------------------
// Geometry.

/// A quad from four corners in order (counter-clockwise seen from the front), as two
/// triangles with the flat normal `(p1 − p0) × (p2 − p0)`.
pub fn quad(p: [[f32; 3]; 4]) -> Prim {
    let v = |i: usize| glam::Vec3::from(p[i]);
    let n = (v(1) - v(0)).cross(v(2) - v(0)).normalize();
    Prim::new(p.to_vec())
        .normals(vec![n.to_array(); 4])
        .indices_u16(vec![0, 1, 2, 0, 2, 3])
}

/// A horizontal rectangle `x0..x1 × z0..z1` at height `y`, facing +Y.
pub fn rect_up(x0: f32, x1: f32, z0: f32, z1: f32, y: f32) -> Prim {
    quad([[x0, y, z0], [x0, y, z1], [x1, y, z1], [x1, y, z0]])
}

/// A vertical rectangle in the plane `x = x`, `y0..y1 × z0..z1`, facing +X.
pub fn rect_px(x: f32, y0: f32, y1: f32, z0: f32, z1: f32) -> Prim {
    quad([[x, y0, z0], [x, y1, z0], [x, y1, z1], [x, y0, z1]])
}

/// A closed axis-aligned box with outward faces (12 triangles).
pub fn box_prim(min: [f32; 3], max: [f32; 3]) -> Prim {
    let [x0, y0, z0] = min;
    let [x1, y1, z1] = max;
    let faces: [[[f32; 3]; 4]; 6] = [
        [[x0, y1, z0], [x0, y1, z1], [x1, y1, z1], [x1, y1, z0]], // +Y
        [[x0, y0, z0], [x1, y0, z0], [x1, y0, z1], [x0, y0, z1]], // −Y
        [[x1, y0, z0], [x1, y1, z0], [x1, y1, z1], [x1, y0, z1]], // +X
        [[x0, y0, z0], [x0, y0, z1], [x0, y1, z1], [x0, y1, z0]], // −X
        [[x0, y0, z1], [x1, y0, z1], [x1, y1, z1], [x0, y1, z1]], // +Z
        [[x0, y0, z0], [x0, y1, z0], [x1, y1, z0], [x1, y0, z0]], // −Z
    ];
    let mut pos = Vec::new();
    let mut nor = Vec::new();
    let mut idx = Vec::new();
    for f in faces {
        let v = |i: usize| glam::Vec3::from(f[i]);
        let n = (v(1) - v(0)).cross(v(2) - v(0)).normalize().to_array();
        let b = pos.len() as u16;
        pos.extend_from_slice(&f);
        nor.extend_from_slice(&[n; 4]);
        idx.extend_from_slice(&[b, b + 1, b + 2, b, b + 2, b + 3]);
    }
    Prim::new(pos).normals(nor).indices_u16(idx)
}

/// Add a mesh node with one primitive and material.
pub fn add_object(g: &mut Gltf, name: &str, prim: Prim, material: usize) {
    let mesh = g.mesh(vec![prim.material(material)]);
    g.root(Node {
        name: Some(name.into()),
        mesh: Some(mesh),
        ..Default::default()
    });
}

/// Add a white point light of `candela` at `pos`.
pub fn add_point_light(g: &mut Gltf, pos: [f32; 3], candela: f32) {
    let l = g.light(Light::point(candela));
    g.root(Node {
        name: Some("Lamp".into()),
        transform: Transform::translation(pos),
        light: Some(l),
        ..Default::default()
    });
}

/// `L = (albedo/π)·(I/683)·cosθ/d²` at `x` on a surface with normal `n` from a point light of
/// `candela` at `light` (no visibility test).
pub fn point_radiance(albedo: f64, candela: f64, light: [f64; 3], x: [f64; 3], n: [f64; 3]) -> f64 {
    let d = [light[0] - x[0], light[1] - x[1], light[2] - x[2]];
    let d2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
    let cos = (d[0] * n[0] + d[1] * n[1] + d[2] * n[2]) / d2.sqrt();
    albedo / std::f64::consts::PI * (candela / 683.0) * cos.max(0.0) / d2
}

// ---------------------------------------------------------------------------------------------
// A top-down orthographic view.

/// An orthographic camera at height `height` above `(cx, cz)` looking straight down (−Y), image
/// up = world −Z, `w × h` pixels covering `2·ymag·w/h × 2·ymag` metres.
#[derive(Clone, Copy, Debug)]
pub struct TopView {
    /// Centre x.
    pub cx: f64,
    /// Centre z.
    pub cz: f64,
    /// Half of the vertical extent (m).
    pub ymag: f64,
    /// Camera height (rays start there: nothing above it is seen).
    pub height: f64,
    /// Width in pixels.
    pub w: u32,
    /// Height in pixels.
    pub h: u32,
}

impl TopView {
    /// Add the camera node.
    pub fn add_camera(&self, g: &mut Gltf) {
        let c = g.camera(Camera::Orthographic {
            xmag: (self.ymag * self.w as f64 / self.h as f64) as f32,
            ymag: self.ymag as f32,
        });
        g.root(Node {
            name: Some("Top".into()),
            transform: Transform::tr([self.cx as f32, self.height as f32, self.cz as f32], look_down()),
            camera: Some(c),
            ..Default::default()
        });
    }

    /// Edge of a pixel in metres.
    pub fn pixel_size(&self) -> f64 {
        2.0 * self.ymag / self.h as f64
    }

    /// World (x, z) at film position (fx, fy) (pixels, y down).
    pub fn film_to_world(&self, fx: f64, fy: f64) -> (f64, f64) {
        let ndc_x = 2.0 * fx / self.w as f64 - 1.0;
        let ndc_y = 1.0 - 2.0 * fy / self.h as f64;
        (
            self.cx + ndc_x * self.ymag * self.w as f64 / self.h as f64,
            self.cz - ndc_y * self.ymag,
        )
    }

    /// World (x, z) of a pixel's centre.
    pub fn center(&self, px: u32, py: u32) -> (f64, f64) {
        self.film_to_world(px as f64 + 0.5, py as f64 + 0.5)
    }

    /// `f(x, z)` averaged over pixel (px, py) by 8×8 midpoint sub-sampling.
    pub fn pixel_mean(&self, px: u32, py: u32, f: &dyn Fn(f64, f64) -> f64) -> f64 {
        let n = 8;
        let mut s = 0.0;
        for i in 0..n {
            for j in 0..n {
                let (x, z) = self.film_to_world(
                    px as f64 + (i as f64 + 0.5) / n as f64,
                    py as f64 + (j as f64 + 0.5) / n as f64,
                );
                s += f(x, z);
            }
        }
        s / (n * n) as f64
    }

    /// The closed form per pixel (pixel means of `f`), row-major.
    pub fn truth(&self, f: &dyn Fn(f64, f64) -> f64) -> Vec<f64> {
        let mut out = Vec::with_capacity((self.w * self.h) as usize);
        for py in 0..self.h {
            for px in 0..self.w {
                out.push(self.pixel_mean(px, py, f));
            }
        }
        out
    }

    /// Pixel indices whose centre satisfies `keep(x, z)`.
    pub fn select(&self, keep: &dyn Fn(f64, f64) -> bool) -> Vec<usize> {
        let mut out = Vec::new();
        for py in 0..self.h {
            for px in 0..self.w {
                let (x, z) = self.center(px, py);
                if keep(x, z) {
                    out.push((py * self.w + px) as usize);
                }
            }
        }
        out
    }

    /// Check that the loaded camera maps pixels as [`TopView::film_to_world`] says.
    pub fn check_camera(&self, scene: &Scene) {
        let cam = &scene.cameras[0];
        for (fx, fy) in [(0.5, 0.5), (self.w as f64 - 0.25, self.h as f64 - 0.75), (10.25, 7.5)] {
            let (o, d) = cam.generate_ray(glam::Vec2::new(fx as f32, fy as f32), self.w, self.h);
            let (x, z) = self.film_to_world(fx, fy);
            assert!((d - glam::Vec3::NEG_Y).length() < 1e-5, "camera direction {d}");
            let tol = 1e-5 * (1.0 + self.cx.abs() + self.cz.abs() + self.ymag);
            assert!(
                (o.x as f64 - x).abs() < tol && (o.z as f64 - z).abs() < tol,
                "camera mapping: {o} vs ({x}, {z})"
            );
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Renders.

/// One estimator configuration.
#[derive(Clone, Copy, Debug)]
pub struct MethodSpec {
    /// Short name for tables.
    pub name: &'static str,
    /// Radius choice.
    pub method: Method,
    /// Neighbours k.
    pub k: usize,
}

/// The three estimators compared: kNN with k = 100 and 500, the paper's adaptive radius with
/// k = 100.
pub const METHODS: [MethodSpec; 4] = [
    MethodSpec {
        name: "knn k=100",
        method: Method::Knn,
        k: 100,
    },
    MethodSpec {
        name: "knn k=500",
        method: Method::Knn,
        k: 500,
    },
    MethodSpec {
        name: "adaptive k=100",
        method: Method::Adaptive,
        k: 100,
    },
    MethodSpec {
        name: "multiscale",
        method: Method::Multiscale,
        k: 100,
    },
];

/// Load a scene file (panics with the loader's message).
pub fn load(path: &std::path::Path) -> Scene {
    photongrid::load(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// Photon pass, grids and index for `settings` (method forced to adaptive so the plane grids
/// exist; the photons do not depend on the method).
pub fn prepare_adaptive(scene: &Scene, settings: &Settings) -> Prepared {
    let s = Settings {
        method: Method::Adaptive,
        ..settings.clone()
    };
    prepare(scene, &s, &Progress::quiet(), &mut PhaseTimes::default()).unwrap_or_else(|e| panic!("{e}"))
}

/// Render the first camera with prepared data and `settings` (its method and neighbours).
pub fn render_prepared(scene: &Scene, prepared: &Prepared, settings: &Settings) -> Film {
    let cams = select_cameras(scene, &[]).unwrap();
    render_camera(scene, prepared, cams[0], settings, &Progress::quiet())
}

/// Films per method (outer) and seed (inner): one photon pass per seed, shared by every method.
pub fn render_methods(scene: &Scene, base: &Settings, seeds: &[u64], methods: &[MethodSpec]) -> Vec<Vec<Film>> {
    render_methods_with(scene, base, seeds, methods, &mut |_, _| {})
}

/// As [`render_methods`], calling `inspect(seed, prepared)` on each seed's photon map.
pub fn render_methods_with(
    scene: &Scene,
    base: &Settings,
    seeds: &[u64],
    methods: &[MethodSpec],
    inspect: &mut dyn FnMut(u64, &Prepared),
) -> Vec<Vec<Film>> {
    let mut out: Vec<Vec<Film>> = methods.iter().map(|_| Vec::new()).collect();
    for &seed in seeds {
        let s = Settings { seed, ..base.clone() };
        let prepared = prepare_adaptive(scene, &s);
        inspect(seed, &prepared);
        // The multiscale pyramids come from the same seed's photons (the same photons).
        let multiscale = methods.iter().any(|m| m.method == Method::Multiscale).then(|| {
            let ms = Settings {
                method: Method::Multiscale,
                ..s.clone()
            };
            prepare(scene, &ms, &Progress::quiet(), &mut PhaseTimes::default()).unwrap_or_else(|e| panic!("{e}"))
        });
        for (m, spec) in methods.iter().enumerate() {
            let rs = Settings {
                method: spec.method,
                neighbours: spec.k,
                ..s.clone()
            };
            let p = match (&multiscale, spec.method) {
                (Some(ms), Method::Multiscale) => ms,
                _ => &prepared,
            };
            let film = render_prepared(scene, p, &rs);
            assert_eq!(film.nonfinite(), 0, "{}: non-finite pixels", spec.name);
            out[m].push(film);
        }
    }
    out
}

/// Grey value of a pixel (the mean of the channels).
pub fn grey(film: &Film, i: usize) -> f64 {
    let c = film.color[i];
    ((c.x + c.y + c.z) / 3.0) as f64
}

/// Σ over `pixels` of the grey value.
pub fn sum_over(film: &Film, pixels: &[usize]) -> f64 {
    pixels.iter().map(|&i| grey(film, i)).sum()
}

/// Σ over `pixels` of `truth`.
pub fn sum_truth(truth: &[f64], pixels: &[usize]) -> f64 {
    pixels.iter().map(|&i| truth[i]).sum()
}

/// Σ film / Σ reference over `pixels`, per film.
pub fn ratios(films: &[Film], reference: &[f64], pixels: &[usize]) -> Vec<f64> {
    let t = sum_truth(reference, pixels);
    films.iter().map(|f| sum_over(f, pixels) / t).collect()
}

/// Relative errors Σ film / Σ truth − 1 over `pixels`, per film.
pub fn rel_errors(films: &[Film], truth: &[f64], pixels: &[usize]) -> Vec<f64> {
    ratios(films, truth, pixels).into_iter().map(|r| r - 1.0).collect()
}

/// Per-pixel bias and noise over `pixels`, relative to the mean truth there: the RMS over
/// pixels of (mean over seeds − truth), and the RMS over pixels of the standard deviation
/// across seeds. (With n seeds the first includes σ²/n of noise.)
pub fn pixel_bias_noise(films: &[Film], truth: &[f64], pixels: &[usize]) -> (f64, f64) {
    let n = films.len() as f64;
    let mean_truth = sum_truth(truth, pixels) / pixels.len() as f64;
    let (mut b2, mut v) = (0.0, 0.0);
    for &i in pixels {
        let vals: Vec<f64> = films.iter().map(|f| grey(f, i)).collect();
        let m = vals.iter().sum::<f64>() / n;
        b2 += (m - truth[i]).powi(2);
        v += vals.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0).max(1.0);
    }
    let p = pixels.len() as f64;
    ((b2 / p).sqrt() / mean_truth, (v / p).sqrt() / mean_truth)
}

// ---------------------------------------------------------------------------------------------
// Statistics and the table.

/// Mean and sample standard deviation.
pub fn mean_std(v: &[f64]) -> (f64, f64) {
    let n = v.len() as f64;
    let m = v.iter().sum::<f64>() / n;
    let var = v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0).max(1.0);
    (m, var.sqrt())
}

/// One measured quantity of one case and method over the seeds.
#[derive(Clone, Debug)]
pub struct Row {
    /// Case.
    pub case: String,
    /// What is measured.
    pub metric: String,
    /// Method name.
    pub method: String,
    /// The exact value.
    pub truth: f64,
    /// Mean over seeds.
    pub mean: f64,
    /// Standard deviation across seeds.
    pub std: f64,
    /// Seeds measured (the bias's standard error is `std / √seeds`).
    pub seeds: usize,
    /// Unit or scale shown ("%" multiplies by 100).
    pub unit: &'static str,
    /// Per-pixel RMS bias and RMS σ across seeds over the metric's pixels, relative to the
    /// mean truth there (see [`pixel_bias_noise`]), when measured.
    pub pixel: Option<(f64, f64)>,
}

impl Row {
    /// Mean over seeds minus the truth.
    pub fn bias(&self) -> f64 {
        self.mean - self.truth
    }

    /// Standard error of the bias: σ across seeds over √seeds.
    pub fn standard_error(&self) -> f64 {
        self.std / (self.seeds.max(1) as f64).sqrt()
    }

    /// The figures of the tables: truth, mean, bias ± its standard error and σ across seeds in
    /// the row's unit, and the pixel RMS bias and σ in % (`space` before the sign), empty when
    /// not measured.
    fn cells(&self, space: &str) -> [String; 6] {
        let (pb, pn) = match self.pixel {
            Some((b, n)) => (format!("{:.2}{space}%", 100.0 * b), format!("{:.2}{space}%", 100.0 * n)),
            None => (String::new(), String::new()),
        };
        [
            fmt_value(self.truth, self.unit, false),
            fmt_value(self.mean, self.unit, false),
            format!(
                "{} ± {}",
                fmt_value(self.bias(), self.unit, true),
                fmt_value(self.standard_error(), self.unit, false)
            ),
            fmt_value(self.std, self.unit, false),
            pb,
            pn,
        ]
    }
}

/// Rows, notes and failed checks of a run.
#[derive(Default)]
pub struct Report {
    /// The measurements.
    pub rows: Vec<Row>,
    /// Free text per case (geometry, photon counts).
    pub notes: Vec<(String, String)>,
    /// Failed threshold checks.
    pub failures: Vec<String>,
}

fn scaled(x: f64, unit: &str) -> f64 {
    if unit == "%" {
        100.0 * x
    } else {
        x
    }
}

impl Report {
    /// Record a metric measured over seeds; returns the row.
    pub fn add(
        &mut self,
        case: &str,
        metric: &str,
        method: &str,
        truth: f64,
        values: &[f64],
        unit: &'static str,
    ) -> Row {
        let (mean, std) = mean_std(values);
        let row = Row {
            case: case.into(),
            metric: metric.into(),
            method: method.into(),
            truth,
            mean,
            std,
            seeds: values.len(),
            unit,
            pixel: None,
        };
        self.rows.push(row.clone());
        row
    }

    /// Record the relative error of `films` over `pixels` against `truth_px` ([`rel_errors`],
    /// in %, truth 0) with its per-pixel bias and noise; returns the row.
    pub fn add_rel_error(
        &mut self,
        case: &str,
        metric: &str,
        method: &str,
        films: &[Film],
        truth_px: &[f64],
        pixels: &[usize],
    ) -> Row {
        let values = rel_errors(films, truth_px, pixels);
        let mut row = self.add(case, metric, method, 0.0, &values, "%");
        row.pixel = Some(pixel_bias_noise(films, truth_px, pixels));
        *self.rows.last_mut().unwrap() = row.clone();
        row
    }

    /// A note shown under the case.
    pub fn note(&mut self, case: &str, text: String) {
        self.notes.push((case.into(), text));
    }

    /// Require `lo ≤ bias ≤ hi` for `row`; `what` explains the quantity in the failure message.
    pub fn check_bias(&mut self, row: &Row, lo: f64, hi: f64, what: &str) {
        let b = row.bias();
        if !(b >= lo && b <= hi) {
            self.failures.push(format!(
                "{}: {} {what}: bias {:+.3}{u} outside [{:+.3}{u}, {:+.3}{u}] (mean {:.4}{u}, truth {:.4}{u}, σ {:.3}{u})",
                row.case,
                row.method,
                scaled(b, row.unit),
                scaled(lo, row.unit),
                scaled(hi, row.unit),
                scaled(row.mean, row.unit),
                scaled(row.truth, row.unit),
                scaled(row.std, row.unit),
                u = row.unit,
            ));
        }
    }

    /// Check `row` against the bias measured when the thresholds were set: the bias may grow to
    /// 1.5 × the measured one (plus `floor`, at least 3 standard errors) on the side it was
    /// measured, and shrink to 0 (minus the same floor): a worse estimate fails, a better one
    /// passes. `what` names the quantity in the message.
    pub fn check_measured(&mut self, row: &Row, measured: f64, floor: f64, what: &str) {
        let floor = floor.max(3.0 * row.standard_error());
        let (lo, hi) = if measured < 0.0 {
            (1.5 * measured - floor, floor)
        } else {
            (-floor, 1.5 * measured + floor)
        };
        let b = row.bias();
        if !(b >= lo && b <= hi) {
            let u = row.unit;
            self.failures.push(format!(
                "{}: {} {what}: {} is outside the allowed {} … {} (measured {} when the thresholds were \
                 set; mean {}, truth {}, σ across seeds {})",
                row.case,
                row.method,
                fmt_value(b, u, true),
                fmt_value(lo, u, true),
                fmt_value(hi, u, true),
                fmt_value(measured, u, true),
                fmt_value(row.mean, u, false),
                fmt_value(row.truth, u, false),
                fmt_value(row.std, u, false),
            ));
        }
    }

    /// The measured biases as Rust source for a baseline table `(case, metric, [bias per
    /// method in METHODS order])`.
    pub fn baseline_source(&self) -> String {
        let mut s = String::new();
        let mut seen: Vec<(String, String)> = Vec::new();
        for r in &self.rows {
            let key = (r.case.clone(), r.metric.clone());
            if seen.contains(&key) || !METHODS.iter().any(|m| m.name == r.method) {
                continue;
            }
            let b: Vec<String> = METHODS
                .iter()
                .map(|m| {
                    self.rows
                        .iter()
                        .find(|x| x.case == r.case && x.metric == r.metric && x.method == m.name)
                        .map(|x| format!("{:.4}", x.bias()))
                        .unwrap_or_else(|| "f64::NAN".into())
                })
                .collect();
            let _ = writeln!(s, "    ({:?}, {:?}, [{}]),", r.case, r.metric, b.join(", "));
            seen.push(key);
        }
        s
    }

    /// Require the spread across seeds of `row` to be at most `max`.
    pub fn check_std(&mut self, row: &Row, max: f64, what: &str) {
        if row.std.is_nan() || row.std > max {
            self.failures.push(format!(
                "{}: {} {what}: spread across seeds {:.3}{u} > {:.3}{u}",
                row.case,
                row.method,
                scaled(row.std, row.unit),
                scaled(max, row.unit),
                u = row.unit,
            ));
        }
    }

    /// Record a failure directly.
    pub fn fail(&mut self, msg: String) {
        self.failures.push(msg);
    }

    /// The table as text (stderr).
    pub fn text(&self) -> String {
        let mut s = String::new();
        let _ = writeln!(
            s,
            "{:<12} {:<30} {:<14} {:>10} {:>10} {:>20} {:>9} {:>8} {:>8}",
            "case", "metric", "method", "truth", "mean", "bias ± s.e.", "σ seeds", "px bias", "px σ"
        );
        let mut last = "";
        for r in &self.rows {
            if r.case != last {
                let _ = writeln!(s, "{}", "-".repeat(129));
                last = &r.case;
            }
            let [truth, mean, bias, std, pb, pn] = r.cells("");
            let _ = writeln!(
                s,
                "{:<12} {:<30} {:<14} {truth:>10} {mean:>10} {bias:>20} {std:>9} {pb:>8} {pn:>8}",
                r.case, r.metric, r.method,
            );
        }
        s
    }

    /// The table as Markdown, one section per case with its notes.
    pub fn markdown(&self) -> String {
        let mut s = String::new();
        let mut cases: Vec<&str> = Vec::new();
        for r in &self.rows {
            if !cases.contains(&r.case.as_str()) {
                cases.push(&r.case);
            }
        }
        for case in cases {
            let _ = writeln!(s, "### {case}\n");
            for (c, n) in &self.notes {
                if c == case {
                    let _ = writeln!(s, "{n}\n");
                }
            }
            let _ = writeln!(
                s,
                "| metric | method | truth | mean | bias ± standard error | σ across seeds | pixel RMS bias | pixel RMS σ |"
            );
            let _ = writeln!(s, "|---|---|---:|---:|---:|---:|---:|---:|");
            for r in self.rows.iter().filter(|r| r.case == case) {
                let [truth, mean, bias, std, pb, pn] = r.cells(" ");
                let _ = writeln!(
                    s,
                    "| {} | {} | {truth} | {mean} | {bias} | {std} | {pb} | {pn} |",
                    r.metric, r.method,
                );
            }
            let _ = writeln!(s);
        }
        s
    }
}

/// A value in its unit: "%" as a percentage, others with the unit appended.
fn fmt_value(x: f64, unit: &str, signed: bool) -> String {
    let v = scaled(x, unit);
    let num = if signed { format!("{v:+.2}") } else { format!("{v:.2}") };
    let num = if unit != "%" && v.abs() < 0.1 && v != 0.0 {
        if signed {
            format!("{v:+.4}")
        } else {
            format!("{v:.4}")
        }
    } else {
        num
    };
    match unit {
        "" => num,
        "%" => format!("{num} %"),
        u => format!("{num} {u}"),
    }
}
