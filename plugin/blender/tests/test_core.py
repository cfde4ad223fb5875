"""The add-on's core without Blender: binary lookup, settings schema, command line, progress,
process control."""

import importlib.util
import json
import os
import signal
import stat
import sys
import textwrap

import pytest

HERE = os.path.dirname(os.path.abspath(__file__))
CORE = os.path.join(os.path.dirname(HERE), "photongrid", "core.py")

# core.py is loaded on its own, so that these tests need no bpy.
_spec = importlib.util.spec_from_file_location("photongrid_core", CORE)
core = importlib.util.module_from_spec(_spec)
sys.modules[_spec.name] = core
_spec.loader.exec_module(core)


def script(tmp_path, name, body):
    """An executable Python script standing in for the binary."""
    path = tmp_path / name
    path.write_text(f"#!{sys.executable}\n" + textwrap.dedent(body))
    path.chmod(path.stat().st_mode | stat.S_IXUSR | stat.S_IXGRP | stat.S_IXOTH)
    return str(path)


SCHEMA = {
    "version": "0.1.0",
    "settings": [
        {"key": "photons", "flag": "--photons", "type": "integer", "default": 2000000, "help": "Photon paths",
         "choices": [], "optional": False},
        {"key": "caustic_photons", "flag": "--caustic-photons", "type": "integer", "default": 1000000,
         "help": "Caustic paths", "choices": [], "optional": False},
        {"key": "width", "flag": "--width", "type": "integer", "default": None, "help": "Width", "choices": [],
         "optional": True},
        {"key": "spp", "flag": "--spp", "type": "integer", "default": 4, "help": "Camera rays per pixel\n and pass",
         "choices": [], "optional": False},
        {"key": "alpha", "flag": "--alpha", "type": "number", "default": 0.1, "help": "Share", "choices": [],
         "optional": False},
        {"key": "gather", "flag": "--gather", "type": "integer", "default": 8, "help": "Rays", "choices": [],
         "optional": False},
        {"key": "method", "flag": "--method", "type": "choice", "default": "adaptive", "help": "Estimate",
         "choices": [{"value": "knn", "help": "Classic"}, {"value": "adaptive", "help": "The paper's"},
                     {"value": "sppm", "help": "SPPM"}], "optional": False},
        {"key": "direct", "flag": "--direct", "type": "choice", "default": "shadow-rays", "help": "Direct",
         "choices": [{"value": "shadow-rays", "help": "Rays"}, {"value": "photons", "help": "Map"}],
         "optional": False},
        {"key": "passes", "flag": "--passes", "type": "integer", "default": None, "help": "At most this many passes",
         "choices": [], "optional": True},
        {"key": "time", "flag": "--time", "type": "number", "default": None, "help": "Time budget", "choices": [],
         "optional": True},
    ],
}


def test_find_binary_order(tmp_path):
    on_path = tmp_path / "bin"
    on_path.mkdir()
    path_bin = script(on_path, "photongrid", "")
    env_bin = script(tmp_path, "pg-env", "")
    pref_bin = script(tmp_path, "pg-pref", "")
    bundled = script(tmp_path, "pg-bundled", "")
    env = {"PATH": str(on_path), core.ENV_VAR: env_bin}
    assert core.find_binary(pref_bin, env, bundled) == pref_bin
    with pytest.raises(core.MissingBinaryError, match="from the add-on preferences"):
        core.find_binary(str(tmp_path / "nope"), env, bundled)
    assert core.find_binary("", env, bundled) == env_bin
    # With nothing set, the binary inside the extension, before PATH.
    assert core.find_binary("", {"PATH": str(on_path)}, bundled) == bundled
    assert core.find_binary("", {"PATH": str(on_path)}, str(tmp_path / "none")) == path_bin
    assert core.find_binary(str(on_path), {}, None) == path_bin  # a folder holding photongrid
    with pytest.raises(core.MissingBinaryError) as e:
        core.find_binary("", {"PATH": str(tmp_path / "empty")}, None)
    assert str(e.value) == core.MISSING_BINARY_MESSAGE
    with pytest.raises(core.MissingBinaryError, match="PHOTONGRID_BIN"):
        core.find_binary("", {"PATH": "", core.ENV_VAR: str(tmp_path / "nope")}, None)


