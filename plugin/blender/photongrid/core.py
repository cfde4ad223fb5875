# SPDX-License-Identifier: GPL-3.0-or-later
"""The add-on's core as plain Python, testable without a RenderEngine.

- ``find_binary``: where the ``photongrid`` executable is (the preferences, ``PHOTONGRID_BIN``,
  the binary inside the extension, ``PATH``).
- ``schema_from_binary`` / ``property_specs``: the binary's own description of its settings
  (``photongrid settings --schema``, run once per binary and cached) turned into the panel's
  properties: names, defaults, choices and tooltips are the binary's, never copies.
- ``gltf_export_options`` / ``export_scene``: the scene to a .glb with Blender's own exporter.
- ``build_command``: the ``photongrid render`` command line for one camera.
- ``parse_event`` / ``ProgressTracker``: the CLI's ``--progress json`` lines to a status and an
  overall fraction that never goes back, over every phase and pass.
- ``run_process``: runs the command, reads stderr in a thread, hands events to a callback on
  the calling thread; asked to cancel, it asks the renderer to stop after the current pass
  (SIGINT, which makes it write the image so far), and stops it outright if that takes too long.
- ``read_exr_channels``: the EXR's channels (colour, alpha and passes) in Blender's row order.
- ``run_photongrid``: export → process (checkpoints and warnings reported as they come) → the
  rendered EXR.

Nothing here imports ``bpy`` at module level; ``export_scene`` and ``run_photongrid`` import
it when called.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
import queue
import shutil
import signal
import stat
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
PACKAGE_DIR = os.path.dirname(os.path.abspath(__file__))
# The binary the platform build of the extension carries (plugin/build_extension.py).
BUNDLED_BINARY = os.path.join(PACKAGE_DIR, "bin", BINARY_NAME + (".exe" if os.name == "nt" else ""))
# The settings schema of that binary, written beside it at build time.
BUNDLED_SCHEMA = os.path.join(PACKAGE_DIR, "settings_schema.json")


class PhotongridError(Exception):
    """A render that could not be done; the message says why and what to do."""


class MissingBinaryError(PhotongridError):
    """No photongrid executable was found."""


class Cancelled(PhotongridError):
    """The user cancelled the render (Esc) and no image was kept; the process has been stopped."""


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


def bundled_binary(path: str = BUNDLED_BINARY) -> Optional[str]:
    """The binary inside the installed extension, made executable if the installer dropped its
    permission bits (Blender extracts extension zips without them); None if there is none."""
    if not os.path.isfile(path):
        return None
    if not os.access(path, os.X_OK):
        try:
            mode = os.stat(path).st_mode
            os.chmod(path, mode | stat.S_IXUSR | stat.S_IXGRP | stat.S_IXOTH)
        except OSError:
            return None
    return path if os.access(path, os.X_OK) else None


def find_binary(configured: str = "", env: Optional[dict] = None, bundled: Optional[str] = BUNDLED_BINARY) -> str:
    """The photongrid executable to run.

    Order: the path set in the add-on preferences (an error if set but wrong, rather than
    silently running another binary), then the ``PHOTONGRID_BIN`` environment variable, then the
    binary inside the extension (``bundled``), then ``photongrid`` on ``PATH``. Raises
    ``MissingBinaryError`` with what to do when none is found.
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
            "in Preferences > Add-ons > photongrid, or clear it to use the one the add-on carries"
        )
    from_env = (env.get(ENV_VAR) or "").strip()
    if from_env:
        found = _executable(os.path.abspath(os.path.expanduser(from_env)))
        if found:
            return found
    if bundled:
        found = bundled_binary(bundled)
        if found:
            return found
    on_path = shutil.which(BINARY_NAME, path=env.get("PATH"))
    if on_path:
        return on_path
    if from_env:
        raise MissingBinaryError(f"{MISSING_BINARY_MESSAGE} ({ENV_VAR}='{from_env}' is not an executable file)")
    raise MissingBinaryError(MISSING_BINARY_MESSAGE)


# --------------------------------------------------------------------------------------
# The settings schema: what the binary says its settings are


