"""The photongrid add-on in real Blender (bpy as a Python module, `pip install bpy==5.0.1`).

Needs the photongrid binary: PHOTONGRID_BIN, or target/release/photongrid of this repository,
or photongrid on PATH. Run: python3 -m pytest -q plugin/blender/tests
"""

import json
import math
import os
import shutil
import subprocess
import sys
import time
from types import SimpleNamespace

import pytest

HERE = os.path.dirname(os.path.abspath(__file__))
PLUGIN_DIR = os.path.dirname(HERE)  # plugin/blender, which holds the photongrid package
REPO = os.path.dirname(os.path.dirname(PLUGIN_DIR))
sys.path.insert(0, PLUGIN_DIR)

import bpy  # noqa: E402  (no skip: without bpy these tests must fail, not pass silently)
import bmesh  # noqa: E402
import numpy as np  # noqa: E402
from mathutils import Vector  # noqa: E402

import photongrid  # noqa: E402
from photongrid import core  # noqa: E402

WIDTH, HEIGHT = 64, 48
PHOTONS = 20_000


def binary_path():
    candidates = [os.environ.get(core.ENV_VAR, ""), os.path.join(REPO, "target", "release", "photongrid")]
    for c in candidates:
        if c and os.path.isfile(c) and os.access(c, os.X_OK):
            return os.path.abspath(c)
    found = shutil.which("photongrid")
    if found:
        return found
    pytest.fail("photongrid binary not found: build it (cargo build --release) or set PHOTONGRID_BIN")


@pytest.fixture(scope="module")
def addon():
    # The panel's properties come from the binary's settings schema: it must be found when the
    # add-on registers (here through PHOTONGRID_BIN, as the extension's own binary is not there).
    mp = pytest.MonkeyPatch()
    mp.setenv(core.ENV_VAR, binary_path())
    photongrid.register()
    yield photongrid
    photongrid.unregister()
    mp.undo()


@pytest.fixture
def binary(monkeypatch):
    path = binary_path()
    monkeypatch.setenv(core.ENV_VAR, path)
    return path


def material(name, color, transmission=0.0, roughness=0.5):
    mat = bpy.data.materials.new(name)
    if bpy.app.version < (5, 0, 0) and not mat.use_nodes:
        mat.use_nodes = True  # Blender 4.x; 5.x materials always use nodes
    bsdf = mat.node_tree.nodes.get("Principled BSDF")
    assert bsdf is not None
    bsdf.inputs["Base Color"].default_value = (*color, 1.0)
    bsdf.inputs["Metallic"].default_value = 0.0
    bsdf.inputs["Roughness"].default_value = roughness
    bsdf.inputs["IOR"].default_value = 1.5
    bsdf.inputs["Transmission Weight"].default_value = transmission
    return mat


def mesh_object(scene, name, build, mat, location=(0, 0, 0)):
    me = bpy.data.meshes.new(name)
    bm = bmesh.new()
    build(bm)
    bm.to_mesh(me)
    bm.free()
    me.materials.append(mat)
    for p in me.polygons:
        p.use_smooth = name == "Sphere"
    obj = bpy.data.objects.new(name, me)
    obj.location = location
    scene.collection.objects.link(obj)
    return obj


def look_at(obj, target):
    direction = Vector(target) - obj.location
    obj.rotation_euler = direction.to_track_quat("-Z", "Y").to_euler()