def test_bundled_binary_gets_its_execute_bit_back(tmp_path):
    """Blender extracts extension zips without permission bits."""
    b = tmp_path / "photongrid"
    b.write_text("#!/bin/sh\n")
    b.chmod(0o644)
    assert core.bundled_binary(str(b)) == str(b)
    assert os.access(b, os.X_OK)
    assert core.bundled_binary(str(tmp_path / "missing")) is None


def test_schema_is_run_once_and_cached(tmp_path):
    count = tmp_path / "count"
    schema_file = tmp_path / "schema.json"
    schema_file.write_text(json.dumps(SCHEMA))
    fake = script(tmp_path, "pg", f"""
        import sys
        assert sys.argv[1:] == ["settings", "--schema"], sys.argv
        with open({str(count)!r}, "a") as f:
            f.write("x")
        print(open({str(schema_file)!r}).read())
    """)
    cache = tmp_path / "cache"
    a = core.schema_from_binary(fake, str(cache))
    b = core.schema_from_binary(fake, str(cache))
    assert a == b == SCHEMA and count.read_text() == "x"
    core._schema_memo.clear()  # a new session: the disk cache answers
    assert core.schema_from_binary(fake, str(cache)) == SCHEMA and count.read_text() == "x"
    bad = script(tmp_path, "bad", "print('no json')")
    with pytest.raises(core.PhotongridError, match="settings --schema"):
        core.schema_from_binary(bad)


def test_property_specs_come_from_the_schema():
    specs = {sp.key: sp for sp in core.property_specs(SCHEMA)}
    # Width and height are Blender's resolution; passes and time are the Sampling section's own.
    assert not {"width", "passes", "time"} & set(specs)
    assert specs["photons"].kind == "INT" and specs["photons"].default == 2_000_000
    assert specs["photons"].section == "PHOTONS" and specs["photons"].label == "Photons"
    assert specs["spp"].description == "Camera rays per pixel and pass."
    assert specs["alpha"].kind == "FLOAT" and specs["alpha"].section == "ADVANCED"
    m = specs["method"]
    assert m.kind == "ENUM" and m.default == "adaptive" and m.section == "METHOD"
    assert m.items == [("knn", "kNN", "Classic."), ("adaptive", "Adaptive", "The paper's."), ("sppm", "SPPM", "SPPM.")]
    assert specs["direct"].items[0][:2] == ("shadow-rays", "Shadow Rays")
    assert core.schema_help(SCHEMA, "time") == "Time budget."
    order = [sp.key for sp in core.property_specs(SCHEMA)]
    assert order.index("photons") < order.index("caustic_photons") < order.index("alpha")


def test_quality_presets_scale_the_defaults():
    defaults = {sp.key: sp.default for sp in core.property_specs(SCHEMA)}
    assert core.quality_values("DEFAULT", defaults) == {"photons": 2_000_000, "caustic_photons": 1_000_000,
                                                         "spp": 4, "gather": 8}
    assert core.quality_values("PREVIEW", defaults) == {"photons": 250_000, "caustic_photons": 125_000,
                                                         "spp": 1, "gather": 4}
    assert core.quality_values("HIGH", defaults)["spp"] == 8