EMPTY_SCHEMA = {"version": "", "settings": []}
_schema_memo: dict = {}


def _valid_schema(doc) -> bool:
    return (
        isinstance(doc, dict)
        and isinstance(doc.get("settings"), list)
        and all(isinstance(s, dict) and isinstance(s.get("key"), str) for s in doc["settings"])
    )


def schema_from_binary(binary: str, cache_dir: Optional[str] = None, timeout: float = 30.0) -> dict:
    """``photongrid settings --schema`` of ``binary``, run once per binary (same path, size and
    modification time) and cached in memory and, if given, in ``cache_dir``."""
    try:
        st = os.stat(binary)
    except OSError as e:
        raise PhotongridError(f"cannot read {binary}: {e}") from e
    identity = f"{os.path.realpath(binary)}|{st.st_size}|{st.st_mtime_ns}"
    if identity in _schema_memo:
        return _schema_memo[identity]
    cache_file = None
    if cache_dir:
        cache_file = os.path.join(cache_dir, "schema-" + hashlib.sha1(identity.encode()).hexdigest()[:16] + ".json")
        try:
            with open(cache_file, encoding="utf-8") as f:
                doc = json.load(f)
            if _valid_schema(doc):
                _schema_memo[identity] = doc
                return doc
        except (OSError, ValueError):
            pass
    try:
        run = subprocess.run([binary, "settings", "--schema"], capture_output=True, text=True, timeout=timeout,
                             stdin=subprocess.DEVNULL)
    except (OSError, subprocess.TimeoutExpired) as e:
        raise PhotongridError(f"{binary} settings --schema failed: {e}") from e
    try:
        doc = json.loads(run.stdout) if run.returncode == 0 else None
    except ValueError:
        doc = None
    if not _valid_schema(doc):
        detail = (run.stderr or run.stdout).strip().splitlines()[-1:] or [f"exit code {run.returncode}"]
        raise PhotongridError(f"{binary} settings --schema gave no settings schema: {detail[0]}")
    _schema_memo[identity] = doc
    if cache_file:
        try:
            os.makedirs(cache_dir, exist_ok=True)
            tmp = f"{cache_file}.{os.getpid()}.tmp"
            with open(tmp, "w", encoding="utf-8") as f:
                json.dump(doc, f)
            os.replace(tmp, cache_file)
        except OSError:
            pass
    return doc


def bundled_schema(path: str = BUNDLED_SCHEMA) -> Optional[dict]:
    """The schema written into the extension beside its binary, or None."""
    try:
        with open(path, encoding="utf-8") as f:
            doc = json.load(f)
    except (OSError, ValueError):
        return None
    return doc if _valid_schema(doc) else None


# The panel: which settings each section shows, in order, with the label an artist reads. Their
# tooltips, defaults and choices come from the schema; settings not named here are listed
# under "Advanced". Width and height are Blender's resolution; passes and time are the
# Sampling section's own properties (0 meaning "not set").
SECTIONS = {
    "SAMPLING": ("spp", "seed"),
    "PHOTONS": ("photons", "caustic_photons", "neighbours", "max_photon_depth"),
    "LIGHT_PATHS": ("direct", "gather", "light_samples", "max_depth", "max_specular_depth", "split_depth"),
    "METHOD": ("method", "grid"),
}
NOT_PROPERTIES = ("width", "height", "passes", "time")
LABELS = {
    "spp": "Samples per Pass",
    "seed": "Seed",
    "photons": "Photons",
    "caustic_photons": "Caustic Photons",
    "neighbours": "Neighbours",
    "max_photon_depth": "Photon Bounces",
    "direct": "Direct Light",
    "gather": "Gather Rays",
    "light_samples": "Light Samples",
    "max_depth": "Max Bounces",
    "max_specular_depth": "Specular Bounces",
    "split_depth": "Glass Split Depth",
    "method": "Estimator",
    "grid": "Grid Mode",
}
CHOICE_LABELS = {
    "knn": "kNN",
    "sppm": "SPPM",
    "cdf53": "CDF 5/3",
    "cdf97": "CDF 9/7",
}