def build_scene(tmp_path):
    """A white plane, a glass sphere off-centre, a 30 W point light, a camera: a caustic."""
    bpy.ops.wm.read_homefile(use_empty=True)  # not factory settings: they would disable add-ons
    scene = bpy.context.scene
    white = material("White", (0.8, 0.8, 0.8), roughness=1.0)
    glass = material("Glass", (1.0, 1.0, 1.0), transmission=1.0, roughness=0.0)
    mesh_object(scene, "Plane", lambda bm: bmesh.ops.create_grid(bm, x_segments=1, y_segments=1, size=2.0), white)
    # A back wall, so that the image has a clear up and down.
    wall = mesh_object(
        scene, "Wall", lambda bm: bmesh.ops.create_grid(bm, x_segments=1, y_segments=1, size=2.0), white,
        location=(0, 2, 2),
    )
    wall.rotation_euler = (math.radians(90), 0, 0)
    mesh_object(
        scene, "Sphere",
        lambda bm: bmesh.ops.create_uvsphere(bm, u_segments=32, v_segments=16, radius=0.5),
        glass, location=(0.4, 0.2, 0.5),
    )
    light_data = bpy.data.lights.new("Light", "POINT")
    light_data.energy = 30.0
    light_data.shadow_soft_size = 0.0
    light = bpy.data.objects.new("Light", light_data)
    light.location = (0.8, -0.2, 2.4)
    scene.collection.objects.link(light)
    # First in the file a camera that is not the active one: the add-on must pick the active
    # one by name, where the CLI alone would take the first.
    other = bpy.data.objects.new("Other Camera", bpy.data.cameras.new("Other Camera"))
    other.location = (3, 3, 3)
    look_at(other, (0, 0, 0))
    scene.collection.objects.link(other)
    cam_data = bpy.data.cameras.new("Camera")
    cam_data.lens = 35
    cam = bpy.data.objects.new("Camera", cam_data)
    cam.location = (0.0, -4.0, 2.2)
    look_at(cam, (0.0, 0.3, 0.6))
    scene.collection.objects.link(cam)
    scene.camera = cam

    r = scene.render
    r.engine = "PHOTONGRID"
    r.resolution_x, r.resolution_y, r.resolution_percentage = WIDTH * 2, HEIGHT * 2, 50
    r.image_settings.file_format = "OPEN_EXR"
    r.image_settings.color_depth = "32"
    r.image_settings.exr_codec = "ZIP"
    r.filepath = str(tmp_path / "blender.exr")
    r.use_file_extension = False
    scene.view_settings.view_transform = "Standard"
    s = scene.photongrid
    s.photons, s.spp, s.seed, s.neighbours = PHOTONS, 1, 7, 50
    return scene


def export_reference_glb(path):
    """The exporter call of the brief, spelled out here independently of the add-on."""
    bpy.ops.export_scene.gltf(
        filepath=str(path),
        export_format="GLB",
        export_cameras=True,
        export_lights=True,
        export_import_convert_lighting_mode="SPEC",
        export_apply=True,
        export_yup=True,
        use_selection=False,
        use_renderable=True,
        use_active_scene=True,
        export_animations=False,
        export_extras=False,
        will_save_settings=False,
    )


def read_exr(path):
    img = bpy.data.images.load(str(path), check_existing=False)
    try:
        w, h = img.size
        px = np.empty(w * h * 4, dtype=np.float32)
        img.pixels.foreach_get(px)
        return px.reshape(h, w, 4)  # bottom row first, as Blender stores it
    finally:
        bpy.data.images.remove(img)


def cli_render(binary, glb, out, camera="Camera", direct="shadow-rays", extra=()):
    cmd = [
        binary, "render", str(glb), "--camera", camera, "--output", str(out),
        "--width", str(WIDTH), "--height", str(HEIGHT), "--photons", str(PHOTONS),
        "--neighbours", "50", "--spp", "1", "--seed", "7", "--direct", direct, "--progress", "quiet",
        *extra,
    ]
    subprocess.run(cmd, check=True, timeout=300)
    return out


def schema(binary):
    return json.loads(subprocess.run([binary, "settings", "--schema"], capture_output=True, text=True,
                                     check=True).stdout)


def test_engine_is_registered(addon, binary):
    render = bpy.context.scene.render
    render.engine = "PHOTONGRID"  # a TypeError if no such engine is registered
    assert render.engine == "PHOTONGRID"
    assert hasattr(bpy.types.Scene, "photongrid")
    panel = photongrid.RENDER_PT_photongrid
    assert panel.poll(SimpleNamespace(engine="PHOTONGRID"))
    assert not panel.poll(SimpleNamespace(engine="CYCLES"))
    for sub in ("sampling", "photons", "light_paths", "method", "advanced"):
        assert getattr(photongrid, f"RENDER_PT_photongrid_{sub}").bl_parent_id == "RENDER_PT_photongrid"