def test_build_command():
    specs = core.property_specs(SCHEMA)
    values = {sp.key: sp.default for sp in specs}
    values.update(photons=1000, method="sppm", alpha=0.10000000149011612)  # Blender's float32 0.1
    s = core.RenderSettings(values=core.settings_values(specs, values.get), passes=1)
    assert s.values == {"photons": 1000, "method": "sppm"}, "only what differs from the defaults"
    cmd = core.build_command("/bin/pg", "/t/scene.glb", "-Cam 1", "/t/out.exr", 64, 48, s)
    assert cmd[:3] == ["/bin/pg", "render", "/t/scene.glb"]
    assert "--camera=-Cam 1" in cmd and "--output=/t/out.exr" in cmd
    pairs = dict(zip(cmd[3:], cmd[4:]))
    assert pairs["--width"] == "64" and pairs["--height"] == "48" and pairs["--progress"] == "json"
    assert "--photons=1000" in cmd and "--method=sppm" in cmd
    assert not any(a.startswith(("--passes", "--time", "--checkpoint", "--aovs", "--threads", "--alpha")) for a in cmd)
    # Several passes: the image after each; a time limit with passes 0: as many as fit.
    cmd = core.build_command("pg", "s.glb", None, "o.exr", 1, 1, core.RenderSettings(passes=3, aovs=True, threads=2))
    assert "--passes=3" in cmd and "--checkpoint=0" in cmd and "--aovs" in cmd
    assert cmd[cmd.index("--threads") + 1] == "2" and not any(a.startswith("--camera") for a in cmd)
    cmd = core.build_command("pg", "s.glb", None, "o.exr", 1, 1, core.RenderSettings(passes=0, time_limit=12.5))
    assert "--time=12.5" in cmd and "--checkpoint=0" in cmd and not any(a.startswith("--passes") for a in cmd)


def test_parse_event():
    assert core.parse_event('{"event":"start","phase":"photons","total":10}\n') == {
        "event": "start", "phase": "photons", "total": 10}
    assert core.parse_event(b'{"event":"end","phase":"render","seconds":0.5}')["seconds"] == 0.5
    for line in ("", "error: boom", "{not json", '{"phase":"x"}', "[1]", "  WARN something"):
        assert core.parse_event(line) is None


def one_pass(t0, seconds=None, gather=True):
    """The events of one pass starting at t0 (photons 2 s, irradiance 3 s, build 1 s, render 2 s)."""
    s = seconds or {"photons": 2.0, "irradiance": 3.0, "build": 1.0, "render": 2.0}
    t, out = t0, []
    for phase in ("photons", "irradiance", "build", "render"):
        if phase == "irradiance" and not gather:
            continue
        total = 100 if phase in ("photons", "render") else 0
        out.append((t, {"event": "start", "phase": phase, "total": total}))
        if total:
            out.append((t + s[phase] / 2, {"event": "progress", "phase": phase, "done": 50, "total": 100,
                                            "fraction": 0.5}))
        else:
            out.append((t + s[phase] / 2, None))  # a tick half-way
        t += s[phase]
        out.append((t, {"event": "end", "phase": phase, "seconds": s[phase]}))
    return t, out


def run_tracker(tracker, timeline):
    seen = []
    for t, e in timeline:
        if e is None:
            tracker.tick(now=t)
        else:
            tracker.update(e, now=t)
        seen.append((t, e and e.get("event"), e and e.get("phase"), tracker.fraction, tracker.status))
    return seen


