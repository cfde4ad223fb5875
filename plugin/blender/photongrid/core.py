# SPDX-License-Identifier: GPL-3.0-or-later
"""The add-on's core as plain Python, testable without a RenderEngine.

- ``find_binary``: where the ``photongrid`` executable is.
- ``gltf_export_options`` / ``export_scene``: the scene to a .glb with Blender's own exporter.
- ``build_command``: the ``photongrid render`` command line for one camera.
- ``parse_event`` / ``ProgressTracker``: the CLI's ``--progress json`` lines to a phase and
  an overall fraction.
- ``run_process``: runs the command, reads stderr in a thread, hands events to a callback
  on the calling thread, stops the process when asked to cancel (terminate, then kill).
- ``run_photongrid``: export → process → path of the rendered EXR.

Nothing here imports ``bpy`` at module level; ``export_scene`` and ``run_photongrid`` import
it when called.
"""

from __future__ import annotations

import dataclasses
import json
import os
import queue
import shutil
import subprocess
import sys
import threading
import time
from typing import Callable, Iterable, Optional

BINARY_NAME = "photongrid"
ENV_VAR = "PHOTONGRID_BIN"
MISSING_BINARY_MESSAGE = (
    "photongrid binary not found: set its path in Preferences > Add-ons > photongrid, "
    "or put it on PATH"
)

# Share of the overall progress bar per CLI phase; the small phases split the rest (5 %).
PHASE_WEIGHTS = {
    "load": 0.01,
    "bvh": 0.01,
    "photons": 0.40,
    "build": 0.02,
    "render": 0.55,
    "write": 0.01,
}


class PhotongridError(Exception):
    """A render that could not be done; the message says why and what to do."""


class MissingBinaryError(PhotongridError):
    """No photongrid executable was found."""


class Cancelled(PhotongridError):
    """The user cancelled the render (Esc); the process has been stopped."""


# --------------------------------------------------------------------------------------
# The binary


def _executable(path: str) -> Optional[str]:
    """``path`` if it is an executable file, or the photongrid executable inside a folder."""
    if os.path.isdir(path):
        for name in (BINARY_NAME, BINARY_NAME + ".exe"):
            candidate = os.path.join(path, name)
            if os.path.isfile(candidate) and os.access(candidate, os.X_OK):
                return candidate
        return None
    if os.path.isfile(path) and os.access(path, os.X_OK):
        return path
    return None


def find_binary(configured: str = "", env: Optional[dict] = None) -> str:
    """The photongrid executable to run.

    Order: the path set in the add-on preferences (an error if set but wrong, rather than
    silently running another binary), then the ``PHOTONGRID_BIN`` environment variable, then
    ``photongrid`` on ``PATH``. Raises ``MissingBinaryError`` with what to do when none is found.
    """
    env = os.environ if env is None else env
    configured = (configured or "").strip()
    if configured:
        path = os.path.abspath(os.path.expanduser(configured))
        found = _executable(path)
        if found:
            return found
        raise MissingBinaryError(
            f"photongrid binary not found at '{path}' (from the add-on preferences): set its path "
            "in Preferences > Add-ons > photongrid, or clear it to use photongrid on PATH"
        )
    from_env = (env.get(ENV_VAR) or "").strip()
    if from_env:
        found = _executable(os.path.abspath(os.path.expanduser(from_env)))
        if found:
            return found
    on_path = shutil.which(BINARY_NAME, path=env.get("PATH"))
    if on_path:
        return on_path
    if from_env:
        raise MissingBinaryError(f"{MISSING_BINARY_MESSAGE} ({ENV_VAR}='{from_env}' is not an executable file)")
    raise MissingBinaryError(MISSING_BINARY_MESSAGE)


# --------------------------------------------------------------------------------------
# Settings and the command line


@dataclasses.dataclass
class RenderSettings:
    """What the panel sets; ``None``/empty means "the CLI's default, not passed"."""

    photons: int = 2_000_000
    neighbours: int = 100
    spp: int = 4
    seed: int = 0
    direct: str = "shadow-rays"  # or "photons"
    threads: Optional[int] = None
    # Options of future methods: passed only when set.
    method: str = ""
    grid: str = ""
    time_budget: str = ""