def test_panel_settings_come_from_the_binary(addon, binary):
    """Names, defaults, choices and tooltips are the binary's (settings --schema), none copied."""
    rna = bpy.types.Scene.bl_rna.properties["photongrid"].fixed_type.properties
    settings = {s["key"]: s for s in schema(binary)["settings"]}
    for key in ("photons", "caustic_photons", "neighbours", "gather", "max_specular_depth", "method", "grid",
                "direct", "alpha"):
        s, p = settings[key], rna[key]
        assert p.description.rstrip(".") == " ".join(s["help"].split()).rstrip("."), key
        if s["type"] == "choice":
            assert [i.identifier for i in p.enum_items] == [c["value"] for c in s["choices"]], key
            assert p.default == s["default"], key
        else:
            assert p.default == pytest.approx(s["default"]), key
    # Width, height are Blender's resolution; Time Limit is a number of seconds, as in Cycles.
    assert "width" not in rna and "time" not in rna
    assert rna["time_limit"].type == "FLOAT" and rna["time_limit"].unit == "TIME_ABSOLUTE"
    assert rna["passes"].type == "INT"
    assert "every" not in rna["time_limit"].description and rna["time_limit"].description
    # The sections an artist reads.
    sections = photongrid.core.SECTIONS
    assert {"photons", "caustic_photons", "neighbours"} <= set(sections["PHOTONS"])
    assert {"gather", "max_specular_depth"} <= set(sections["LIGHT_PATHS"])
    assert {"method", "grid"} <= set(sections["METHOD"])
    # The quality preset sets the photons and samples, and shows Custom once they are edited.
    s = bpy.context.scene.photongrid
    s.quality = "PREVIEW"
    assert s.photons == settings["photons"]["default"] // 8 and s.spp == 1 and s.quality == "PREVIEW"
    s.quality = "DEFAULT"
    assert s.photons == settings["photons"]["default"] and s.quality == "DEFAULT"
    s.photons = 12345
    assert s.quality == "CUSTOM"


@pytest.mark.parametrize("direct", ["shadow-rays", "photons"])
def test_f12_matches_cli(addon, binary, tmp_path, direct):
    scene = build_scene(tmp_path)
    scene.photongrid.direct = direct
    if direct == "photons":  # and Blender's fixed thread count, passed as --threads
        scene.render.threads_mode, scene.render.threads = "FIXED", 1
    t = time.monotonic()
    bpy.ops.render.render(write_still=True)
    blender_seconds = time.monotonic() - t
    out = tmp_path / "blender.exr"
    assert out.is_file(), "the render was not saved"

    glb = tmp_path / "reference.glb"
    export_reference_glb(glb)
    ref_path = cli_render(binary, glb, tmp_path / "cli.exr", direct=direct)

    got, ref = read_exr(out), read_exr(ref_path)
    assert got.shape == ref.shape == (HEIGHT, WIDTH, 4)
    rgb, ref_rgb = got[..., :3], ref[..., :3]
    assert np.isfinite(rgb).all()
    assert ref_rgb.mean() > 1e-3, "the reference is black: the scene is not lit"
    assert np.allclose(got[..., 3], 1.0), "an opaque film (Film > Transparent off) is opaque"
    # Same pixels within 1e-4 relative.
    assert np.allclose(rgb, ref_rgb, rtol=1e-4, atol=1e-6), float(np.abs(rgb - ref_rgb).max())
    # The comparison sees orientation: the image upside down is far from the reference.
    flipped = rgb[::-1]
    assert np.abs(flipped - ref_rgb).mean() > 0.05 * ref_rgb.mean()
    # The active camera was rendered, not the file's first one.
    first = read_exr(cli_render(binary, glb, tmp_path / "first.exr", camera="0"))
    assert np.abs(first[..., :3] - ref_rgb).mean() > 0.05 * ref_rgb.mean()
    # The crate's own EXR reader (top row first) agrees too.
    cmp = subprocess.run([binary, "compare", str(out), str(ref_path), "--json"], capture_output=True, text=True,
                         check=True)
    score = json.loads(cmp.stdout)
    assert score["rel_rmse"] is not None and score["rel_rmse"] < 1e-4, score
    print(f"F12 render {WIDTH}x{HEIGHT}, {PHOTONS} photons: {blender_seconds:.2f} s")


