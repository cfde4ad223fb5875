//! Radiance from photons. Every method is one variant of [`Estimator`], a closed set behind
//! one interface: [`Method::needs`] says what a method needs from the photon pass (grids,
//! the triangle each photon landed on, how passes accumulate), [`Estimator::gather`] returns
//! the photons around a point with the radius the method chooses, and [`density`] holds the
//! formulas (eq. (1), the kNN correction, eq. (3), the progressive schedules) once.
//!
//! To add an estimator: a [`Method`] variant (settings), its [`Needs`], an [`Estimator`]
//! variant built in [`Estimator::for_pass`], and its arm in [`Estimator::gather`]; the compiler
//! lists every `match` to update.

pub mod bright;
pub mod density;
pub mod irradiance;
pub mod multiscale;
pub mod photon_map;
pub mod sppm;
pub mod support;

pub use irradiance::IrradianceCache;
pub use photon_map::{Gather, PhotonMap, NORMAL_AGREEMENT};
pub use support::Surfaces;

use crate::grid::multiscale::MultiscaleGrids;
use crate::grid::{GridSample, Grids};
use crate::settings::{Method, Settings};
use crate::spatial::KnnBuffer;
use density::{assumed_radius, blended_radius, progressive_neighbours};
use glam::Vec3;
pub use multiscale::Gammas;

/// How a camera's image accumulates over progressive passes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Accumulation {
    /// Each pass is a complete image; the passes' images are averaged.
    Average,
    /// Each camera sample keeps its radius, count and flux across passes (SPPM).
    PerSample,
}

/// What a method needs from the photon pass.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Needs {
    /// Count textures on planes and voxels ([`Grids`]), accumulated over passes.
    pub grids: bool,
    /// Flux pyramids on the planes ([`MultiscaleGrids`]), accumulated over passes.
    pub multiscale: bool,
    /// The triangle each photon landed on (to count it into its plane's texture).
    pub photon_triangles: bool,
    /// How passes accumulate.
    pub accumulation: Accumulation,
}

impl Method {
    /// What this method needs from the photon pass.
    pub fn needs(self) -> Needs {
        match self {
            Method::Knn => Needs {
                grids: false,
                multiscale: false,
                photon_triangles: false,
                accumulation: Accumulation::Average,
            },
            Method::Adaptive => Needs {
                grids: true,
                multiscale: false,
                photon_triangles: true,
                accumulation: Accumulation::Average,
            },
            Method::Sppm => Needs {
                grids: false,
                multiscale: false,
                photon_triangles: false,
                accumulation: Accumulation::PerSample,
            },
            Method::Multiscale => Needs {
                grids: false,
                multiscale: true,
                photon_triangles: true,
                accumulation: Accumulation::Average,
            },
        }
    }
}

/// A diffuse point where radiance is estimated.
#[derive(Clone, Copy, Debug)]
pub struct Query {
    /// Position.
    pub position: Vec3,
    /// Geometric normal facing the viewer: photons must agree with it.
    pub facing_normal: Vec3,
    /// Geometric normal of the triangle's front face (the voxel grid's bins follow it).
    pub geometric_normal: Vec3,
    /// The triangle (its plane grid, if any).
    pub triangle: u32,
    /// Radius of the camera pixel's footprint here (0: not seen by the camera, or not known).
    /// Off the planes no kernel is made narrower: the photons of a caustic line thinner than
    /// a pixel would otherwise be counted over discs reaching them from beside the line, more
    /// than once in total (a kNN disc is not a partition of the light).
    pub footprint: f32,
    /// The point reflects glossily what it stores: final gathering evaluates its lobe, where
    /// the photons' estimate takes it as diffuse, so gathering supplies its indirect light
    /// unless the photons' noise is negligible beside the point's light
    /// ([`multiscale::photons_suffice`] without gather rays).
    pub glossy: bool,
}

/// The grids an estimate may read (those its [`Needs`] asked for).
#[derive(Clone, Copy, Default)]
pub struct PassGrids<'a> {
    /// The paper's count textures and voxels.
    pub paper: Option<&'a Grids>,
    /// The multiscale flux pyramids.
    pub multiscale: Option<&'a MultiscaleGrids>,
}