def build_command(
    binary: str,
    scene_path: str,
    camera: Optional[str],
    output: str,
    width: int,
    height: int,
    settings: RenderSettings,
) -> list:
    """The ``photongrid render`` command for one camera (by glTF node name)."""
    if settings.direct not in ("shadow-rays", "photons"):
        raise PhotongridError(f"direct lighting must be 'shadow-rays' or 'photons', not '{settings.direct}'")
    cmd = [binary, "render", scene_path]
    if camera:
        # "--camera=NAME" so that a name starting with "-" is not taken for an option.
        cmd.append(f"--camera={camera}")
    cmd += [
        f"--output={output}",
        "--width", str(int(width)),
        "--height", str(int(height)),
        "--photons", str(int(settings.photons)),
        "--neighbours", str(int(settings.neighbours)),
        "--spp", str(int(settings.spp)),
        "--seed", str(int(settings.seed)),
        "--direct", settings.direct,
        "--progress", "json",
    ]
    if settings.threads:
        cmd += ["--threads", str(int(settings.threads))]
    for flag, value in (
        ("--method", settings.method),
        ("--grid", settings.grid),
        ("--time-budget", settings.time_budget),
    ):
        value = (value or "").strip()
        if value:
            cmd.append(f"{flag}={value}")
    return cmd


# --------------------------------------------------------------------------------------
# Progress


def parse_event(line) -> Optional[dict]:
    """One ``--progress json`` line as a dict with an ``event`` key, or ``None`` for other lines."""
    if isinstance(line, bytes):
        line = line.decode("utf-8", "replace")
    line = line.strip()
    if not line.startswith("{"):
        return None
    try:
        value = json.loads(line)
    except ValueError:
        return None
    if not isinstance(value, dict) or not isinstance(value.get("event"), str):
        return None
    return value


class ProgressTracker:
    """Turns events into (phase name, overall fraction in [0, 1], never going back)."""

    def __init__(self, weights: Optional[dict] = None):
        self.weights = dict(PHASE_WEIGHTS if weights is None else weights)
        self.finished: set = set()
        self.phase: Optional[str] = None
        self.phase_fraction = 0.0
        self.fraction = 0.0

    def update(self, event: dict) -> bool:
        """Take one event; True when the phase or the fraction changed."""
        kind = event.get("event")
        phase = event.get("phase")
        before = (self.phase, self.fraction)
        if kind == "start" and phase:
            self.phase, self.phase_fraction = phase, 0.0
        elif kind == "progress" and phase:
            self.phase = phase
            try:
                f = float(event.get("fraction", 0.0))
            except (TypeError, ValueError):
                f = 0.0
            self.phase_fraction = min(max(f, 0.0), 1.0)
        elif kind == "end" and phase:
            self.finished.add(phase)
            self.phase, self.phase_fraction = phase, 1.0
        else:
            return False
        done = sum(self.weights.get(p, 0.0) for p in self.finished)
        if self.phase and self.phase not in self.finished:
            done += self.weights.get(self.phase, 0.0) * self.phase_fraction
        self.fraction = max(self.fraction, min(done, 1.0))
        return (self.phase, self.fraction) != before


# --------------------------------------------------------------------------------------
# The process


@dataclasses.dataclass
class ProcessResult:
    returncode: Optional[int]
    cancelled: bool
    error: Optional[str]  # the CLI's message when it failed
    outputs: list  # paths from "output" events
    log: list  # stderr lines that were not JSON events

    @property
    def ok(self) -> bool:
        return not self.cancelled and self.returncode == 0


def _reader(stream, sink: "queue.Queue") -> None:
    try:
        for raw in iter(stream.readline, b""):
            sink.put(raw.decode("utf-8", "replace").rstrip("\r\n"))
    except (OSError, ValueError):
        pass
    finally:
        sink.put(None)