def test_exr_readers_agree(binary, tmp_path, monkeypatch):
    """OpenImageIO (bundled with Blender) and the bpy.data.images fallback give the same pixels."""
    build_scene(tmp_path)
    glb = tmp_path / "scene.glb"
    export_reference_glb(glb)
    exr = str(cli_render(binary, glb, tmp_path / "cli.exr"))
    assert core._import_oiio() is not None, "bpy 5.0.1 bundles OpenImageIO"
    with_oiio = core.read_exr_rgba(exr, WIDTH, HEIGHT, alpha=True)
    monkeypatch.setattr(core, "_import_oiio", lambda: None)
    with_images = core.read_exr_rgba(exr, WIDTH, HEIGHT, alpha=True)
    assert with_oiio.shape == with_images.shape == (WIDTH * HEIGHT * 4,)
    assert np.array_equal(with_oiio, with_images)
    assert len(bpy.data.images) == 0, "the temporary image was not removed"
    with pytest.raises(core.PhotongridError, match="expected"):
        core.read_exr_rgba(exr, WIDTH + 1, HEIGHT)


def watch(monkeypatch, name):
    """Record the calls of the engine's Python method ``name``, still calling it."""
    calls = []
    real = getattr(photongrid.PhotongridRenderEngine, name)

    def wrapper(self, *args, **kwargs):
        calls.append((args, kwargs))
        return real(self, *args, **kwargs)

    monkeypatch.setattr(photongrid.PhotongridRenderEngine, name, wrapper)
    return calls


def test_progress_shows_phases(addon, binary, tmp_path, monkeypatch):
    build_scene(tmp_path)
    statuses, fractions = [], []
    monkeypatch.setattr(photongrid.PhotongridRenderEngine, "show_status", lambda self, text: statuses.append(text))
    monkeypatch.setattr(photongrid.PhotongridRenderEngine, "show_progress", lambda self, f: fractions.append(f))
    bpy.ops.render.render()
    for phase in ("exporting glTF", "load", "bvh", "photons", "irradiance", "build", "render"):
        assert f"photongrid: {phase}" in statuses, statuses
    assert fractions == sorted(fractions) and fractions[-1] == 1.0, fractions


def test_passes_update_the_result_as_they_finish(addon, binary, tmp_path, monkeypatch):
    """Three passes: the result is shown after the first and the second, then the final image,
    which is the command line's three-pass image; the bar never goes back."""
    scene = build_scene(tmp_path)
    scene.photongrid.passes = 3
    shown = watch(monkeypatch, "show_image")
    fractions = []
    real_progress = photongrid.PhotongridRenderEngine.show_progress
    monkeypatch.setattr(photongrid.PhotongridRenderEngine, "show_progress",
                        lambda self, f: (fractions.append(f), real_progress(self, f)))
    statuses = watch(monkeypatch, "show_status")
    bpy.ops.render.render(write_still=True)
    counts = [(a[4] if len(a) > 4 else k.get("count"), k.get("final", False)) for a, k in shown]
    assert counts == [(1, False), (2, False), (3, True)], counts
    assert fractions == sorted(fractions) and fractions[-1] == 1.0
    assert any("pass 2/3" in a[0] for a, _ in statuses), statuses
    glb = tmp_path / "reference.glb"
    export_reference_glb(glb)
    ref = read_exr(cli_render(binary, glb, tmp_path / "cli3.exr", extra=("--passes", "3")))
    got = read_exr(tmp_path / "blender.exr")
    assert np.allclose(got[..., :3], ref[..., :3], rtol=1e-4, atol=1e-6)