@dataclasses.dataclass
class PropertySpec:
    """One setting as a Blender property: ``kind`` is INT, FLOAT, BOOL, ENUM or STRING; enum
    items are ``(value, label, description)`` with the CLI's value as identifier."""

    key: str
    flag: str
    kind: str
    default: object
    label: str
    description: str
    section: str
    items: list = dataclasses.field(default_factory=list)


def _tooltip(text) -> str:
    text = " ".join(str(text or "").split())
    return text if not text or text.endswith(".") else text + "."


def _label(key: str) -> str:
    return LABELS.get(key) or key.replace("_", " ").title()


def property_specs(schema: dict) -> list:
    """The panel's properties, from the binary's schema (settings it does not know are not
    shown; settings the panel does not place are in section ADVANCED)."""
    section_of = {k: name for name, keys in SECTIONS.items() for k in keys}
    order = {k: i for i, k in enumerate(k for keys in SECTIONS.values() for k in keys)}
    specs = []
    for s in schema.get("settings", []):
        key = s["key"]
        if key in NOT_PROPERTIES:
            continue
        kind = {"integer": "INT", "number": "FLOAT", "boolean": "BOOL", "choice": "ENUM"}.get(s.get("type"), "STRING")
        default = s.get("default")
        items = []
        if kind == "ENUM":
            items = [
                (c["value"], CHOICE_LABELS.get(c["value"], c["value"].replace("-", " ").title()), _tooltip(c.get("help")))
                for c in s.get("choices", [])
            ]
            if not items:
                kind = "STRING"
        if default is None:  # an optional setting the panel has no place for: text, passed when set
            kind, default = "STRING", ""
        if kind == "INT" and not (isinstance(default, int) and 0 <= default < 2**31):
            kind, default = "STRING", str(default)
        specs.append(PropertySpec(
            key=key,
            flag=s.get("flag") or "--" + key.replace("_", "-"),
            kind=kind,
            default=default,
            label=_label(key),
            description=_tooltip(s.get("help")),
            section=section_of.get(key, "ADVANCED"),
            items=items,
        ))
    specs.sort(key=lambda sp: (sp.section == "ADVANCED", order.get(sp.key, len(order)), sp.key))
    return specs


def schema_help(schema: dict, key: str) -> str:
    """A setting's help text from the schema (tooltips of the properties the panel defines
    itself: passes, time)."""
    for s in schema.get("settings", []):
        if s.get("key") == key:
            return _tooltip(s.get("help"))
    return ""


# Quality presets: multiples of the binary's defaults (Default is the defaults themselves).
QUALITY_PRESETS = (
    ("PREVIEW", "Preview", "Fast look: an eighth of the default photons, 1 sample and half the gather rays per pass"),
    ("DEFAULT", "Default", "The renderer's defaults"),
    ("HIGH", "High", "Twice the default photons, caustic photons and samples per pass"),
)


def quality_values(preset: str, defaults: dict) -> dict:
    """The values a quality preset sets, from the settings' ``defaults`` (key → value)."""
    scale = {
        "PREVIEW": {"photons": 1 / 8, "caustic_photons": 1 / 8, "spp": None, "gather": 1 / 2},
        "DEFAULT": {"photons": 1, "caustic_photons": 1, "spp": 1, "gather": 1},
        "HIGH": {"photons": 2, "caustic_photons": 2, "spp": 2, "gather": 1},
    }[preset]
    out = {}
    for key, factor in scale.items():
        d = defaults.get(key)
        if not isinstance(d, int):
            continue
        out[key] = 1 if factor is None else max(1 if d > 0 else 0, int(round(d * factor)))
    return out


def same_value(a, b) -> bool:
    """Equal as settings: floats within Blender's single precision."""
    if isinstance(a, float) or isinstance(b, float):
        try:
            return math.isclose(float(a), float(b), rel_tol=1e-6, abs_tol=1e-9)
        except (TypeError, ValueError):
            return False
    return a == b


def _flag_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return f"{value:.7g}"
    return str(value)


# --------------------------------------------------------------------------------------
# Settings and the command line


