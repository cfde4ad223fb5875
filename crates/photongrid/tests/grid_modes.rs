//! Choosing the model a scene needs: `--grid auto` gives planes to the Cornell box's walls and
//! a voxel grid to curved_3d's trough, and no grid where none is asked for.

use photongrid::grid::Grids;
use photongrid::settings::GridMode;
use photongrid::Settings;

fn scene(name: &str) -> photongrid::scene::Scene {
    photongrid::load(&photongrid_testkit::repo_root().join("samples").join(name)).unwrap()
}

fn grids(s: &photongrid::scene::Scene, mode: GridMode) -> Grids {
    Grids::build(
        s,
        &[],
        &[],
        &(&Settings {
            grid: mode,
            ..Settings::default()
        })
            .into(),
    )
}

#[test]
fn auto_uses_planes_for_cornell_walls_and_voxels_only_for_the_rest() {
    let s = scene("cornell_glass.glb");
    let g = grids(&s, GridMode::Auto);
    let planes = g.planes.as_ref().expect("plane grids");
    assert_eq!(planes.set.planes.len(), 11, "5 walls + 6 box faces: {:?}", g.choice);
    // Every wall and box triangle (all but the sphere's) is on a plane; no sphere triangle is.
    let on = (0..s.triangles.len() as u32).filter(|&t| g.on_plane(t)).count();
    assert_eq!(on, 22);
    // The sphere is glass: it stores no photons, so auto mode builds no voxel grid for it.
    assert!(g.voxels.is_none(), "{:?}", g.choice);
}

#[test]
fn auto_uses_voxels_for_the_trough() {
    let s = scene("curved_3d.glb");
    let g = grids(&s, GridMode::Auto);
    let v = g.voxels.as_ref().expect("voxel grid for the curved scene");
    assert!(v.occupied() > 100, "{:?}", g.choice);
    // The trough's triangles are not planes (only its two thin rims may be).
    let on = (0..s.triangles.len() as u32).filter(|&t| g.on_plane(t)).count();
    assert!(on < s.triangles.len() / 100, "{on} triangles on planes");
    // Voxel areas add up to the area they serve.
    let served: f64 = s
        .triangles
        .iter()
        .enumerate()
        .filter(|(t, tri)| !g.on_plane(*t as u32) && !s.materials[tri.material as usize].is_specular())
        .map(|(_, t)| t.area() as f64)
        .sum();
    assert!(
        (v.total_area() / served - 1.0).abs() < 1e-3,
        "{} vs {served}",
        v.total_area()
    );
}

#[test]
fn modes_build_only_what_they_name() {
    let s = scene("shadow_edges.glb");
    let auto = grids(&s, GridMode::Auto);
    assert!(auto.planes.is_some());
    assert!(
        auto.voxels.is_none(),
        "boxes and walls are all planes: {:?}",
        auto.choice
    );
    let none = grids(&s, GridMode::None);
    assert!(none.planes.is_none() && none.voxels.is_none());
    let vox = grids(&s, GridMode::Voxels);
    assert!(vox.planes.is_none() && vox.voxels.is_some());
}
