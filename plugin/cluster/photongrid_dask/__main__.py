"""``python -m photongrid_dask JOBS.toml --report REPORT.json [--scheduler ADDRESS | --local N]``."""

from __future__ import annotations

import argparse
import os
import sys

from . import find_binary, run_batch


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="photongrid_dask",
        description="Render a photongrid JOBS.toml on a Dask cluster, one task per unit "
        "(as listed by `photongrid batch JOBS.toml --list`), and merge the per-unit reports.",
    )
    p.add_argument("jobs", help="the jobs file (same format as `photongrid batch`)")
    p.add_argument("--report", required=True, help="where to write the merged JSON report")
    where = p.add_mutually_exclusive_group()
    where.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="a running scheduler, e.g. tcp://10.0.0.5:8786 (dask-jobqueue, dask-kubernetes, dask-scheduler)",
    )
    where.add_argument(
        "--local", type=int, metavar="N", help="start a LocalCluster of N single-threaded worker processes"
    )
    p.add_argument(
        "--unit-threads",
        type=int,
        metavar="T",
        help="threads for each photongrid task (default: cores/N with --local, all of the worker's cores otherwise)",
    )
    p.add_argument("--bin", help="photongrid binary as seen by the workers (default: $PHOTONGRID_BIN, "
                   "the repository's target/release/photongrid, or photongrid on PATH)")
    p.add_argument("--journal", help="append each unit's start/done/skipped/failed events (JSON lines) here")
    p.add_argument("--retries", type=int, default=2, help="retries of a task that raised (default 2)")
    a = p.parse_args(argv)

    binary = find_binary(a.bin)
    if a.scheduler:
        from distributed import Client

        client = Client(a.scheduler)
        cluster = None
        unit_threads = a.unit_threads
    else:
        from distributed import Client, LocalCluster

        n = a.local or os.cpu_count() or 1
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None)
        client = Client(cluster)
        unit_threads = a.unit_threads or max(1, (os.cpu_count() or 1) // n)
    try:
        report = run_batch(
            client,
            a.jobs,
            a.report,
            binary=binary,
            journal=a.journal,
            unit_threads=unit_threads,
            retries=a.retries,
        )
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    t = report["totals"]
    print(
        f"{a.jobs}: {t['units']} units: {t['done']} done, {t['skipped']} skipped, {t['failed']} failed "
        f"in {t['seconds']:.2f} s; report {a.report}",
        file=sys.stderr,
    )
    failed = [u for u in report["units"] if u["status"] == "failed"]
    for u in failed:
        cam = f", camera {u['camera']}" if u.get("camera") else ""
        print(f"failed: unit {u['index']} (job {u['job']}{cam}): {u.get('error')}", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