def test_progress_is_monotone_over_phases_and_passes():
    t = core.ProgressTracker(passes=3, phases={"photons", "irradiance", "build", "render"})
    timeline = [(0.0, {"event": "start", "phase": "load", "total": 0}),
                (0.1, {"event": "end", "phase": "load", "seconds": 0.1}),
                (0.1, {"event": "start", "phase": "bvh", "total": 0}),
                (0.2, {"event": "end", "phase": "bvh", "seconds": 0.1})]
    now = 0.2
    for p in range(3):
        now, events = one_pass(now)
        timeline += events
        if p < 2:
            timeline.append((now, {"event": "checkpoint", "path": "/o.exr", "passes": p + 1}))
    timeline.append((now, {"event": "output", "camera": "Camera", "path": "/o.exr", "passes": 3}))
    seen = run_tracker(t, timeline)
    fractions = [s[3] for s in seen]
    assert fractions == sorted(fractions) and fractions[-1] == 1 - core.FINISH_SHARE
    # The irradiance phase (no progress events) moves the bar: half-way through it, more than
    # at its start.
    irr = [s for s in seen if s[2] == "irradiance" or (s[1] is None)]
    assert irr[1][3] > irr[0][3], irr[:3]
    # Each pass ends near a third of the body of the bar; nothing sits at 99 % after pass one.
    body = 1 - core.SETUP_SHARE - core.FINISH_SHARE
    ends = [s[3] for s in seen if s[1] == "checkpoint"]
    assert ends == pytest.approx([core.SETUP_SHARE + body / 3, core.SETUP_SHARE + 2 * body / 3], abs=1e-6)
    # Later passes are weighted by the previous pass's times: half-way through pass 2's
    # irradiance (3 s of 8) is (2 + 1.5) / 8 of the pass.
    mid = [s for s in seen if s[1] is None][2]
    assert mid[3] == pytest.approx(core.SETUP_SHARE + body * (1 + 3.5 / 8) / 3, abs=1e-6)
    assert [s[4] for s in seen if s[1] == "start" and s[2] == "render"] == [
        "pass 1/3 · render", "pass 2/3 · render", "pass 3/3 · render"]


def test_progress_under_a_time_limit():
    t = core.ProgressTracker(passes=0, time_limit=20.0)
    timeline = [(0.0, {"event": "start", "phase": "load", "total": 0}),
                (0.0, {"event": "end", "phase": "load", "seconds": 0.0})]
    now = 0.0
    for _ in range(2):
        now, events = one_pass(now)
        timeline += events
    seen = run_tracker(t, timeline)
    fractions = [s[3] for s in seen]
    assert fractions == sorted(fractions)
    # 16 of 20 s used: the bar follows the clock, not a pass count.
    body = 1 - core.SETUP_SHARE - core.FINISH_SHARE
    assert fractions[-1] == pytest.approx(core.SETUP_SHARE + body * 16 / 20, abs=1e-6)
    assert seen[-1][4] == "pass 2 · render"


def test_stop_grace_follows_the_pass():
    t = core.ProgressTracker(passes=5)
    assert t.stop_grace(now=0.0) == 30.0  # nothing known yet
    t.update({"event": "start", "phase": "photons", "total": 100}, now=0.0)
    t.update({"event": "progress", "phase": "photons", "fraction": 0.5}, now=1.0)
    assert 5.0 <= t.stop_grace(now=1.0) <= 60.0
    # Pass 2 just started, its quick photon phase done: the wait covers a whole pass like the
    # first (40 s), not what the fraction alone suggests.
    for event, at in [({"event": "end", "phase": "photons", "seconds": 2.0}, 2.0),
                      ({"event": "start", "phase": "render", "total": 10}, 2.0),
                      ({"event": "end", "phase": "render", "seconds": 38.0}, 40.0),
                      ({"event": "start", "phase": "photons", "total": 100}, 40.0),
                      ({"event": "progress", "phase": "photons", "fraction": 1.0}, 41.0)]:
        t.update(event, now=at)
    assert t.stop_grace(now=41.0) >= 1.5 * 39.0
    assert t.stop_grace(now=41.0) <= 3 * 40.0


def test_run_process_events_and_error(tmp_path):
    fake = script(tmp_path, "fake", """
        import json, sys
        def e(**kw): print(json.dumps(kw), file=sys.stderr, flush=True)
        e(event="start", phase="photons", total=2)
        print("WARN a warning line", file=sys.stderr)
        e(event="progress", phase="photons", done=2, total=2, fraction=1.0)
        e(event="error", message="no camera 'X' in scene.glb; available: 0 (Camera)")
        sys.exit(1)
    """)
    events = []
    r = core.run_process([fake], on_event=events.append)
    assert r.returncode == 1 and not r.ok and not r.cancelled
    assert r.error == "no camera 'X' in scene.glb; available: 0 (Camera)"
    assert [e["event"] for e in events] == ["start", "progress", "error"]
    assert "WARN a warning line" in r.log


