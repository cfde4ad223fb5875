"""The add-on's core without Blender: binary lookup, command line, progress, process control."""

import importlib.util
import os
import stat
import sys
import textwrap
import time

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


def test_find_binary_order(tmp_path):
    on_path = tmp_path / "bin"
    on_path.mkdir()
    path_bin = script(on_path, "photongrid", "")
    env_bin = script(tmp_path, "pg-env", "")
    pref_bin = script(tmp_path, "pg-pref", "")
    env = {"PATH": str(on_path), core.ENV_VAR: env_bin}
    assert core.find_binary(pref_bin, env) == pref_bin
    with pytest.raises(core.MissingBinaryError, match="from the add-on preferences"):
        core.find_binary(str(tmp_path / "nope"), env)
    assert core.find_binary("", env) == env_bin
    assert core.find_binary("", {"PATH": str(on_path)}) == path_bin
    assert core.find_binary(str(on_path), {}) == path_bin  # a folder holding photongrid
    with pytest.raises(core.MissingBinaryError) as e:
        core.find_binary("", {"PATH": str(tmp_path / "empty")})
    assert str(e.value) == core.MISSING_BINARY_MESSAGE
    with pytest.raises(core.MissingBinaryError, match="PHOTONGRID_BIN"):
        core.find_binary("", {"PATH": "", core.ENV_VAR: str(tmp_path / "nope")})


def test_build_command_passes_future_options_only_when_set():
    s = core.RenderSettings(photons=1000, neighbours=20, spp=2, seed=3, direct="photons")
    cmd = core.build_command("/bin/pg", "/t/scene.glb", "-Cam 1", "/t/out.exr", 64, 48, s)
    assert cmd[:3] == ["/bin/pg", "render", "/t/scene.glb"]
    assert "--camera=-Cam 1" in cmd and "--output=/t/out.exr" in cmd
    pairs = dict(zip(cmd[3:], cmd[4:]))
    assert pairs["--width"] == "64" and pairs["--height"] == "48"
    assert pairs["--photons"] == "1000" and pairs["--neighbours"] == "20"
    assert pairs["--spp"] == "2" and pairs["--seed"] == "3" and pairs["--direct"] == "photons"
    assert pairs["--progress"] == "json"
    assert not any(a.startswith(("--method", "--grid", "--time-budget", "--threads")) for a in cmd)
    s.method, s.grid, s.time_budget, s.threads = "adaptive", "64", "30s", 2
    cmd = core.build_command("pg", "s.glb", None, "o.exr", 1, 1, s)
    assert "--method=adaptive" in cmd and "--grid=64" in cmd and "--time-budget=30s" in cmd
    assert not any(a.startswith("--camera") for a in cmd)
    assert cmd[cmd.index("--threads") + 1] == "2"
    with pytest.raises(core.PhotongridError):
        core.build_command("pg", "s.glb", None, "o.exr", 1, 1, core.RenderSettings(direct="both"))


def test_parse_event():
    assert core.parse_event('{"event":"start","phase":"photons","total":10}\n') == {
        "event": "start", "phase": "photons", "total": 10}
    assert core.parse_event(b'{"event":"end","phase":"render","seconds":0.5}')["seconds"] == 0.5
    for line in ("", "error: boom", "{not json", '{"phase":"x"}', "[1]", "  WARN something"):
        assert core.parse_event(line) is None


def test_progress_weights():
    t = core.ProgressTracker()
    seen = []
    events = [
        {"event": "start", "phase": "load", "total": 0},
        {"event": "end", "phase": "load", "seconds": 0.1},
        {"event": "start", "phase": "bvh", "total": 0},
        {"event": "end", "phase": "bvh", "seconds": 0.1},
        {"event": "start", "phase": "photons", "total": 100},
        {"event": "progress", "phase": "photons", "done": 50, "total": 100, "fraction": 0.5},
        {"event": "end", "phase": "photons", "seconds": 1},
        {"event": "start", "phase": "build", "total": 0},
        {"event": "end", "phase": "build", "seconds": 0.1},
        {"event": "start", "phase": "render", "total": 48},
        {"event": "progress", "phase": "render", "done": 24, "total": 48, "fraction": 0.5},
        {"event": "progress", "phase": "render", "done": 12, "total": 48, "fraction": 0.25},  # never back
        {"event": "end", "phase": "render", "seconds": 1},
        {"event": "output", "camera": "Camera", "path": "/x.exr"},
    ]
    for e in events:
        t.update(e)
        seen.append((t.phase, round(t.fraction, 4)))
    assert seen[5] == ("photons", 0.02 + 0.20)
    assert seen[6] == ("photons", 0.42)
    assert seen[10] == ("render", round(0.44 + 0.275, 4))
    assert seen[11] == seen[10]
    assert seen[12] == ("render", 0.99)
    fractions = [f for _, f in seen]
    assert fractions == sorted(fractions) and max(fractions) <= 1.0


def test_run_process_events_and_error(tmp_path):
    fake = script(tmp_path, "fake", """
        import json, sys
        def e(**kw): print(json.dumps(kw), file=sys.stderr, flush=True)
        e(event="start", phase="photons", total=2)
        print("WARN a warning line", file=sys.stderr)
        e(event="progress", phase="photons", done=2, total=2, fraction=1.0)
        e(event="error", message="no camera 'X' in scene.glb; available: 0 (Camera)")
        print("error: no camera 'X' in scene.glb", file=sys.stderr)
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


def test_cancel_terminates_then_kills(tmp_path):
    # Ignores SIGTERM, so it has to be killed after the grace period.
    fake = script(tmp_path, "fake", """
        import json, signal, sys, time
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        print(json.dumps({"event": "progress", "phase": "photons", "done": 1, "total": 9, "fraction": 0.1}),
              file=sys.stderr, flush=True)
        time.sleep(60)
    """)
    events, procs = [], []
    t = time.monotonic()
    r = core.run_process([fake], on_event=events.append, should_cancel=lambda: bool(events),
                         grace_seconds=0.5, on_start=procs.append)
    assert r.cancelled and not r.ok and r.error is None
    assert time.monotonic() - t < 10
    assert procs[0].poll() is not None and procs[0].returncode < 0


def test_start_failure_is_an_error(tmp_path):
    with pytest.raises(core.PhotongridError, match="could not start"):
        core.run_process([str(tmp_path / "missing")])


def test_export_options():
    o = core.gltf_export_options("/t/s.glb")
    assert o["export_format"] == "GLB" and o["export_import_convert_lighting_mode"] == "SPEC"
    assert o["export_cameras"] and o["export_lights"] and o["export_apply"] and o["export_yup"]
    assert not o["use_selection"] and not o["export_animations"] and not o["will_save_settings"]
    assert core.supported_options(o, {"filepath", "export_format"}) == {"filepath": "/t/s.glb", "export_format": "GLB"}
