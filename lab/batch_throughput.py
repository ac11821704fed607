"""Throughput of ``python -m garment_transfer batch``: transfers per hour with 1 and 2 workers, the
speed-up, Dask's overhead per pair, and what a catalogue of 10,000 garments on 20 bodies would take.

    python -m lab.batch_throughput [--garments N] [--json FILE] [--data MAKEHUMAN_FOLDER]

Data: the MakeHuman fixtures (real garments of 1.7K-8.4K vertices on a 26.8K-triangle body), the
garments dressed on ``female_average`` transferred to the four other bodies, with the reference fits
on those bodies for the metrics (what a catalogue run does for every pair). Every run starts with
empty caches and an empty results folder, so it does all the work.

Runs, one after the other on the same pairs:

- ``serial``: in this process, the baseline (no scheduler at all);
- ``dask-1``: a local Dask cluster with one worker process: the same work through the scheduler, so
  ``(dask-1 - serial) / pairs`` is the scheduler's overhead per pair (transport, bookkeeping, the stop
  flag checked before each pair, the worker's own caches starting cold);
- ``dask-2``: two worker processes: the speed-up on this machine;
- ``pool-2``: the process pool (no Dask) with two workers, for comparison;
- a round trip of empty tasks through the same one-worker cluster: the scheduler's cost per task.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MAKEHUMAN = ROOT.parent / "shared" / "data" / "makehuman"

CATALOGUE_GARMENTS = 10_000
CATALOGUE_BODIES = 20
WORKER_COUNTS = (1, 2, 4, 8, 16, 32, 64, 128, 256, 512)


def _noop(i):
    return i


def _timed_run(cat, out, **kw):
    from garment_transfer.pipeline import batch

    batch.clear_input_cache()
    shutil.rmtree(out, ignore_errors=True)
    t = time.perf_counter()
    s = batch.run_batch(cat, out, **kw)
    wall = time.perf_counter() - t
    if not s.ok or s.counts["done"] != cat.n_pairs:
        raise SystemExit(f"the run did not transfer every pair: {s.counts}")
    garments = {r["garment"]: r for r in s.records}.values()
    busy = sum(r.get("garment_seconds", 0.0) for r in garments)
    cpu = sum(r.get("garment_cpu_seconds", 0.0) for r in garments)
    return {"wall": wall, "pairs": cat.n_pairs, "per_hour": 3600 * cat.n_pairs / wall,
            "worker_busy": busy, "worker_cpu": cpu, "records": s.records}


def _cluster(workers):
    import dask
    import distributed

    # As the batch command's own local cluster (garment_transfer.batch): no profiler sampling.
    with dask.config.set({"distributed.worker.profile.enabled": False}):
        cluster = distributed.LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                           dashboard_address=None)
    client = distributed.Client(cluster)
    client.wait_for_workers(workers)
    return cluster, client


def estimate(per_pair, prepare, overhead_pair, efficiency, workers, garments=CATALOGUE_GARMENTS,
             bodies=CATALOGUE_BODIES, startup=60.0):
    """Hours for ``garments`` garments on ``bodies`` bodies (each garment to ``bodies - 1`` targets).

    One work unit is a garment: ``prepare + targets * (per_pair + overhead_pair)`` seconds on one
    worker; the units are spread over ``workers`` in whole units (the last round may be partly idle),
    each worker running at ``efficiency`` of a lone worker's speed; ``startup`` covers starting the
    cluster and the workers' first reads.
    """
    targets = bodies - 1
    unit = prepare + targets * (per_pair + overhead_pair)
    rounds = math.ceil(garments / workers)
    return (startup + rounds * unit / efficiency) / 3600


def main(argv=None):
    p = argparse.ArgumentParser(prog="python -m lab.batch_throughput", description=__doc__.split("\n\n")[0])
    p.add_argument("--garments", type=int, default=4, help="MakeHuman garments to use (1-8; default 4)")
    p.add_argument("--json", help="also write the figures to this JSON file")
    p.add_argument("--data", type=Path, default=MAKEHUMAN,
                   help=f"the MakeHuman fixtures (default {MAKEHUMAN})")
    args = p.parse_args(argv)
    if not (args.data / "bodies").is_dir():
        raise SystemExit(f"the MakeHuman fixtures are needed: {args.data} (--data)")
    from garment_transfer.pipeline.catalogue import read_catalogue

    full = read_catalogue(args.data, source="female_average")
    cat = type(full)(full.origin, full.jobs[: args.garments])
    print(f"catalogue: {len(cat.jobs)} MakeHuman garments x {len(cat.jobs[0].targets)} targets = "
          f"{cat.n_pairs} pairs; {os.cpu_count()} cores on this machine, load average "
          f"{os.getloadavg()[0]:.1f} (other processes share them: the figures are only as good as that)")
    tmp = Path(tempfile.mkdtemp(prefix="batch-throughput-"))
    runs = {}
    try:
        runs["serial"] = _timed_run(cat, tmp / "serial", workers=1)
        cluster, client = _cluster(1)
        try:
            runs["dask-1"] = _timed_run(cat, tmp / "dask1", client=client)
            client.submit(_noop, -1).result()
            n = 500
            t = time.perf_counter()
            client.gather(client.map(_noop, range(n), pure=False))
            task_overhead = (time.perf_counter() - t) / n
        finally:
            client.close()
            cluster.close()
        cluster, client = _cluster(2)
        try:
            runs["dask-2"] = _timed_run(cat, tmp / "dask2", client=client)
        finally:
            client.close()
            cluster.close()
        runs["pool-2"] = _timed_run(cat, tmp / "pool2", workers=2)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)

    pairs = cat.n_pairs
    serial = runs["serial"]
    targets = len(cat.jobs[0].targets)
    done = [r for r in serial["records"] if r["outcome"] == "done"]
    prepare = sum({r["garment"]: r["prepare_seconds"] for r in done}.values()) / len(cat.jobs)
    # Everything else the serial run did (reading, hashing, transfer, metrics, writing), per pair.
    per_pair = (serial["wall"] - prepare * len(cat.jobs)) / pairs
    # Core-seconds: what a garment costs on a core of its own, whatever else ran beside it here.
    cpu_garment = serial["worker_cpu"] / len(cat.jobs)
    overhead_pair = (runs["dask-1"]["wall"] - serial["wall"]) / pairs
    speedup = runs["dask-1"]["wall"] / runs["dask-2"]["wall"]
    efficiency = speedup / 2
    print()
    print(f"{'run':8} {'wall s':>8} {'pairs/hour':>11} {'speed-up vs serial':>19} {'worker CPU s':>13}")
    for name, r in runs.items():
        print(f"{name:8} {r['wall']:8.1f} {r['per_hour']:11.0f} {serial['wall'] / r['wall']:19.2f} "
              f"{r['worker_cpu']:13.1f}")
    print()
    print(f"per pair (serial, wall): {per_pair:.3f} s reading, transfer, metrics, writing; "
          f"per garment: {prepare:.3f} s preparation (binding, factor), shared by its {targets} targets")
    print(f"per garment of {targets} targets (serial, CPU): {cpu_garment:.2f} core-seconds = "
          f"{cpu_garment / targets:.2f} per pair")
    print(f"speed-up 2 Dask workers vs 1: {speedup:.2f}x (parallel efficiency {efficiency:.0%})")
    print(f"Dask overhead per pair (dask-1 - serial, wall): {1000 * overhead_pair:+.1f} ms; "
          f"per empty task round trip: {1000 * task_overhead:.2f} ms, i.e. "
          f"{1000 * task_overhead / targets:.2f} ms per pair with one task per garment")
    print()
    print(f"Estimate: {CATALOGUE_GARMENTS:,} garments dressed on one of {CATALOGUE_BODIES} bodies, each "
          f"transferred to the other {CATALOGUE_BODIES - 1} "
          f"({CATALOGUE_GARMENTS * (CATALOGUE_BODIES - 1):,} transfers)")
    print("assumptions: garments and bodies like these (the MakeHuman mix); one worker process per core, "
          "each core its own (a garment costs its measured core-seconds: "
          f"{cpu_garment / targets:.2f} s per pair, preparation {prepare:.2f} s per garment, as measured "
          "here); the scheduler's cost per garment = the empty task round trip; garments independent, so "
          "the work divides evenly over the workers up to the last round; 60 s to start; the shared "
          "filesystem keeps up (~0.3 MB read and written per pair). 'here' applies the 2-worker "
          "efficiency measured on this machine instead of 100%.")
    pair_cpu = (cpu_garment - prepare) / targets
    table = []
    for w in WORKER_COUNTS:
        ideal = estimate(pair_cpu, prepare, task_overhead / (CATALOGUE_BODIES - 1), 1.0, w)
        here = estimate(pair_cpu, prepare, task_overhead / (CATALOGUE_BODIES - 1), efficiency, w)
        table.append({"workers": w, "hours": ideal, "hours_at_measured_efficiency": here})
        print(f"  {w:4d} workers: {ideal:8.2f} h   (here: {here:8.2f} h)")
    print(f"load average at the end: {os.getloadavg()[0]:.1f}")
    out = {"pairs": pairs, "garments": len(cat.jobs), "cores": os.cpu_count(), "load": os.getloadavg()[0],
           "runs": {k: {kk: v for kk, v in r.items() if kk != "records"} for k, r in runs.items()},
           "per_pair_seconds": per_pair, "prepare_seconds": prepare, "cpu_per_garment": cpu_garment,
           "overhead_per_pair_seconds": overhead_pair, "empty_task_seconds": task_overhead,
           "speedup_2_workers": speedup, "estimate_hours": table}
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1) + "\n")
    return out


if __name__ == "__main__":
    main()