def test_esc_keeps_the_pass_that_was_running(addon, binary, tmp_path, monkeypatch):
    """Esc during the first pass of many: the renderer finishes the pass it is running, writes
    it and exits 0; the result is that pass's image (the command line's image with as many
    passes). Which pass was running when Esc arrived depends on timing: the add-on polls."""
    scene = build_scene(tmp_path)
    scene.photongrid.passes = 500
    started, rendering = [], []
    real_popen = core.subprocess.Popen

    def popen(*args, **kwargs):
        proc = real_popen(*args, **kwargs)
        started.append(proc)
        return proc

    real_update = core.ProgressTracker.update

    def update(self, event, now=None):
        if event.get("event") == "progress" and event.get("phase") == "render":
            rendering.append(event)
        return real_update(self, event, now)

    monkeypatch.setattr(core.subprocess, "Popen", popen)
    monkeypatch.setattr(core.ProgressTracker, "update", update)
    # Esc while the first pass renders. (test_break itself is an RNA function, which a Python
    # attribute of the same name does not override; the engine polls it through this method.)
    monkeypatch.setattr(photongrid.PhotongridRenderEngine, "cancel_requested", lambda self: bool(rendering))
    shown = watch(monkeypatch, "show_image")
    try:
        bpy.ops.render.render(write_still=True)
    except RuntimeError as e:
        pytest.fail(f"a render stopped by Esc is not an error: {e}")
    assert len(started) == 1 and rendering
    proc = started[0]
    assert proc.poll() == 0, "the renderer wrote the pass and exited by itself"
    counts = [(a[4] if len(a) > 4 else k.get("count"), k.get("final", False)) for a, k in shown]
    assert counts[-1][1] and 1 <= counts[-1][0] < 500, counts
    n = counts[-1][0]
    glb = tmp_path / "reference.glb"
    export_reference_glb(glb)
    ref = read_exr(cli_render(binary, glb, tmp_path / "cli1.exr", extra=("--passes", str(n))))
    got = read_exr(tmp_path / "blender.exr")
    assert ref[..., :3].mean() > 1e-3
    assert np.allclose(got[..., :3], ref[..., :3], rtol=1e-4, atol=1e-6)


def test_esc_after_the_first_pass_keeps_an_image(addon, binary, tmp_path, monkeypatch):
    """Esc once the first pass is shown: the result keeps at least that pass (a pass already
    running is finished too; whether the second had started when Esc came depends on timing),
    never nothing, and the process is gone."""
    scene = build_scene(tmp_path)
    scene.photongrid.passes = 500
    shown = watch(monkeypatch, "show_image")
    monkeypatch.setattr(photongrid.PhotongridRenderEngine, "cancel_requested", lambda self: bool(shown))
    bpy.ops.render.render(write_still=True)
    counts = [(a[4] if len(a) > 4 else k.get("count"), k.get("final", False)) for a, k in shown]
    assert counts[0] == (1, False) and counts[-1][1] and 1 <= counts[-1][0] < 500, counts
    glb = tmp_path / "reference.glb"
    export_reference_glb(glb)
    n = counts[-1][0]
    ref = read_exr(cli_render(binary, glb, tmp_path / "clin.exr", extra=("--passes", str(n))))
    got = read_exr(tmp_path / "blender.exr")
    assert np.allclose(got[..., :3], ref[..., :3], rtol=1e-4, atol=1e-6)


def test_passes_reach_the_result_with_blender_names(addon, binary, tmp_path, monkeypatch):
    """View Layer > Passes: Depth (Z), Normal, Diffuse Color and the photon passes are in the
    render result under Blender's names, transparent background with Film > Transparent."""
    scene = build_scene(tmp_path)
    layer = scene.view_layers[0]
    layer.use_pass_z = layer.use_pass_normal = layer.use_pass_diffuse_color = True
    layer.photongrid.use_pass_photon_density = layer.photongrid.use_pass_photon_radius = True
    scene.render.film_transparent = True
    # The result's passes as the engine leaves them (Blender 5 saves only Combined in a
    # multilayer EXR when no compositor node tree is set, so the file cannot show them).
    seen = {}
    real = photongrid.PhotongridRenderEngine.show_image

    def show_image(self, *args, **kwargs):
        real(self, *args, **kwargs)
        if kwargs.get("final"):
            for rl in self._result.layers:
                for p in rl.passes:
                    px = np.empty(len(p.rect) * p.channels, dtype=np.float32)
                    p.rect.foreach_get(px)
                    seen[f"{rl.name}.{p.name}"] = px.reshape(-1, p.channels)

    monkeypatch.setattr(photongrid.PhotongridRenderEngine, "show_image", show_image)
    bpy.ops.render.render(write_still=True)
    name = layer.name
    for p in ("Combined", "Depth", "Normal", "DiffCol", "Photon Density", "Photon Radius"):
        assert f"{name}.{p}" in seen, sorted(seen)
    alpha, depth = seen[f"{name}.Combined"][:, 3], seen[f"{name}.Depth"][:, 0]
    background = alpha == 0.0
    assert background.any() and (alpha == 1.0).any(), "the camera sees the sky and the scene"
    assert np.all(depth[background] == 1e10), "Cycles' background depth"
    hit = ~background
    assert np.all((depth[hit] > 1.0) & (depth[hit] < 20.0))
    # The floor faces up in Blender's Z-up world; its albedo is 0.8.
    nz, diff = seen[f"{name}.Normal"][:, 2], seen[f"{name}.DiffCol"][:, 0]
    floor = hit & (nz > 0.99)
    assert floor.sum() > 50, "floor pixels with normal +Z"
    assert np.allclose(diff[floor], 0.8, atol=1e-3)
    radius, density = seen[f"{name}.Photon Radius"][floor, 0], seen[f"{name}.Photon Density"][floor, 0]
    print(f"floor: radius > 0 on {np.mean(radius > 0):.3f}, density > 0 on {np.mean(density > 0):.3f}")
    # Some floor pixels may see no photon (20 k of them); most must.
    assert np.all((radius >= 0) & (density >= 0))
    assert np.mean(radius > 0) > 0.9 and np.mean(density > 0) > 0.9