@dataclasses.dataclass
class RenderSettings:
    """What the panel sets. ``values``: setting key → value, the settings that differ from the
    binary's defaults (the others are not passed). ``passes`` 0 and ``time_limit`` 0 mean "not
    set": one pass without a time limit, as many as fit with one."""

    values: dict = dataclasses.field(default_factory=dict)
    passes: int = 1
    time_limit: float = 0.0
    threads: Optional[int] = None
    aovs: bool = False
    flags: dict = dataclasses.field(default_factory=dict)  # key → flag, when not --key-with-dashes

    @property
    def progressive(self) -> bool:
        """More than one pass may run (then each finished pass is shown)."""
        return self.time_limit > 0 or self.passes > 1


def settings_values(specs: Iterable, get: Callable[[str], object]) -> dict:
    """Key → value of the settings whose value (``get(key)``) differs from the default."""
    out = {}
    for sp in specs:
        value = get(sp.key)
        if sp.kind == "STRING" and not str(value or "").strip():
            continue
        if not same_value(value, sp.default):
            out[sp.key] = value
    return out


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
    cmd = [binary, "render", scene_path]
    if camera:
        # "--camera=NAME" so that a name starting with "-" is not taken for an option.
        cmd.append(f"--camera={camera}")
    cmd += [
        f"--output={output}",
        "--width", str(int(width)),
        "--height", str(int(height)),
        "--progress", "json",
    ]
    for key, value in settings.values.items():
        flag = settings.flags.get(key) or "--" + key.replace("_", "-")
        cmd.append(f"{flag}={_flag_value(value)}")
    if settings.time_limit and settings.time_limit > 0:
        cmd.append(f"--time={settings.time_limit:g}")
        if settings.passes and settings.passes > 0:
            cmd.append(f"--passes={int(settings.passes)}")
    elif settings.passes and settings.passes > 1:
        cmd.append(f"--passes={int(settings.passes)}")
    if settings.progressive:
        cmd.append("--checkpoint=0")  # the image after every pass, for the render window
    if settings.aovs:
        cmd.append("--aovs")
    if settings.threads:
        cmd += ["--threads", str(int(settings.threads))]
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


# The phases before the passes, and those of each pass (every pass starts with "photons").
SETUP_PHASES = ("load", "bvh")
# Shares of the first pass's time per phase, before any pass has been timed; later passes are
# weighted by the previous pass's measured times.
FIRST_PASS_WEIGHTS = {"photons": 0.35, "irradiance": 0.20, "grids": 0.05, "build": 0.05, "render": 0.35}
SETUP_SHARE = 0.04  # load and BVH, of the whole bar
FINISH_SHARE = 0.02  # reading the image into Blender, after the last event


def expected_phases(values: dict, defaults: dict) -> set:
    """The phases of one pass for these settings (``values`` over ``defaults``): irradiance with
    final gathering (not SPPM), grids for the grid-based estimators."""
    method = values.get("method", defaults.get("method"))
    gather = values.get("gather", defaults.get("gather", 0))
    phases = {"photons", "build", "render"}
    if gather and method != "sppm":
        phases.add("irradiance")
    if method in ("adaptive", "multiscale"):
        phases.add("grids")
    return phases