def test_run_process_error_without_json(tmp_path):
    fake = script(tmp_path, "fake", """
        import sys
        print("error: unexpected argument '--method' found", file=sys.stderr)
        sys.exit(2)
    """)
    r = core.run_process([fake])
    assert r.returncode == 2 and r.error == "error: unexpected argument '--method' found"


def test_run_process_output_event(tmp_path):
    fake = script(tmp_path, "fake", """
        import json, sys
        print(json.dumps({"event": "output", "camera": "Camera", "path": "/tmp/x.exr"}), file=sys.stderr)
    """)
    r = core.run_process([fake])
    assert r.ok and r.outputs == ["/tmp/x.exr"]


def test_cancel_asks_to_stop_after_the_pass(tmp_path):
    """Esc: SIGINT, and the renderer's image written on its way out is the result."""
    fake = script(tmp_path, "fake", """
        import json, signal, sys, time
        stop = []
        signal.signal(signal.SIGINT, lambda *a: stop.append(1))
        def e(**kw): print(json.dumps(kw), file=sys.stderr, flush=True)
        e(event="start", phase="photons", total=9)
        while not stop:
            time.sleep(0.01)
        e(event="output", camera="Camera", path="/tmp/kept.exr", passes=1)
    """)
    events = []
    r = core.run_process([fake], on_event=events.append, should_cancel=lambda: bool(events),
                         stop_seconds=lambda: 10.0)
    assert r.cancelled and r.ok and r.returncode == 0 and r.outputs == ["/tmp/kept.exr"]


def test_cancel_terminates_then_kills(tmp_path):
    # Ignores SIGINT and SIGTERM, so it has to be killed after the stop wait and the grace period.
    fake = script(tmp_path, "fake", """
        import json, signal, sys, time
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        print(json.dumps({"event": "progress", "phase": "photons", "done": 1, "total": 9, "fraction": 0.1}),
              file=sys.stderr, flush=True)
        time.sleep(60)
    """)
    events, procs = [], []
    r = core.run_process([fake], on_event=events.append, should_cancel=lambda: bool(events),
                         grace_seconds=0.5, on_start=procs.append, stop_seconds=lambda: 0.5)
    assert r.cancelled and not r.ok and r.error is None
    # Killed, not ended by itself after its sleep (that would be exit code 0).
    assert procs[0].poll() == -signal.SIGKILL


def test_start_failure_is_an_error(tmp_path):
    with pytest.raises(core.PhotongridError, match="could not start"):
        core.run_process([str(tmp_path / "missing")])


def test_passes_from_channels():
    np = pytest.importorskip("numpy")
    h, w = 2, 3
    ch = {name: np.full((h, w), v, dtype=np.float32) for name, v in
          [("Normal.X", 1.0), ("Normal.Y", 2.0), ("Normal.Z", 3.0), ("Depth.Z", 5.0)]}
    normal = core.pass_pixels(ch, "Normal").reshape(h, w, 3)
    assert normal[0, 0].tolist() == [1.0, -3.0, 2.0], "glTF Y-up to Blender Z-up"
    assert core.pass_pixels(ch, "Depth").tolist() == [5.0] * 6
    assert core.pass_pixels(ch, "DiffCol") is None


def test_export_options():
    o = core.gltf_export_options("/t/s.glb")
    assert o["export_format"] == "GLB" and o["export_import_convert_lighting_mode"] == "SPEC"
    assert o["export_cameras"] and o["export_lights"] and o["export_apply"] and o["export_yup"]
    assert not o["use_selection"] and not o["export_animations"] and not o["will_save_settings"]
    assert core.supported_options(o, {"filepath", "export_format"}) == {"filepath": "/t/s.glb", "export_format": "GLB"}
