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
    photongrid.register()
    yield photongrid
    photongrid.unregister()


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


def test_engine_is_registered(addon):
    render = bpy.context.scene.render
    render.engine = "PHOTONGRID"  # a TypeError if no such engine is registered
    assert render.engine == "PHOTONGRID"
    assert hasattr(bpy.types.Scene, "photongrid")
    panel = photongrid.RENDER_PT_photongrid
    assert panel.poll(SimpleNamespace(engine="PHOTONGRID"))
    assert not panel.poll(SimpleNamespace(engine="CYCLES"))


@pytest.mark.parametrize("direct", ["SHADOW_RAYS", "PHOTONS"])
def test_f12_matches_cli(addon, binary, tmp_path, direct):
    scene = build_scene(tmp_path)
    scene.photongrid.direct = direct
    if direct == "PHOTONS":  # and Blender's fixed thread count, passed as --threads
        scene.render.threads_mode, scene.render.threads = "FIXED", 1
    t = time.monotonic()
    bpy.ops.render.render(write_still=True)
    blender_seconds = time.monotonic() - t
    out = tmp_path / "blender.exr"
    assert out.is_file(), "the render was not saved"

    glb = tmp_path / "reference.glb"
    export_reference_glb(glb)
    ref_path = cli_render(binary, glb, tmp_path / "cli.exr", direct=direct.lower().replace("_", "-"))

    got, ref = read_exr(out), read_exr(ref_path)
    assert got.shape == ref.shape == (HEIGHT, WIDTH, 4)
    rgb, ref_rgb = got[..., :3], ref[..., :3]
    assert np.isfinite(rgb).all()
    assert ref_rgb.mean() > 1e-3, "the reference is black: the scene is not lit"
    assert np.allclose(got[..., 3], 1.0)
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
    with_oiio = core.read_exr_rgba(exr, WIDTH, HEIGHT)
    monkeypatch.setattr(core, "_import_oiio", lambda: None)
    with_images = core.read_exr_rgba(exr, WIDTH, HEIGHT)
    assert with_oiio.shape == with_images.shape == (WIDTH * HEIGHT * 4,)
    assert np.array_equal(with_oiio, with_images)
    assert len(bpy.data.images) == 0, "the temporary image was not removed"
    with pytest.raises(core.PhotongridError, match="expected"):
        core.read_exr_rgba(exr, WIDTH + 1, HEIGHT)


def test_progress_shows_phases(addon, binary, tmp_path, monkeypatch):
    build_scene(tmp_path)
    statuses, fractions = [], []
    monkeypatch.setattr(photongrid.PhotongridRenderEngine, "show_status", lambda self, text: statuses.append(text))
    monkeypatch.setattr(photongrid.PhotongridRenderEngine, "show_progress", lambda self, f: fractions.append(f))
    bpy.ops.render.render()
    for phase in ("exporting glTF", "load", "bvh", "photons", "build", "render"):
        assert f"photongrid: {phase}" in statuses, statuses
    assert fractions == sorted(fractions) and fractions[-1] == 1.0, fractions
    # Photons weigh ~40 % (the bar is at ~42 % when they are done), the camera pass ~55 %.
    assert any(0.40 <= f <= 0.45 for f in fractions), fractions


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
    scene.photongrid.time_budget = "soon"  # passed because it is set; the CLI rejects it
    with pytest.raises(RuntimeError) as info:
        bpy.ops.render.render(write_still=True)
    message = str(info.value)
    assert "photongrid failed" in message and "time" in message, message


