"""Transfer speed at the paper's garment sizes, cold and reused, per stage, with exactness checks.

    python -m lab.speed                          # 28K, 46K, 84K, 156K triangles, then 1M in a fresh process
    python -m lab.speed --baseline b348479       # the same, beside the package as it was at a commit
    python -m lab.speed --sizes 156000 --no-million --json out.json

For each size: the best of ``--repeats`` cold transfers (prepare + transfer) and reused ones (the
garment's factor and binding kept), seconds per stage, the paper's published time and the ratio,
and the process CPU seconds (on a shared machine the CPU time says what the wall time cannot).
``exact`` is the largest relative difference, over a sample of 2,000 query points near the target
body, between ``TriangleSurface.closest`` and a brute-force search over all body triangles (0 means
the same closest points). ``--baseline REV`` runs the same measurement on the package from another
commit (``git archive``) in a subprocess, so both columns come from one run on one machine.
The 1M-triangle transfer runs in a fresh process, so its peak memory (max resident set) is its own.

The garment is ``lab.bench.tube_dress`` around the source body of
``lab.bench.bench_bodies`` (MakeHuman bodies when ../shared/data/makehuman exists).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

import numpy as np

from .bench import PAPER_SECONDS, TUBE_CROSSINGS, bench_bodies, exactness, machine_description, tube_dress

ROOT = Path(__file__).resolve().parents[1]

SIZES = (28000, 46000, 84000, 156000)
SAMPLE = 2000


def _transfer(*args, **options):
    """``transfer_garment`` as the benchmark times it: without the crossing pass (``bench.TUBE_CROSSINGS``)
    where the package measured has one (a baseline commit may predate it)."""
    import inspect

    from garment_transfer.pipeline.transfer import transfer_garment


    if "resolve_crossings" in inspect.signature(transfer_garment).parameters:
        options["resolve_crossings"] = TUBE_CROSSINGS
    return transfer_garment(*args, **options)


def measure(sizes, repeats, check=True):
    """Cold and reused transfers at each size; returns a list of records."""
    from garment_transfer.pipeline.transfer import prepare_garment

    source, bodies = bench_bodies(1)
    target = bodies[0]
    rng = np.random.default_rng(0)
    records = []
    for n in sizes:
        garment = tube_dress(source, n)
        best = {}
        for kind in ("cold", "reused"):
            prepared = prepare_garment(source, garment) if kind == "reused" else None
            for _ in range(repeats):
                c, t = time.process_time(), time.perf_counter()
                r = _transfer(source, target, garment, prepared=prepared)
                wall, cpu = time.perf_counter() - t, time.process_time() - c
                if kind not in best or wall < best[kind]["wall"]:
                    best[kind] = dict(r.seconds, wall=wall, cpu=cpu, inside=r.penetrating_vertices,
                                      solver=r.info.get("solver"))
        rec = {"requested": n, "triangles": garment.n_triangles, "vertices": garment.n_vertices, **best,
               "paper": PAPER_SECONDS.get(n)}
        if check:
            rec["exact"] = exactness(r.V, target, rng, SAMPLE)
        records.append(rec)
    return records


def million(triangles=1_000_000):
    """One cold transfer of a garment of ``triangles`` triangles; its time and this process's peak."""

    source, bodies = bench_bodies(1)
    garment = tube_dress(source, triangles)
    t = time.perf_counter()
    r = _transfer(source, bodies[0], garment)
    wall = time.perf_counter() - t
    return {"triangles": garment.n_triangles, "vertices": garment.n_vertices, "wall": wall,
            "stages": r.seconds, "inside": r.penetrating_vertices, "peak_mb": peak_mb(),
            "solver": r.info.get("solver")}


def peak_mb():
    try:
        import resource
    except ImportError:     # Windows: no peak figure
        return None
    kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return kb / 1024 if sys.platform != "darwin" else kb / 2 ** 20


def run_worker(args, package_root=None):
    """Run this module as a worker in a fresh process (optionally on another copy of the package)."""
    env = dict(os.environ)
    paths = [str(package_root)] if package_root else []
    env["PYTHONPATH"] = os.pathsep.join(paths + [str(ROOT), env.get("PYTHONPATH", "")])
    # ``-m`` puts the working folder first on sys.path: for a baseline it must be the package's copy,
    # not the checkout (whose garment_transfer would win).
    proc = subprocess.run([sys.executable, "-m", "lab.speed", "--worker", *args], capture_output=True,
                          text=True, env=env, cwd=package_root or ROOT)
    if proc.returncode != 0:
        raise RuntimeError(f"worker {args} failed:\n{proc.stderr[-3000:]}")
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    used = Path(out["package"]).resolve()
    if package_root and Path(package_root).resolve() not in used.parents:
        raise RuntimeError(f"the baseline worker imported {used}, not the package in {package_root}")
    return out["result"]