class ProgressTracker:
    """Turns events into a status text and an overall fraction in [0, 1] that never goes back.

    The bar covers setup (load, BVH), every pass and the final read. ``passes`` is the pass
    count asked for (with ``time_limit`` > 0 the passes run until the time is used, ``passes``
    then being at most that many, 0 for no limit). Within a pass each phase weighs what it took
    in the previous pass (the first pass: ``FIRST_PASS_WEIGHTS``); phases that report no
    progress of their own (irradiance, grids, the index) advance with time against their
    expected duration. ``clock`` is for tests.
    """

    def __init__(self, passes: int = 1, time_limit: float = 0.0, phases: Optional[Iterable[str]] = None,
                 clock: Callable[[], float] = time.monotonic):
        self.passes = max(int(passes or 0), 0)
        self.time_limit = float(time_limit or 0.0)
        if self.time_limit <= 0 and self.passes < 1:
            self.passes = 1
        self.clock = clock
        weights = {p: w for p, w in FIRST_PASS_WEIGHTS.items() if phases is None or p in set(phases)}
        self.first_weights = weights or dict(FIRST_PASS_WEIGHTS)
        self.setup_done: set = set()
        self.started: Optional[float] = None  # the first event: about when the renderer started
        self.pass_index = -1  # the pass running (0-based), -1 before the first
        self.pass_start = 0.0
        self.current: dict = {}  # phase → seconds in the running pass
        self.previous: Optional[dict] = None  # phase → seconds in the last finished pass
        self.phase: Optional[str] = None
        self.phase_total = 0
        self.phase_fraction = 0.0
        self.phase_start = 0.0
        self.camera: Optional[str] = None
        self.finished = False
        self.fraction = 0.0

    # -- events

    def update(self, event: dict, now: Optional[float] = None) -> bool:
        """Take one event; True when the status or the fraction changed."""
        now = self.clock() if now is None else now
        if self.started is None:
            self.started = now
        before = (self.status, self.fraction)
        kind = event.get("event")
        phase = event.get("phase")
        if kind == "start" and phase:
            if phase == "photons":
                if self.pass_index >= 0:
                    self.previous = dict(self.current)
                self.pass_index += 1
                self.pass_start = now
                self.current = {}
            self.phase, self.phase_start, self.phase_fraction = phase, now, 0.0
            try:
                self.phase_total = int(event.get("total") or 0)
            except (TypeError, ValueError):
                self.phase_total = 0
        elif kind == "progress" and phase:
            self.phase = phase
            try:
                f = float(event.get("fraction", 0.0))
            except (TypeError, ValueError):
                f = 0.0
            self.phase_fraction = min(max(f, 0.0), 1.0)
        elif kind == "end" and phase:
            try:
                seconds = max(float(event.get("seconds") or 0.0), 0.0)
            except (TypeError, ValueError):
                seconds = 0.0
            if phase in SETUP_PHASES and self.pass_index < 0:
                self.setup_done.add(phase)
            else:
                self.current[phase] = self.current.get(phase, 0.0) + seconds
            self.phase, self.phase_fraction = phase, 1.0
        elif kind == "camera":
            self.camera = event.get("camera")
        elif kind in ("output", "done"):
            self.finished = True
        elif kind != "checkpoint":
            return False
        self._recompute(now)
        return (self.status, self.fraction) != before

    def tick(self, now: Optional[float] = None) -> bool:
        """Advance phases that report no progress with time; True when the fraction changed."""
        if self.started is None:
            return False
        before = self.fraction
        self._recompute(self.clock() if now is None else now)
        return self.fraction != before

    # -- the numbers

    @property
    def status(self) -> str:
        if self.phase is None:
            return "starting"
        if self.pass_index < 0 or (self.passes == 1 and self.time_limit <= 0):
            return self.phase
        total = f"/{self.passes}" if self.passes and self.time_limit <= 0 else ""
        return f"pass {self.pass_index + 1}{total} · {self.phase}"

    def _weights(self) -> dict:
        if self.previous:
            total = sum(self.previous.values())
            if total > 0:
                return {p: s / total for p, s in self.previous.items()}
        total = sum(self.first_weights.values())
        return {p: w / total for p, w in self.first_weights.items()}

    def _expected_seconds(self, phase: str) -> Optional[float]:
        if self.previous and self.previous.get(phase):
            return self.previous[phase]
        # The first pass: in proportion to the photon phase, once that has been timed.
        photons = self.current.get("photons")
        w = self.first_weights.get(phase)
        if photons and w and self.first_weights.get("photons"):
            return photons * w / self.first_weights["photons"]
        return None

    def pass_fraction(self, now: float) -> float:
        """How much of the running pass is done."""
        if self.pass_index < 0:
            return 0.0
        w = self._weights()
        done = sum(w.get(p, 0.0) for p in self.current)
        phase = self.phase
        if phase and phase not in self.current and phase not in SETUP_PHASES:
            share = w.get(phase, 0.0)
            if self.phase_total > 0:
                done += share * self.phase_fraction
            else:
                expected = self._expected_seconds(phase)
                if expected:
                    done += share * min(0.95, max(0.0, now - self.phase_start) / expected)
        return min(max(done, 0.0), 1.0)

    def _recompute(self, now: float) -> None:
        if self.finished:
            self.fraction = max(self.fraction, 1.0 - FINISH_SHARE)
            return
        setup = SETUP_SHARE * (1.0 if self.pass_index >= 0 else len(self.setup_done) / len(SETUP_PHASES))
        body = 0.0
        if self.pass_index >= 0:
            f = self.pass_fraction(now)
            done = self.pass_index + f  # passes done, with the running one's share
            by_passes = done / self.passes if self.passes else 0.0
            by_time = 0.0
            if self.time_limit > 0:
                elapsed = now - self.started
                in_pass = now - self.pass_start
                # When this pass is expected to end (the first may overrun the limit).
                if f > 0.02:
                    end = (self.pass_start - self.started) + in_pass / f
                elif self.previous:
                    end = (self.pass_start - self.started) + sum(self.previous.values())
                else:
                    end = math.inf
                by_time = elapsed / max(self.time_limit, end)
            body = max(by_passes, by_time)
        total = setup + (1.0 - SETUP_SHARE - FINISH_SHARE) * min(body, 1.0)
        self.fraction = max(self.fraction, min(total, 1.0 - FINISH_SHARE))

    def stop_grace(self, now: Optional[float] = None) -> float:
        """Seconds to wait, after asking the renderer to stop, for the running pass to end and
        its image to be written: the pass's expected remainder with a margin, at least 5 s and
        at most 60 s or three times the last pass."""
        now = self.clock() if now is None else now
        if self.pass_index < 0:
            return 30.0
        f = self.pass_fraction(now)
        in_pass = now - self.pass_start
        remaining = in_pass * (1.0 - f) / f if f > 0.02 else None
        last = sum(self.previous.values()) if self.previous else None
        if last is not None:
            # Early in a pass its fraction says little (the photon phase is quick, the ones
            # after it long): the previous pass's length is the better guide.
            remaining = max(remaining or 0.0, last - in_pass)
        if remaining is None:
            return 60.0
        return min(max(60.0, 3.0 * (last or 0.0)), max(5.0, 1.5 * remaining + 5.0))