def stop_process(proc: subprocess.Popen, grace_seconds: float = 3.0) -> None:
    """Terminate ``proc``, and kill it if it is still there after ``grace_seconds``."""
    if proc.poll() is not None:
        return
    try:
        proc.terminate()
    except OSError:
        pass
    try:
        proc.wait(timeout=grace_seconds)
    except subprocess.TimeoutExpired:
        try:
            proc.kill()
        except OSError:
            pass
        proc.wait()


def run_process(
    cmd: list,
    on_event: Optional[Callable[[dict], None]] = None,
    should_cancel: Optional[Callable[[], bool]] = None,
    on_log: Optional[Callable[[str], None]] = None,
    poll_interval: float = 0.05,
    grace_seconds: float = 3.0,
    on_start: Optional[Callable[[subprocess.Popen], None]] = None,
) -> ProcessResult:
    """Run ``cmd``; ``on_event`` and ``should_cancel`` are called on this thread only."""
    kwargs = {}
    if os.name == "nt":
        kwargs["creationflags"] = getattr(subprocess, "CREATE_NO_WINDOW", 0)
    try:
        proc = subprocess.Popen(
            cmd,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            **kwargs,
        )
    except OSError as e:
        raise PhotongridError(f"could not start {cmd[0]}: {e}") from e
    if on_start:
        on_start(proc)
    lines: "queue.Queue" = queue.Queue()
    reader = threading.Thread(target=_reader, args=(proc.stderr, lines), name="photongrid-stderr", daemon=True)
    reader.start()
    outputs, log, errors = [], [], []
    cancelled = False
    eof = False

    def drain(block_seconds: float) -> None:
        nonlocal eof
        deadline = time.monotonic() + block_seconds
        while True:
            timeout = max(0.0, deadline - time.monotonic())
            try:
                line = lines.get(timeout=timeout) if timeout > 0 else lines.get_nowait()
            except queue.Empty:
                return
            if line is None:
                eof = True
                return
            event = parse_event(line)
            if event is None:
                if line.strip():
                    log.append(line)
                    if on_log:
                        on_log(line)
                continue
            kind = event.get("event")
            if kind == "error":
                errors.append(str(event.get("message", "")))
            elif kind == "output" and event.get("path"):
                outputs.append(str(event["path"]))
            if on_event:
                on_event(event)

    try:
        while proc.poll() is None:
            drain(poll_interval)
            if should_cancel and should_cancel():
                cancelled = True
                stop_process(proc, grace_seconds)
                break
        # The process has exited: read what is left of stderr.
        reader.join(timeout=5.0)
        while not eof:
            before = lines.qsize()
            drain(0.0 if before else 0.05)
            if not before and not reader.is_alive():
                break
    except BaseException:
        stop_process(proc, grace_seconds)
        raise
    finally:
        if proc.stderr:
            try:
                proc.stderr.close()
            except OSError:
                pass
    rc = proc.returncode
    error = None
    if not cancelled and rc != 0:
        if errors:
            error = errors[-1]
        else:
            tail = [l for l in log if l.lower().startswith("error")] or log[-5:]
            error = "\n".join(tail) if tail else f"exited with code {rc}"
    return ProcessResult(returncode=rc, cancelled=cancelled, error=error, outputs=outputs, log=log)


# --------------------------------------------------------------------------------------
# Export with Blender's glTF exporter