/// One pass's photon estimate, ready for queries.
#[derive(Clone, Copy)]
pub enum Estimator<'a> {
    /// The `k` nearest photons (Jensen).
    Knn {
        /// This pass's photons.
        map: &'a PhotonMap,
        /// Neighbours.
        k: usize,
    },
    /// The paper's: the assumed radius of `n_all` neighbours from the grids' filtered counts
    /// (which hold every pass's photons so far), blended with the kNN radius of `k` neighbours
    /// in this pass's map; kNN where no grid covers the point or in shadow.
    Adaptive {
        /// This pass's photons.
        map: &'a PhotonMap,
        /// The grids (none built: plain kNN).
        grids: Option<&'a Grids>,
        /// Neighbours among all passes' photons ([`progressive_neighbours`]).
        n_all: usize,
        /// Neighbours within this pass's map.
        k: usize,
        /// Blend factor α of [`blended_radius`].
        alpha: f32,
        /// Filtered count below which the kNN radius is used.
        shadow_count: f32,
    },
    /// The grids as the estimator ([`multiscale::gather`]): on a plane, each photon layer's
    /// flux at the widest scale consistent with all finer ones; elsewhere the widest of nested
    /// kNN discs consistent with all narrower ones ([`PhotonMap::adaptive_knn`]).
    Multiscale {
        /// This pass's photons (the fallback off the planes).
        map: &'a PhotonMap,
        /// The flux pyramids (every pass's photons so far).
        grids: Option<&'a MultiscaleGrids>,
        /// Neighbours of the kNN fallback.
        k: usize,
        /// Confidence-interval widths in standard deviations.
        gamma: Gammas,
        /// Direct light comes from photons (the single-map setting).
        direct: bool,
        /// Final gathering is on: near plane edges it supplies indirect light.
        gathering: bool,
        /// Final-gather rays per pixel over the passes so far, this one included (camera
        /// samples × gather rays; [`Estimator::with_gather_rays`]).
        gather_rays: f32,
        /// The surfaces, for the area each disc covers off the planes.
        surfaces: &'a Surfaces<'a>,
    },
    /// SPPM: each camera sample keeps its own radius ([`sppm::SppmPixel`]); a query gives the
    /// kNN radius that starts it.
    Sppm {
        /// This pass's photons.
        map: &'a PhotonMap,
        /// Neighbours of the starting radius.
        k: usize,
    },
}

/// Off the planes, where the map holds global light (no final gathering), the multiscale
/// estimate's discs may grow to this many times `neighbours` photons where the light is flat.
/// A caustic map (final gathering on) stops at `neighbours`: wider discs changed nothing there
/// and cost camera time (docs/multiscale.md).
pub const OFF_PLANE_WIDENING: usize = 4;

impl<'a> Estimator<'a> {
    /// The estimator of `settings.method` for pass `pass` (0-based) over `map`, the grids and
    /// the scene's `surfaces`.
    pub fn for_pass(
        settings: &Settings,
        pass: u32,
        map: &'a PhotonMap,
        grids: PassGrids<'a>,
        surfaces: &'a Surfaces<'a>,
    ) -> Self {
        let k = settings.neighbours;
        match settings.method {
            Method::Knn => Estimator::Knn { map, k },
            Method::Sppm => Estimator::Sppm { map, k },
            Method::Multiscale => Estimator::Multiscale {
                map,
                grids: grids.multiscale,
                k,
                gamma: Gammas::of_settings(settings, grids.multiscale.is_some_and(|g| g.stratified)),
                direct: settings.direct == crate::settings::DirectLighting::Photons,
                gathering: settings.effective_gather() > 0,
                gather_rays: settings.spp as f32 * settings.effective_gather() as f32,
                surfaces,
            },
            Method::Adaptive => {
                let (n_all, k) = progressive_neighbours(k, pass);
                Estimator::Adaptive {
                    map,
                    grids: grids.paper,
                    n_all,
                    k,
                    alpha: settings.alpha,
                    shadow_count: settings.shadow_count,
                }
            }
        }
    }

    /// The estimator with `rays` final-gather rays per pixel over all passes so far (for_pass
    /// counts this pass's only): where the photons' indirect estimate replaces gathering
    /// depends on it ([`multiscale::photons_suffice`]).
    pub fn with_gather_rays(mut self, rays: f32) -> Self {
        if let Estimator::Multiscale { gather_rays, .. } = &mut self {
            *gather_rays = rays;
        }
        self
    }

    /// Whether the gather rays per pixel ([`with_gather_rays`](Self::with_gather_rays)) decide
    /// where final gathering runs (elsewhere it runs wherever the pass has gather rays).
    pub fn weighs_gather_rays(&self) -> bool {
        matches!(self, Estimator::Multiscale { .. })
    }