# --------------------------------------------------------------------------------------
# The process


@dataclasses.dataclass
class ProcessResult:
    returncode: Optional[int]
    cancelled: bool  # a stop was asked for (Esc)
    error: Optional[str]  # the CLI's message when it failed
    outputs: list  # paths from "output" events
    log: list  # stderr lines that were not JSON events

    @property
    def ok(self) -> bool:
        """The renderer finished and wrote its image (after a stop request too)."""
        return self.returncode == 0 and self.error is None


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


def request_stop(proc: subprocess.Popen) -> bool:
    """Ask the renderer to stop after its current pass and write the image so far (SIGINT);
    False where that cannot be asked (Windows), and the caller stops it outright."""
    if os.name == "nt" or proc.poll() is not None:
        return False
    try:
        proc.send_signal(signal.SIGINT)
        return True
    except OSError:
        return False


def run_process(
    cmd: list,
    on_event: Optional[Callable[[dict], None]] = None,
    should_cancel: Optional[Callable[[], bool]] = None,
    on_log: Optional[Callable[[str], None]] = None,
    poll_interval: float = 0.05,
    grace_seconds: float = 3.0,
    on_start: Optional[Callable[[subprocess.Popen], None]] = None,
    stop_seconds: Optional[Callable[[], float]] = None,
    on_tick: Optional[Callable[[], None]] = None,
) -> ProcessResult:
    """Run ``cmd``; ``on_event``, ``should_cancel`` and ``on_tick`` are called on this thread only.

    When ``should_cancel()`` turns true the renderer is asked to stop after its current pass
    (``request_stop``) and given ``stop_seconds()`` seconds (default 0: none) to write its image
    and exit; then it is terminated (and killed after ``grace_seconds``).
    """
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
    deadline = None
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
            if on_tick:
                on_tick()
            if not cancelled and should_cancel and should_cancel():
                cancelled = True
                wait = float(stop_seconds()) if stop_seconds else 0.0
                if wait > 0 and request_stop(proc):
                    deadline = time.monotonic() + wait
                else:
                    stop_process(proc, grace_seconds)
                    break
            if deadline is not None and time.monotonic() > deadline:
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
    if rc != 0 and not cancelled:
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