def gltf_export_options(filepath: str) -> dict:
    """The exporter options: what a render needs, in the units photongrid expects."""
    return dict(
        filepath=filepath,
        check_existing=False,
        export_format="GLB",
        # Lights in physical units (cd, lx, nt): "Standard" lighting mode.
        export_import_convert_lighting_mode="SPEC",
        export_cameras=True,
        export_lights=True,
        export_apply=True,  # modifiers applied
        export_yup=True,
        # The whole active scene, as rendered (not the selection, not viewport visibility).
        use_selection=False,
        use_visible=False,
        use_renderable=True,
        use_active_collection=False,
        use_active_scene=True,
        # Materials and their textures, embedded in the .glb.
        export_materials="EXPORT",
        export_image_format="AUTO",
        export_keep_originals=False,
        export_texcoords=True,
        export_normals=True,
        export_tangents=False,
        # Nothing the renderer does not read.
        export_animations=False,
        export_current_frame=True,
        export_skins=False,
        export_morph=False,
        export_extras=False,
        export_attributes=False,
        export_draco_mesh_compression_enable=False,
        export_use_gltfpack=False,
        export_gpu_instances=False,
        export_unused_images=False,
        export_unused_textures=False,
        # Do not store these options in the .blend.
        will_save_settings=False,
    )


def supported_options(options: dict, known: Iterable[str]) -> dict:
    """``options`` less those this Blender's exporter does not have (4.2 has fewer than 5.x)."""
    known = set(known)
    return {k: v for k, v in options.items() if k in known}


def export_scene(scene, filepath: str) -> str:
    """Export ``scene`` to ``filepath`` (.glb) with Blender's glTF exporter."""
    import bpy

    op = bpy.ops.export_scene.gltf
    known = op.get_rna_type().properties.keys()
    options = supported_options(gltf_export_options(filepath), known)
    override = {"scene": scene}
    view_layer = getattr(bpy.context, "view_layer", None)
    if view_layer is None or scene.view_layers.get(view_layer.name) is None:
        override["view_layer"] = scene.view_layers[0]
    try:
        with bpy.context.temp_override(**override):
            result = op(**options)
    except RuntimeError as e:
        raise PhotongridError(f"glTF export failed: {e}") from e
    if "FINISHED" not in result or not os.path.isfile(filepath):
        raise PhotongridError(f"glTF export failed ({', '.join(sorted(result))}): {filepath} was not written")
    return filepath


# --------------------------------------------------------------------------------------
# The EXR back into Blender


def _import_oiio():
    """OpenImageIO's Python module, which Blender bundles; None if it cannot be imported.

    Blender-as-a-module (``pip install bpy``) ships it too, but not on ``sys.path``."""
    try:
        import OpenImageIO

        return OpenImageIO
    except ImportError:
        pass
    try:
        import bpy

        local = bpy.utils.resource_path("LOCAL")
    except Exception:  # noqa: BLE001 - any failure means "not available"
        return None
    version = f"python{sys.version_info.major}.{sys.version_info.minor}"
    site = os.path.join(local, "python", "lib", version, "site-packages")
    if not os.path.isdir(os.path.join(site, "OpenImageIO")):
        return None
    if site not in sys.path:
        sys.path.append(site)
    try:
        import OpenImageIO

        return OpenImageIO
    except ImportError:
        return None


def read_exr_rgba(path: str, width: int, height: int):
    """The EXR's pixels as a flat float32 RGBA array, bottom row first (Blender's order).

    The file's floats are kept as they are (scene-linear radiance, like the CLI's output);
    alpha is 1 where the file has none. Reads with OpenImageIO when it can, else through
    ``bpy.data.images`` (a temporary image, removed again).
    """
    import numpy as np

    oiio = _import_oiio()
    if oiio is not None:
        inp = oiio.ImageInput.open(path)
        if inp is None:
            raise PhotongridError(f"cannot read {path}: {oiio.geterror()}")
        try:
            spec = inp.spec()
            pixels = inp.read_image(0, 0, 0, spec.nchannels, "float")
        finally:
            inp.close()
        if pixels is None:
            raise PhotongridError(f"cannot read {path}: {oiio.geterror()}")
        pixels = np.asarray(pixels, dtype=np.float32).reshape(spec.height, spec.width, spec.nchannels)
        names = list(spec.channelnames)
        if (spec.width, spec.height) != (width, height):
            raise PhotongridError(f"{path} is {spec.width}×{spec.height}, expected {width}×{height}")
        rgba = np.ones((height, width, 4), dtype=np.float32)
        for i, c in enumerate("RGBA"):
            if c in names:
                rgba[..., i] = pixels[..., names.index(c)]
            elif c != "A":
                raise PhotongridError(f"{path} has no channel {c} (channels: {', '.join(names)})")
        return np.ascontiguousarray(rgba[::-1]).ravel()  # EXR: top row first

    import bpy

    img = bpy.data.images.load(path, check_existing=False)
    try:
        if tuple(img.size) != (width, height):
            raise PhotongridError(f"{path} is {img.size[0]}×{img.size[1]}, expected {width}×{height}")
        flat = np.empty(width * height * 4, dtype=np.float32)
        img.pixels.foreach_get(flat)  # already bottom row first
        return flat
    finally:
        bpy.data.images.remove(img)