    /// This pass's photon map.
    pub fn map(&self) -> &'a PhotonMap {
        match *self {
            Estimator::Knn { map, .. }
            | Estimator::Adaptive { map, .. }
            | Estimator::Multiscale { map, .. }
            | Estimator::Sppm { map, .. } => map,
        }
    }

    /// The grids and their bright texels, for aiming final-gather rays (the multiscale
    /// estimate, once its textures are resolved for gathering).
    pub fn bright(&self) -> Option<(&'a MultiscaleGrids, &'a bright::BrightTexels)> {
        match *self {
            Estimator::Multiscale { grids: Some(g), .. } => g.bright.as_ref().map(|b| (g, b)),
            _ => None,
        }
    }

    /// The photons around `q` with the radius the method chooses, and whether final
    /// gathering must add indirect light there.
    pub fn gather(&self, q: &Query, buf: &mut KnnBuffer) -> Gather {
        let mut g = self.gather_photons(q, buf);
        if !matches!(self, Estimator::Multiscale { .. }) {
            // The map holds indirect photons only when nothing gathers them.
            g.needs_gathering = true;
        }
        g
    }

    /// Total irradiance at a final-gather ray's hit (on the side `facing_normal` faces) read
    /// from the grids, where they cover it
    /// (the multiscale estimate); None: read precomputed irradiance instead.
    pub fn grid_irradiance(&self, triangle: u32, p: Vec3, facing_normal: Vec3) -> Option<crate::Rgb> {
        match *self {
            Estimator::Multiscale {
                grids: Some(g), gamma, ..
            } => g.irradiance(triangle, p, facing_normal, gamma),
            _ => None,
        }
    }

    fn gather_photons(&self, q: &Query, buf: &mut KnnBuffer) -> Gather {
        match *self {
            Estimator::Knn { map, k } | Estimator::Sppm { map, k } => map.knn(q.position, q.facing_normal, k, buf),
            Estimator::Multiscale {
                map,
                grids,
                k,
                gamma,
                direct,
                gathering,
                gather_rays,
                surfaces,
            } => {
                // With final gathering the map holds caustics only: its photons within a disc
                // resolve a caustic finer than the grids' finest texel.
                let mut finer = |r: f32| map.within(q.position, q.facing_normal, r);
                let finer = gathering.then_some(&mut finer as &mut dyn FnMut(f32) -> Gather);
                let on_plane =
                    grids.and_then(|g| multiscale::gather(g, q, gamma, direct, gathering, gather_rays, finer));
                match on_plane {
                    Some(g) => g,
                    None => {
                        let k_max = if gathering { k } else { OFF_PLANE_WIDENING * k };
                        // The surface under each disc where the map holds global light; a
                        // caustic map's discs (final gathering on) keep πr²: there the areas
                        // cost camera time and moved no figure (docs/multiscale.md, "Discs
                        // that cross an edge off the planes").
                        let area = |r2: &[f32], a: &mut [f32]| {
                            if gathering {
                                support::flat_disc_areas(r2, a)
                            } else {
                                surfaces.kernel_areas(q.position, q.facing_normal, q.triangle, r2, a)
                            }
                        };
                        Gather {
                            needs_gathering: gathering,
                            ..map.adaptive_knn(q.position, q.facing_normal, (k_max, q.footprint), &area, buf)
                        }
                    }
                }
            }
            Estimator::Adaptive {
                map,
                grids,
                n_all,
                k,
                alpha,
                shadow_count,
            } => {
                let gk = map.knn(q.position, q.facing_normal, k, buf);
                let Some(grids) = grids else { return gk };
                let r_a = match grids.sample(q.triangle, q.position, q.geometric_normal) {
                    GridSample::Covered { count, density } if count >= shadow_count && density > 0.0 => {
                        assumed_radius(n_all, density)
                    }
                    // Shadows, dark corners, surfaces no grid covers: the real kNN radius.
                    _ => return gk,
                };
                if !r_a.is_finite() {
                    return gk;
                }
                if gk.count < k {
                    return gk; // fewer than k photons within the largest radius: nothing to blend
                }
                let r_k = gk.r2.sqrt();
                let r = blended_radius(r_a, r_k, alpha).min(map.max_radius);
                if r <= r_k {
                    map.knn_within(buf, r)
                } else {
                    map.within(q.position, q.facing_normal, r)
                }
            }
        }
    }
}
