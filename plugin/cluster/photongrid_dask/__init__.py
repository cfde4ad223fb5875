"""Run a photongrid ``JOBS.toml`` on a Dask cluster.

The Rust binary does all the work that matters: ``photongrid batch JOBS.toml --list`` expands
the jobs into units (one scene, one camera, one output; numbered in a stable order), and each
Dask task runs ``photongrid batch JOBS.toml --only INDEX --report <tmp>.json`` for one unit.
Tasks are idempotent: a finished output has a checked sidecar (``<output>.done.json``), so a
task re-run after its worker died (or retried after an error) skips work already written, and
outputs are written atomically, so a killed task leaves nothing half written. The per-unit
reports are merged into the same JSON report format as ``photongrid batch --report``.

Outputs and the jobs file must be on a file system every worker sees at the same path (as on a
Slurm/PBS cluster with a shared home or scratch, or a Kubernetes volume).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

__all__ = ["find_binary", "list_units", "run_unit", "run_batch", "merge_reports", "totals"]

REPO_ROOT = Path(__file__).resolve().parents[3]


def find_binary(explicit: str | None = None) -> str:
    """The photongrid binary: ``explicit``, ``$PHOTONGRID_BIN``, the repository's release build, or PATH."""
    for c in (explicit, os.environ.get("PHOTONGRID_BIN")):
        if c:
            return str(Path(c).resolve()) if os.sep in c else c
    built = REPO_ROOT / "target" / "release" / "photongrid"
    if built.is_file():
        return str(built)
    found = shutil.which("photongrid")
    if found:
        return found
    raise FileNotFoundError(
        "no photongrid binary: build it (cargo build --release), set PHOTONGRID_BIN or pass --bin"
    )


def list_units(binary: str, jobs: str | os.PathLike) -> list[dict]:
    """The units of a jobs file, in order, as ``photongrid batch --list`` prints them."""
    p = subprocess.run([binary, "batch", str(jobs), "--list"], capture_output=True, text=True)
    if p.returncode != 0:
        raise RuntimeError(f"{jobs}: {p.stderr.strip()}")
    return [json.loads(line) for line in p.stdout.splitlines() if line.strip()]


def _die_with_parent() -> None:
    """In the child: get SIGKILL when the worker that started it dies (Linux), so a killed worker
    leaves no orphan render racing the task's retry."""
    try:
        import ctypes
        import signal

        libc = ctypes.CDLL(None, use_errno=True)
        PR_SET_PDEATHSIG = 1
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    except Exception:  # not Linux: nothing to do
        pass


def run_unit(
    binary: str,
    jobs: str,
    index: int,
    journal: str | None = None,
    threads: int | None = None,
) -> dict:
    """Run one unit (on a worker) and return its entry of the report.

    A render failure (missing scene, bad option...) is a result, not an exception: it comes
    back as a ``failed`` entry, since running it again would fail the same way. An exception
    (so a Dask retry) is raised only when photongrid itself did not finish: killed by a
    signal, or no report written.
    """
    with tempfile.TemporaryDirectory(prefix="photongrid-dask-") as d:
        report = os.path.join(d, f"unit-{index}.json")
        cmd = [binary, "batch", jobs, "--only", str(index), "--report", report, "--quiet"]
        if journal:
            cmd += ["--journal", journal]
        if threads:
            cmd += ["--threads", str(threads)]
        kw = {"preexec_fn": _die_with_parent} if sys.platform.startswith("linux") else {}
        p = subprocess.run(cmd, capture_output=True, text=True, **kw)
        if p.returncode < 0 or not os.path.exists(report):
            tail = "\n".join(p.stderr.strip().splitlines()[-5:])
            raise RuntimeError(f"unit {index}: photongrid exited with status {p.returncode}: {tail}")
        with open(report) as f:
            doc = json.load(f)
    units = doc["units"]
    if len(units) != 1 or units[0]["index"] != index:
        raise RuntimeError(f"unit {index}: unexpected report {units!r}")
    entry = units[0]
    entry["_photongrid"] = doc.get("photongrid")
    return entry


def totals(units: list[dict], wall_seconds: float) -> dict:
    """Counts per status and seconds, as ``photongrid batch`` computes them."""
    count = lambda s: sum(1 for u in units if u["status"] == s)  # noqa: E731
    return {
        "units": len(units),
        "done": count("done"),
        "skipped": count("skipped"),
        "failed": count("failed"),
        "seconds": wall_seconds,
        "unit_seconds": sum(u.get("seconds") or 0.0 for u in units),
    }


def merge_reports(jobs: str, units: list[dict], run: dict, wall_seconds: float) -> dict:
    """One report document from per-unit entries (the ``photongrid batch --report`` format)."""
    units = sorted(units, key=lambda u: u["index"])
    version = next((u.pop("_photongrid") for u in units if u.get("_photongrid")), None)
    for u in units:
        u.pop("_photongrid", None)
    return {
        "photongrid": version,
        "jobs_file": jobs,
        "run": run,
        "units": units,
        "totals": totals(units, wall_seconds),
    }


def _write_atomic(path: str | os.PathLike, text: str) -> None:
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    with open(tmp, "w") as f:
        f.write(text)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def run_batch(
    client,
    jobs: str | os.PathLike,
    report: str | os.PathLike | None = None,
    *,
    binary: str | None = None,
    journal: str | None = None,
    unit_threads: int | None = None,
    retries: int = 2,
) -> dict:
    """Submit one task per unit of ``jobs`` to ``client``, wait, merge and (optionally) write the report."""
    from distributed import as_completed

    start = time.perf_counter()
    binary = find_binary(binary)
    jobs = str(Path(jobs).resolve())
    journal = str(Path(journal).resolve()) if journal else None
    units = list_units(binary, jobs)
    futures = {}
    for u in units:
        f = client.submit(
            run_unit,
            binary,
            jobs,
            u["index"],
            journal,
            unit_threads,
            pure=False,
            retries=retries,
        )
        futures[f] = u
    entries = []
    for f in as_completed(list(futures)):
        u = futures[f]
        try:
            entries.append(f.result())
        except Exception as e:  # retries used up, or the task's workers kept dying
            entries.append(
                {
                    "index": u["index"],
                    "job": u["job"],
                    "scene": u["scene"],
                    "camera": u.get("camera"),
                    "output": u.get("output"),
                    "status": "failed",
                    "error": f"{type(e).__name__}: {e}",
                    "seconds": 0.0,
                    "stats": None,
                }
            )
    workers = client.scheduler_info().get("workers", {})
    run = {
        "runner": "dask",
        "scheduler": client.scheduler.address,
        "workers": len(workers),
        "units_in_file": len(units),
        "threads_per_unit": unit_threads,
        "retries": retries,
    }
    doc = merge_reports(jobs, entries, run, time.perf_counter() - start)
    if report is not None:
        _write_atomic(report, json.dumps(doc, indent=2))
    return doc