def read_exr_channels(path: str, width: int, height: int) -> dict:
    """The EXR's channels by name (``R``, ``A``, ``Depth.Z``, ...), each a float32 array of
    shape (height, width), bottom row first (Blender's order).

    Reads with OpenImageIO when it can; else through ``bpy.data.images`` (a temporary image,
    removed again), which gives ``R``, ``G``, ``B`` and ``A`` only.
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
        if (spec.width, spec.height) != (width, height):
            raise PhotongridError(f"{path} is {spec.width}×{spec.height}, expected {width}×{height}")
        pixels = np.asarray(pixels, dtype=np.float32).reshape(spec.height, spec.width, spec.nchannels)
        # EXR: top row first.
        return {name: np.ascontiguousarray(pixels[::-1, :, i]) for i, name in enumerate(spec.channelnames)}

    import bpy

    img = bpy.data.images.load(path, check_existing=False)
    try:
        if tuple(img.size) != (width, height):
            raise PhotongridError(f"{path} is {img.size[0]}×{img.size[1]}, expected {width}×{height}")
        flat = np.empty(width * height * 4, dtype=np.float32)
        img.pixels.foreach_get(flat)  # already bottom row first
        rgba = flat.reshape(height, width, 4)
        return {c: np.ascontiguousarray(rgba[..., i]) for i, c in enumerate("RGBA")}
    finally:
        bpy.data.images.remove(img)


def read_exr_rgba(path: str, width: int, height: int, alpha: bool = False):
    """The EXR's pixels as a flat float32 RGBA array, bottom row first (Blender's order).

    The file's floats are kept as they are (scene-linear radiance, like the CLI's output).
    Alpha is the file's ``A`` (coverage: 0 where the camera saw only background) when ``alpha``
    is true, else 1 (Blender's opaque film).
    """
    import numpy as np

    channels = read_exr_channels(path, width, height)
    rgba = np.ones((height, width, 4), dtype=np.float32)
    for i, c in enumerate("RGB"):
        if c not in channels:
            raise PhotongridError(f"{path} has no channel {c} (channels: {', '.join(channels)})")
        rgba[..., i] = channels[c]
    if alpha and "A" in channels:
        rgba[..., 3] = channels["A"]
    return rgba.ravel()


# Blender's passes and the EXR channels (``photongrid render --aovs``) that fill them:
# (pass name, channel ids, type, EXR channels, the view layer's switch). Normals are converted
# from the file's glTF world (Y up) to Blender's (Z up): Blender (x, y, z) = glTF (x, -z, y).
PASSES = (
    ("Depth", "Z", "VALUE", ("Depth.Z",), "use_pass_z"),
    ("Normal", "XYZ", "VECTOR", ("Normal.X", "Normal.Y", "Normal.Z"), "use_pass_normal"),
    ("DiffCol", "RGB", "COLOR", ("DiffCol.R", "DiffCol.G", "DiffCol.B"), "use_pass_diffuse_color"),
    ("Photon Density", "X", "VALUE", ("PhotonDensity.X",), "use_pass_photon_density"),
    ("Photon Radius", "X", "VALUE", ("PhotonRadius.X",), "use_pass_photon_radius"),
)


def pass_pixels(channels: dict, name: str):
    """The flat float32 pixels of Blender pass ``name`` from the EXR's ``channels``, or None
    when the file lacks them."""
    import numpy as np

    for pass_name, _ids, _kind, exr, _switch in PASSES:
        if pass_name != name:
            continue
        if not all(c in channels for c in exr):
            return None
        planes = [channels[c] for c in exr]
        if pass_name == "Normal":
            x, y, z = planes
            planes = [x, -z, y]
        return np.ascontiguousarray(np.stack(planes, axis=-1), dtype=np.float32).ravel()
    return None


def render_size(scene) -> tuple:
    """Width and height of the render: resolution × percentage, as Blender computes it."""
    r = scene.render
    pct = r.resolution_percentage
    return max(1, int(r.resolution_x * pct / 100)), max(1, int(r.resolution_y * pct / 100))


def settings_from_scene(scene, specs: Iterable = (), aovs: bool = False) -> RenderSettings:
    """The panel's settings (``scene.photongrid``, described by ``specs``) and Blender's thread
    count."""
    specs = list(specs)
    props = getattr(scene, "photongrid", None)
    s = RenderSettings(aovs=aovs)
    if props is not None:
        present = [sp for sp in specs if hasattr(props, sp.key)]
        s.values = settings_values(present, lambda k: getattr(props, k))
        s.flags = {sp.key: sp.flag for sp in present}
        s.passes = int(getattr(props, "passes", 1))
        s.time_limit = float(getattr(props, "time_limit", 0.0))
    r = scene.render
    if getattr(r, "threads_mode", "AUTO") == "FIXED":
        s.threads = int(r.threads)
    return s


@dataclasses.dataclass
class RunResult:
    path: str  # the final image
    passes: Optional[int]  # passes in it, when the renderer said
    stopped: bool  # Esc ended the render early (after a pass)
    warnings: list


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
    on_checkpoint: Optional[Callable[[str, int], None]] = None,
    on_warning: Optional[Callable[[str], None]] = None,
    grace_seconds: float = 3.0,
    phases: Optional[Iterable[str]] = None,
) -> RunResult:
    """Export ``scene`` into ``workdir``, render its camera with photongrid, return the image.

    ``camera``: the glTF node name (the camera object's name), default the scene's camera.
    ``on_checkpoint(path, passes)`` gets the image after every pass but the last (progressive
    settings); ``on_warning`` every warning (approximated materials). Esc (``should_cancel``)
    asks the renderer to stop after its current pass, which then writes that image: the result
    says ``stopped``. Raises ``Cancelled`` when the render was stopped with no image, and
    ``PhotongridError`` on failure.
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
    tracker = ProgressTracker(passes=settings.passes, time_limit=settings.time_limit, phases=phases)
    warnings, passes = [], [None]
    stopping = [False]

    def show():
        prefix = "photongrid: stopping after this pass · " if stopping[0] else "photongrid: "
        status(prefix + tracker.status)
        progress(tracker.fraction)

    def on_event(event: dict) -> None:
        kind = event.get("event")
        if kind == "warning":
            message = str(event.get("message", ""))
            warnings.append(message)
            if on_warning:
                on_warning(message)
        elif kind == "checkpoint" and event.get("path") and on_checkpoint:
            on_checkpoint(str(event["path"]), int(event.get("passes") or 0))
        elif kind in ("output", "done") and event.get("passes") is not None:
            passes[0] = int(event["passes"])
        if tracker.update(event):
            show()

    def on_tick() -> None:
        if tracker.tick():
            show()

    def cancel() -> bool:
        if should_cancel and should_cancel():
            stopping[0] = True
            show()
            return True
        return False

    def on_log(line: str) -> None:
        print(f"photongrid: {line}", file=sys.stderr)

    result = run_process(
        cmd,
        on_event=on_event,
        should_cancel=cancel,
        on_log=on_log,
        grace_seconds=grace_seconds,
        on_start=on_start,
        stop_seconds=tracker.stop_grace,
        on_tick=on_tick,
    )
    path = result.outputs[-1] if result.outputs else out
    if result.cancelled and not (result.ok and result.outputs):
        raise Cancelled("cancelled")
    if not result.ok:
        raise PhotongridError(f"photongrid failed: {result.error}")
    if not os.path.isfile(path):
        raise PhotongridError(f"photongrid finished but wrote no image at {path}")
    return RunResult(path=path, passes=passes[0], stopped=result.cancelled, warnings=warnings)