def package_at(rev, folder):
    """Extract garment_transfer/ as it was at ``rev`` into ``folder``; returns the folder."""
    archive = subprocess.run(["git", "archive", "--format=tar", rev, "garment_transfer"], cwd=ROOT,
                             capture_output=True, check=True).stdout
    tar = Path(folder) / "package.tar"
    tar.write_bytes(archive)
    with tarfile.open(tar) as tf:
        tf.extractall(folder)
    return Path(folder)


def fmt(x, width=7, digits=3):
    return f"{x:{width}.{digits}f}" if isinstance(x, (int, float)) else f"{'-':>{width}}"


def report(ours, base, mill, base_mill):
    stages = ["field", "bind", "embed", "factor", "solve", "fix"]
    lines = [f"{'triangles':>9} {'':8} {'cold':>7} {'reused':>7} {'cpu c':>7} {'cpu r':>7} {'paper':>7} "
             f"{'x cold':>7} {'x reus':>7} {'exact':>9}   cold stages: " + " ".join(stages)]
    for i, r in enumerate(ours):
        for name, rec in (("ours", r), ("baseline", base[i] if base else None)):
            if rec is None:
                continue
            paper = rec["paper"]
            xc = paper / rec["cold"]["wall"] if paper else None
            xr = paper / rec["reused"]["wall"] if paper else None
            ex = f"{rec['exact']:9.1e}" if "exact" in rec else f"{'-':>9}"
            st = " ".join(f"{rec['cold'].get(s, 0.0):.3f}" for s in stages)
            lines.append(f"{rec['triangles']:>9} {name:8} {fmt(rec['cold']['wall'])} {fmt(rec['reused']['wall'])} "
                         f"{fmt(rec['cold']['cpu'])} {fmt(rec['reused']['cpu'])} {fmt(paper)} "
                         f"{fmt(xc, 7, 1)} {fmt(xr, 7, 1)} {ex}   {st}  ({_solvers(rec)})")
        rs = " ".join(f"{s}={r['reused'].get(s, 0.0):.3f}" for s in stages if s in r["reused"])
        lines.append(f"{'':>9} {'':8} reused stages (ours): {rs}")
    for name, m in (("ours", mill), ("baseline", base_mill)):
        if m:
            peak = f"{m['peak_mb']:.0f} MB" if m["peak_mb"] else "n/a"
            st = " ".join(f"{k}={v:.2f}" for k, v in m["stages"].items())
            lines.append(f"{m['triangles']} triangles ({name}, fresh process): {m['wall']:.2f} s, "
                         f"peak {peak}; {st}; solver {m.get('solver') or 'factor'}")
    lines.append("cold/reused: wall seconds, best of the repeats; cpu: process CPU seconds of that run; "
                 "paper: Shi et al. table 2 (i7-8750H); x: paper / ours; (cold/reused Poisson solver: "
                 "factor, or multigrid whose hierarchy is the 'factor' stage)")
    return lines


def _solvers(rec):
    # A baseline from before the choice of solver always factored.
    return "/".join(rec[k].get("solver") or "factor" for k in ("cold", "reused"))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=list(SIZES))
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--baseline", metavar="REV", help="also measure the package at this git commit")
    ap.add_argument("--no-million", action="store_true", help="skip the 1M-triangle run")
    ap.add_argument("--no-check", action="store_true", help="skip the brute-force exactness column")
    ap.add_argument("--json", type=Path, help="write all figures to this file")
    ap.add_argument("--worker", nargs="*", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.worker is not None:
        # Internal: one measurement in this process, JSON on the last line of stdout.
        what = args.worker[0]
        out = million() if what == "million" else measure(args.sizes, args.repeats, not args.no_check)
        import garment_transfer

        print(json.dumps({"package": garment_transfer.__file__, "result": out}))
        return 0

    load0 = os.getloadavg() if hasattr(os, "getloadavg") else None
    common = ["--sizes", *map(str, args.sizes), "--repeats", str(args.repeats)]
    common += ["--no-check"] if args.no_check else []
    ours = run_worker(["sizes", *common])
    mill = None if args.no_million else run_worker(["million"])
    base = base_mill = None
    if args.baseline:
        with tempfile.TemporaryDirectory(prefix="speed_baseline_") as tmp:
            pkg = package_at(args.baseline, tmp)
            base = run_worker(["sizes", *common], pkg)
            base_mill = None if args.no_million else run_worker(["million"], pkg)
    load1 = os.getloadavg() if hasattr(os, "getloadavg") else None

    machine = machine_description()
    print(f"machine: {machine['cpu']}, {machine['cores']} cores, numpy {machine['numpy']}; "
          f"load average {load0[0]:.1f} before, {load1[0]:.1f} after" if load0 else "")
    for line in report(ours, base, mill, base_mill):
        print(line)
    if args.json:
        data = {"machine": machine, "load": [load0, load1], "ours": ours, "baseline": base,
                "baseline_rev": args.baseline, "million": mill, "baseline_million": base_mill}
        tmp = args.json.with_suffix(args.json.suffix + ".tmp")
        tmp.write_text(json.dumps(data, indent=1))
        os.replace(tmp, args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
