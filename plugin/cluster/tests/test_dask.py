"""The Dask runner end to end: a LocalCluster of 2 worker processes, one failing job, and a worker
killed (SIGKILL) while it renders. Every good output must be rendered exactly once and match a
local ``photongrid batch`` run byte for byte (same seeds and settings give the same image)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent
REPO = HERE.parents[2]
sys.path.insert(0, str(HERE.parent))

import photongrid_dask  # noqa: E402

BIN = os.environ.get("PHOTONGRID_BIN") or str(REPO / "target" / "release" / "photongrid")
SAMPLES = REPO / "samples"

pytestmark = pytest.mark.skipif(not Path(BIN).is_file(), reason=f"no photongrid binary at {BIN}")

TINY = "width = 48\nheight = 36\nphotons = 20000\nspp = 1\n"


def jobs_file(d: Path) -> Path:
    """Unit 0 is slow enough (2 M photons on one thread) to be killed mid-way."""
    jobs = [
        ("cornell_area.glb", "photons = 2000000\nseed = 7"),
        ("cornell_glass.glb", ""),
        ("ring_caustic.glb", 'camera = "all"'),
        (str(d / "missing.glb"), ""),
        ("shadow_edges.glb", "seed = 5"),
    ]
    text = f"[defaults]\n{TINY}output = \"out/{{scene}}-{{camera}}.exr\"\n"
    for scene, extra in jobs:
        scene = scene if scene.startswith("/") else str(SAMPLES / scene)
        text += f'\n[[job]]\nscene = "{scene}"\n{extra}\n'
    d.mkdir(parents=True, exist_ok=True)
    p = d / "jobs.toml"
    p.write_text(text)
    return p


def journal_events(path: Path) -> list[dict]:
    if not path.exists():
        return []
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def test_dask_batch_survives_a_killed_worker(tmp_path):
    from distributed import Client, LocalCluster

    # Reference: the same jobs with the local batch command.
    ref_jobs = jobs_file(tmp_path / "ref")
    p = subprocess.run(
        [BIN, "batch", str(ref_jobs), "--report", str(tmp_path / "ref" / "report.json"), "--quiet"],
        capture_output=True,
        text=True,
    )
    assert p.returncode != 0 and "missing.glb" in p.stderr, p.stderr
    ref = json.loads((tmp_path / "ref" / "report.json").read_text())
    units = photongrid_dask.list_units(BIN, ref_jobs)
    assert [u["index"] for u in units] == list(range(6))
    good = [u["index"] for u in units if u["error"] is None]
    bad = [u["index"] for u in units if u["error"] is not None]
    assert len(good) == 5 and len(bad) == 1

    run_dir = tmp_path / "dask"
    jobs = jobs_file(run_dir)
    journal = run_dir / "journal.jsonl"
    cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None)
    client = Client(cluster)
    killed = {}
    try:
        result = {}
        runner = threading.Thread(
            target=lambda: result.update(
                photongrid_dask.run_batch(
                    client, jobs, run_dir / "report.json", binary=BIN, journal=str(journal), unit_threads=1
                )
            )
        )
        runner.start()
        # Kill the worker process rendering unit 0 once it has started (the render is its child).
        deadline = time.time() + 60
        while time.time() < deadline and not killed:
            for e in journal_events(journal):
                if e["event"] == "start" and e["unit"] == 0:
                    killed = e
                    os.kill(e["ppid"], signal.SIGKILL)
                    break
            time.sleep(0.05)
        runner.join(timeout=150)
        assert not runner.is_alive(), "the Dask batch did not finish"
    finally:
        client.close()
        cluster.close()
    assert killed, "unit 0 never started"

    report = json.loads((run_dir / "report.json").read_text())
    assert report == result
    status = {u["index"]: u["status"] for u in report["units"]}
    assert status == {i: ("failed" if i in bad else "done") for i in range(6)}, report["units"]
    failed = next(u for u in report["units"] if u["index"] in bad)
    assert "does not exist" in failed["error"]
    t = report["totals"]
    assert (t["units"], t["done"], t["failed"], t["skipped"]) == (6, 5, 1, 0)

    events = journal_events(journal)
    # The killed attempt never finished; unit 0 was started again elsewhere and rendered once.
    starts0 = [e for e in events if e["event"] == "start" and e["unit"] == 0]
    assert len(starts0) == 2 and starts0[0]["pid"] == killed["pid"], starts0
    assert not [e for e in events if e["pid"] == killed["pid"] and e["event"] == "done"]
    for i in good:
        done = [e for e in events if e["event"] == "done" and e["unit"] == i]
        assert len(done) == 1, f"unit {i} rendered {len(done)} times"

    # Byte for byte the local batch's images.
    for r, u in zip(ref["units"], report["units"]):
        assert r["index"] == u["index"] and r["status"] == u["status"]
        if u["status"] == "done":
            ours = Path(u["output"])
            theirs = Path(r["output"])
            assert ours.parent == run_dir / "out" and theirs.parent == tmp_path / "ref" / "out"
            assert ours.read_bytes() == theirs.read_bytes(), ours.name

    # The runner's command line, run again: every finished output is skipped.
    env = dict(os.environ, PYTHONPATH=str(HERE.parent), PHOTONGRID_BIN=BIN)
    p = subprocess.run(
        [sys.executable, "-m", "photongrid_dask", str(jobs), "--report", str(run_dir / "again.json"), "--local", "2"],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
    )
    assert p.returncode == 1 and "missing.glb" in p.stderr, p.stderr
    again = json.loads((run_dir / "again.json").read_text())
    assert [u["status"] for u in again["units"]] == [("failed" if i in bad else "skipped") for i in range(6)]