def test_approximated_materials_reach_the_report(addon, binary, tmp_path, monkeypatch):
    scene = build_scene(tmp_path)
    # Rough metal and plastic are rendered as glTF defines them; rough glass without a volume
    # extension is still approximated (as a solid, as Blender renders it).
    glass = material("Glassy", (0.9, 0.9, 0.9), transmission=1.0, roughness=0.3)
    bpy.data.objects["Wall"].data.materials[0] = glass
    warned = watch(monkeypatch, "show_warning")
    bpy.ops.render.render(write_still=True)
    messages = [a[0] for a, _ in warned]
    assert any("Glassy" in m and "transmission" in m for m in messages), messages
    assert (tmp_path / "blender.exr").is_file()


def test_animation_renders_each_frame(addon, binary, tmp_path):
    scene = build_scene(tmp_path)
    sphere = bpy.data.objects["Sphere"]
    scene.frame_start, scene.frame_end = 1, 2
    sphere.location = (0.4, 0.2, 0.5)
    sphere.keyframe_insert("location", frame=1)
    sphere.location = (-0.6, 0.2, 0.5)
    sphere.keyframe_insert("location", frame=2)
    scene.render.filepath = str(tmp_path / "frame_")
    scene.render.use_file_extension = True
    bpy.ops.render.render(animation=True)
    frames = [read_exr(tmp_path / f"frame_{i:04d}.exr")[..., :3] for i in (1, 2)]
    assert all(f.mean() > 1e-3 for f in frames)
    assert np.abs(frames[0] - frames[1]).mean() > 0.02 * frames[0].mean(), "the sphere moved"


def test_missing_binary_reports_what_to_do(addon, monkeypatch, tmp_path):
    build_scene(tmp_path)
    monkeypatch.delenv(core.ENV_VAR, raising=False)
    empty = tmp_path / "empty-path"
    empty.mkdir()
    monkeypatch.setenv("PATH", str(empty))
    # The engine reports an ERROR; the operator passes it on as a RuntimeError (in the UI: the
    # status bar and the Info editor), and Blender goes on.
    with pytest.raises(RuntimeError) as info:
        bpy.ops.render.render(write_still=True)
    message = str(info.value)
    assert core.MISSING_BINARY_MESSAGE in message, message
    assert "Preferences > Add-ons > photongrid" in message and "PATH" in message
    assert not (tmp_path / "blender.exr").exists()


def test_cli_error_reaches_the_report(addon, binary, tmp_path):
    scene = build_scene(tmp_path)
    scene.photongrid.alpha = 2.0  # the panel allows it; the renderer refuses it, saying why
    with pytest.raises(RuntimeError) as info:
        bpy.ops.render.render(write_still=True)
    message = str(info.value)
    assert "photongrid failed" in message and "--alpha must be between 0 and 1" in message, message