def test_cancel_stops_the_process(addon, binary, tmp_path, monkeypatch):
    scene = build_scene(tmp_path)
    scene.photongrid.photons = 20_000_000  # many seconds of work, unless cancelled
    started = []
    real_popen = core.subprocess.Popen

    def popen(*args, **kwargs):
        proc = real_popen(*args, **kwargs)
        started.append(proc)
        return proc

    progress_seen = []
    real_update = core.ProgressTracker.update

    def update(self, event):
        if event.get("event") == "progress":
            progress_seen.append(event)
        return real_update(self, event)

    monkeypatch.setattr(core.subprocess, "Popen", popen)
    monkeypatch.setattr(core.ProgressTracker, "update", update)
    # Esc after the first progress event. (test_break itself is an RNA function, which a Python
    # attribute of the same name does not override; the engine polls it through this method.)
    monkeypatch.setattr(photongrid.PhotongridRenderEngine, "cancel_requested", lambda self: bool(progress_seen))
    t = time.monotonic()
    try:
        bpy.ops.render.render(write_still=False)
    except RuntimeError as e:
        pytest.fail(f"a cancelled render is not an error: {e}")
    seconds = time.monotonic() - t
    assert len(started) == 1 and progress_seen
    proc = started[0]
    assert proc.poll() is not None, "the photongrid process is still running"
    assert proc.returncode != 0  # terminated, not finished
    with pytest.raises(ProcessLookupError):
        os.kill(proc.pid, 0)
    assert seconds < 60, seconds


INSTALLED_SCRIPT = r'''
import os, sys, pathlib
sys.path.insert(0, os.environ["TESTS_DIR"])
import bpy
zip_path, binary, out_dir = sys.argv[1:4]
r = bpy.ops.extensions.package_install_files(filepath=zip_path, repo="user_default", enable_on_install=True)
assert r == {"FINISHED"}, r
addon = bpy.context.preferences.addons.get("bl_ext.user_default.photongrid")
assert addon is not None, [a.module for a in bpy.context.preferences.addons]
import test_addon  # the scene builder; it imports the repository's package too, unregistered
out = pathlib.Path(out_dir)
# A wrong path in the preferences is an error naming it, not a silent fallback to PATH.
scene = test_addon.build_scene(out)
addon.preferences.binary_path = str(out / "no-such-photongrid")
try:
    bpy.ops.render.render(write_still=True)
    raise SystemExit("no error for a wrong binary path")
except RuntimeError as e:
    assert "from the add-on preferences" in str(e), e
# The right path: it renders (same scene as test_f12_matches_cli).
addon.preferences.binary_path = binary
scene = test_addon.build_scene(out)
bpy.ops.render.render(write_still=True)
assert (out / "blender.exr").is_file()
print("INSTALLED-OK")
'''


def test_installed_extension_uses_preferences(binary, tmp_path):
    """The zip installed as a real extension (bl_ext.user_default.photongrid) with the binary
    set in its preferences only: neither PHOTONGRID_BIN nor PATH has it. A fresh Python, so
    that Blender's user folders can point into tmp_path."""
    dist = tmp_path / "dist"
    build = subprocess.run([sys.executable, os.path.join(REPO, "plugin", "build_extension.py"),
                            "--output-dir", str(dist)], capture_output=True, text=True)
    assert build.returncode == 0, build.stdout + build.stderr
    (zip_path,) = dist.glob("photongrid-*.zip")
    script = tmp_path / "installed.py"
    script.write_text(INSTALLED_SCRIPT)
    out = tmp_path / "out"
    out.mkdir()
    env = dict(os.environ, BLENDER_USER_RESOURCES=str(tmp_path / "blender-user"), TESTS_DIR=HERE,
               PATH=os.pathsep.join(p for p in os.environ.get("PATH", "").split(os.pathsep)
                                    if not os.path.isfile(os.path.join(p, "photongrid"))))
    env.pop(core.ENV_VAR, None)
    run = subprocess.run([sys.executable, str(script), str(zip_path), binary, str(out)], env=env,
                         capture_output=True, text=True, timeout=600)
    assert run.returncode == 0 and "INSTALLED-OK" in run.stdout, run.stdout[-3000:] + run.stderr[-3000:]
    assert read_exr(out / "blender.exr")[..., :3].mean() > 1e-3