def render_size(scene) -> tuple:
    """Width and height of the render: resolution × percentage, as Blender computes it."""
    r = scene.render
    pct = r.resolution_percentage
    return max(1, int(r.resolution_x * pct / 100)), max(1, int(r.resolution_y * pct / 100))


def settings_from_scene(scene) -> RenderSettings:
    """The panel's settings (``scene.photongrid``) and Blender's thread count."""
    props = getattr(scene, "photongrid", None)
    s = RenderSettings()
    if props is not None:
        s.photons = int(props.photons)
        s.neighbours = int(props.neighbours)
        s.spp = int(props.spp)
        s.seed = int(props.seed)
        s.direct = "photons" if props.direct == "PHOTONS" else "shadow-rays"
        s.method = "" if props.method == "DEFAULT" else props.method.lower()
        s.grid = "" if props.grid == "DEFAULT" else props.grid.lower()
        s.time_budget = props.time_budget
    r = scene.render
    if getattr(r, "threads_mode", "AUTO") == "FIXED":
        s.threads = int(r.threads)
    return s


def run_photongrid(
    scene,
    workdir: str,
    binary: str,
    settings: Optional[RenderSettings] = None,
    camera: Optional[str] = None,
    size: Optional[tuple] = None,
    on_status: Optional[Callable[[str], None]] = None,
    on_progress: Optional[Callable[[float], None]] = None,
    should_cancel: Optional[Callable[[], bool]] = None,
    on_start: Optional[Callable[[subprocess.Popen], None]] = None,
    grace_seconds: float = 3.0,
) -> str:
    """Export ``scene`` into ``workdir``, render its camera with photongrid, return the EXR's path.

    ``camera``: the glTF node name (the camera object's name), default the scene's camera.
    Raises ``Cancelled`` when ``should_cancel`` said so, ``PhotongridError`` on failure.
    """
    settings = settings or settings_from_scene(scene)
    if camera is None:
        if scene.camera is None:
            raise PhotongridError("the scene has no active camera: set one in Scene properties > Camera")
        camera = scene.camera.name
    width, height = size or render_size(scene)
    status = on_status or (lambda s: None)
    progress = on_progress or (lambda f: None)

    glb = os.path.join(workdir, "scene.glb")
    out = os.path.join(workdir, "out.exr")
    status("photongrid: exporting glTF")
    export_scene(scene, glb)
    if should_cancel and should_cancel():
        raise Cancelled("cancelled")

    cmd = build_command(binary, glb, camera, out, width, height, settings)
    tracker = ProgressTracker()

    def on_event(event: dict) -> None:
        if tracker.update(event):
            status(f"photongrid: {tracker.phase}")
            progress(tracker.fraction)

    def on_log(line: str) -> None:
        print(f"photongrid: {line}", file=sys.stderr)

    result = run_process(
        cmd,
        on_event=on_event,
        should_cancel=should_cancel,
        on_log=on_log,
        grace_seconds=grace_seconds,
        on_start=on_start,
    )
    if result.cancelled:
        raise Cancelled("cancelled")
    if not result.ok:
        raise PhotongridError(f"photongrid failed: {result.error}")
    path = result.outputs[-1] if result.outputs else out
    if not os.path.isfile(path):
        raise PhotongridError(f"photongrid finished but wrote no image at {path}")
    progress(1.0)
    return path