INSTALLED_SCRIPT = r'''
import os, sys, pathlib, subprocess
sys.path.insert(0, os.environ["TESTS_DIR"])
import bpy
zip_path, binary, out_dir = sys.argv[1:4]
r = bpy.ops.extensions.package_install_files(filepath=zip_path, repo="user_default", enable_on_install=True)
assert r == {"FINISHED"}, r
addon = bpy.context.preferences.addons.get("bl_ext.user_default.photongrid")
assert addon is not None, [a.module for a in bpy.context.preferences.addons]
import test_addon  # the scene builder; it imports the repository's package too, unregistered
ext = sys.modules["bl_ext.user_default.photongrid"]
out = pathlib.Path(out_dir)
# Nothing set (no preference, no PHOTONGRID_BIN, none on PATH): the binary the extension carries.
assert "PHOTONGRID_BIN" not in os.environ
used = ext.core.find_binary(ext.configured_binary())
assert used.startswith(os.path.dirname(ext.__file__)), used
assert os.access(used, os.X_OK)
scene = test_addon.build_scene(out)
assert scene.photongrid.photons == test_addon.PHOTONS  # the panel's properties exist
bpy.ops.render.render(write_still=True)
assert (out / "blender.exr").is_file()
os.rename(out / "blender.exr", out / "bundled.exr")
# PHOTONGRID_BIN overrides it: a wrapper that logs its use, then runs the real binary.
log = out / "wrapper.log"
wrapper = out / "wrapper"
wrapper.write_text(f"#!/bin/sh\necho used >> {log}\nexec {binary} \"$@\"\n")
wrapper.chmod(0o755)
os.environ["PHOTONGRID_BIN"] = str(wrapper)
scene = test_addon.build_scene(out)
bpy.ops.render.render(write_still=True)
assert log.is_file() and (out / "blender.exr").is_file()
del os.environ["PHOTONGRID_BIN"]
# The preference overrides both; a wrong one is an error naming it, not a silent fallback.
scene = test_addon.build_scene(out)
addon.preferences.binary_path = str(out / "no-such-photongrid")
try:
    bpy.ops.render.render(write_still=True)
    raise SystemExit("no error for a wrong binary path")
except RuntimeError as e:
    assert "from the add-on preferences" in str(e), e
addon.preferences.binary_path = ""
print("INSTALLED-OK")
'''


def extension_zip(binary, tmp_path):
    """The platform zip: the one CI built (PHOTONGRID_EXTENSION_ZIP), else built here around
    ``binary``."""
    given = os.environ.get("PHOTONGRID_EXTENSION_ZIP")
    if given:
        assert os.path.isfile(given), given
        return given
    dist = tmp_path / "dist"
    build = subprocess.run([sys.executable, os.path.join(REPO, "plugin", "build_extension.py"),
                            "--binary", binary, "--output-dir", str(dist)], capture_output=True, text=True)
    assert build.returncode == 0, build.stdout + build.stderr
    (zip_path,) = dist.glob("photongrid-*-linux_x64.zip")
    return str(zip_path)


def test_installed_extension_renders_with_its_own_binary(binary, tmp_path):
    """The platform zip installed as a real extension (bl_ext.user_default.photongrid) renders
    with nothing set: neither the preferences nor PHOTONGRID_BIN nor PATH has a binary. A
    fresh Python, so that Blender's user folders can point into tmp_path."""
    import zipfile

    zip_path = extension_zip(binary, tmp_path)
    with zipfile.ZipFile(zip_path) as z:
        names = z.namelist()
        manifest = z.read("blender_manifest.toml").decode()
    assert "bin/photongrid" in names and "settings_schema.json" in names, names
    assert 'platforms = ["linux-x64"]' in manifest, manifest
    script = tmp_path / "installed.py"
    script.write_text(INSTALLED_SCRIPT)
    out = tmp_path / "out"
    out.mkdir()
    env = dict(os.environ, BLENDER_USER_RESOURCES=str(tmp_path / "blender-user"), TESTS_DIR=HERE,
               PATH=os.pathsep.join(p for p in os.environ.get("PATH", "").split(os.pathsep)
                                    if not os.path.isfile(os.path.join(p, "photongrid"))))
    env.pop(core.ENV_VAR, None)
    run = subprocess.run([sys.executable, str(script), zip_path, binary, str(out)], env=env,
                         capture_output=True, text=True, timeout=600)
    assert run.returncode == 0 and "INSTALLED-OK" in run.stdout, run.stdout[-3000:] + run.stderr[-3000:]
    assert read_exr(out / "bundled.exr")[..., :3].mean() > 1e-3
