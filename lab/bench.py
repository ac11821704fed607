"""Transfer speed at the paper's garment sizes, cold and with the garment's factor reused.

The garment is a dress made for the benchmark around the source body: a tube from the chest to
the knees with regular folds, at exactly the requested triangle count, so every size has the same
shape and only the resolution changes. Bodies: the MakeHuman fixtures when present (26,756
triangles), otherwise the procedural mannequins.
"""

from __future__ import annotations

import os
import platform
import time

import numpy as np

from garment_transfer.geometry.mesh import Mesh, mesh_from_polygons

from .paths import MAKEHUMAN_SOURCE, makehuman_folder

#: The benchmark dress is a tube the arms pass through (a speed probe, not a garment one could wear): the
#: crossing pass (``clearance.separate``) cannot untangle it, so the speed figures time the transfer
#: without that pass. Its cost on real garments: ``python -m lab.intersections``.
TUBE_CROSSINGS = False

#: The paper's table 2 ("T", laptop i7-8750H), seconds for a whole transfer: published figures.
PAPER_SECONDS = {28000: 0.764, 46000: 1.301, 84000: 2.822, 156000: 5.928}


def bench_bodies(n_targets=6):
    """The source body and ``n_targets`` target bodies (same topology).

    Returns
    -------
    source : Mesh
    targets : list of Mesh
    """
    from garment_transfer.geometry.obj import read_obj

    folder = makehuman_folder()
    if folder is not None:
        names = ["female_pear", "female_slim_banana", "male_average", "male_slim"]
        source = read_obj(folder / "bodies" / f"{MAKEHUMAN_SOURCE}.obj", name=MAKEHUMAN_SOURCE)
        bodies = [read_obj(folder / "bodies" / f"{n}.obj", name=n) for n in names]
    else:
        from .procedural.mannequin import PRESETS, mannequin

        names = [n for n in PRESETS if n != "banana"]
        V, F = mannequin("banana")
        source = mesh_from_polygons(V, F, name="banana")
        bodies = [mesh_from_polygons(mannequin(n)[0], F, name=n) for n in names]
    i = 0
    while len(bodies) < n_targets:
        a, b = bodies[i % len(names)], bodies[(i + 1) % len(names)]
        bodies.append(a.with_vertices(0.5 * (a.V + b.V), name=f"{a.name}+{b.name}"))
        i += 1
    return source, bodies[:n_targets]


def tube_dress(body: Mesh, triangles: int, folds=24, fold_depth=0.012):
    """A dress around ``body`` with ``folds`` vertical folds and exactly ``triangles`` triangles
    (rounded to the grid).

    Returns
    -------
    Mesh
        Quads, ``2 * nu * (nv - 1)`` triangles.
    """
    V = body.V
    ext = V.max(axis=0) - V.min(axis=0)
    up = int(np.argmax(ext))
    side = [a for a in range(3) if a != up]
    height = float(ext[up])
    base = float(V[:, up].min())
    z0, z1 = base + 0.30 * height, base + 0.70 * height
    nu = max(8, int(round(np.sqrt(triangles / 2 * (2 * np.pi * 0.18 / 0.4)))))
    nv = max(2, int(round(triangles / (2 * nu))) + 1)
    zs = np.linspace(z0, z1, nv)
    theta = np.linspace(0, 2 * np.pi, nu, endpoint=False)
    centre = V[:, side].mean(axis=0)
    rel = V[:, side] - centre
    ang = np.arctan2(rel[:, 1], rel[:, 0])
    rad = np.linalg.norm(rel, axis=1)
    # Per height and angle sector: the body's outer radius, plus ease.
    sectors = 32
    out = np.zeros((nv, nu))
    sec_of_theta = ((theta + np.pi) / (2 * np.pi) * sectors).astype(int) % sectors
    sec = ((ang + np.pi) / (2 * np.pi) * sectors).astype(int) % sectors
    slab = 0.04 * height
    for i, z in enumerate(zs):
        near = np.abs(V[:, up] - z) < slab
        r = np.zeros(sectors)
        np.maximum.at(r, sec[near], rad[near])
        r = np.maximum(r, r.max() * 0.5)
        out[i] = r[sec_of_theta]
    out = out + 0.02 * height + fold_depth * height * np.sin(folds * theta)[None, :]
    P = np.zeros((nv, nu, 3))
    P[:, :, up] = zs[:, None]
    P[:, :, side[0]] = centre[0] + out * np.cos(theta)[None, :]
    P[:, :, side[1]] = centre[1] + out * np.sin(theta)[None, :]
    idx = np.arange(nv * nu).reshape(nv, nu)
    quads = np.stack([idx[:-1], np.roll(idx[:-1], -1, axis=1), np.roll(idx[1:], -1, axis=1), idx[1:]],
                     axis=2).reshape(-1, 4)
    return mesh_from_polygons(P.reshape(-1, 3), quads, name=f"dress_{triangles}")


def brute_force_distance(P, V, F, closest_on_triangles, chunk=8):
    """Distance from each point to the nearest of all triangles, by evaluating every one."""
    A, B, C = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    m = F.shape[0]
    out = np.empty(P.shape[0])
    for i in range(0, P.shape[0], chunk):
        p = P[i:i + chunk]
        k = p.shape[0]
        Q, _ = closest_on_triangles(np.repeat(p, m, axis=0), np.tile(A, (k, 1)), np.tile(B, (k, 1)),
                                    np.tile(C, (k, 1)))
        out[i:i + k] = np.linalg.norm(np.repeat(p, m, axis=0) - Q, axis=1).reshape(k, m).min(axis=1)
    return out


def exactness(V_result, body, rng, sample=2000):
    """Max relative difference of TriangleSurface.closest against brute force on ``sample`` points."""
    from garment_transfer.geometry.proximity import TriangleSurface, closest_on_triangles

    pick = rng.choice(V_result.shape[0], min(sample, V_result.shape[0]), replace=False)
    P = V_result[pick].copy()
    scale = float(np.ptp(body.V, axis=0).max())
    # Half where the fix queries (the garment), half spread around it.
    P[::2] += rng.normal(scale=0.03 * scale, size=P[::2].shape)
    d = TriangleSurface(body.V, body.F).closest(P)[1]
    ref = brute_force_distance(P, body.V, body.F, closest_on_triangles)
    return float(np.max(np.abs(d - ref) / np.maximum(ref, 1e-300)))


def _time_transfer(source, target, garment, prepared=None):
    from garment_transfer.pipeline.transfer import transfer_garment

    t = time.perf_counter()
    r = transfer_garment(source, target, garment, prepared=prepared, resolve_crossings=TUBE_CROSSINGS)
    wall = time.perf_counter() - t
    return wall, r


#: Points per size whose closest points are checked against a brute-force search over all body
#: triangles (about 9 s per size on 2 cores; ``python -m lab.speed`` checks 2,000).
EXACT_SAMPLE = 500


def run_bench(sizes=(28000, 46000, 84000, 156000), repeats=3, targets=6, progress=None,
              exact_sample=EXACT_SAMPLE):
    """Time the transfer at each garment size, cold and with the factor reused, and one garment to
    several targets; check the closest points of ``exact_sample`` points near each result against
    brute force (``exact``: the largest relative difference; 0 to rounding means the same points).

    Returns
    -------
    dict
        ``machine``, ``body``, ``sizes`` (a list of per-size records with per-stage ``cold`` and
        ``reused`` seconds and ``paper_seconds``), ``multi_target``.
    """
    from garment_transfer.pipeline.transfer import prepare_garment

    source, bodies = bench_bodies(max(targets, 1))
    target = bodies[0]
    records = []
    steps = len(sizes) + 1
    for i, n in enumerate(sizes):
        if progress:
            progress(i / steps, f"{n} triangles")
        garment = tube_dress(source, n)
        cold, reused = None, None
        for _ in range(repeats):
            wall, r = _time_transfer(source, target, garment)
            if cold is None or wall < cold["wall"]:
                cold = dict(r.seconds, wall=wall, penetrating_vertices=r.penetrating_vertices)
                cold_solver = r.info.get("solver")
        prepared = prepare_garment(source, garment)
        for _ in range(repeats):
            wall, r = _time_transfer(source, target, garment, prepared)
            if reused is None or wall < reused["wall"]:
                reused = dict(r.seconds, wall=wall)
        paper = PAPER_SECONDS.get(n)
        solver = {"cold": cold_solver, "reused": r.info.get("solver")}
        exact = exactness(r.V, target, np.random.default_rng(0), exact_sample) if exact_sample else None
        records.append({"triangles": garment.n_triangles, "requested": n, "vertices": garment.n_vertices,
                        "cold": cold, "reused": reused, "paper_seconds": paper, "solver": solver,
                        "exact": exact, "exact_sample": exact_sample,
                        "speedup_cold": paper / cold["wall"] if paper else None,
                        "speedup_reused": paper / reused["wall"] if paper else None})
    multi = None
    if targets and sizes:
        if progress:
            progress(len(sizes) / steps, "multi-target")
        garment = tube_dress(source, max(sizes))
        t = time.perf_counter()
        prepared = prepare_garment(source, garment)
        prep = time.perf_counter() - t
        per = [_time_transfer(source, b, garment, prepared)[0] for b in bodies[:targets]]
        cold_each = records[-1]["cold"]["wall"]
        multi = {"triangles": garment.n_triangles, "targets": [b.name for b in bodies[:targets]],
                 "prepare_seconds": prep, "per_target_seconds": per,
                 "total_seconds": prep + sum(per),
                 "without_reuse_seconds": cold_each * len(per)}
    if progress:
        progress(1.0, "done")
    return {"machine": machine_description(), "date": time.strftime("%Y-%m-%d"),
            "body": {"name": source.name, "triangles": source.n_triangles}, "sizes": records,
            "multi_target": multi}


def machine_description():
    cpu = platform.processor() or "unknown CPU"
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    return {"cpu": cpu, "cores": os.cpu_count(), "python": platform.python_version(),
            "numpy": np.__version__}


def format_bench(out):
    """Lines of a plain-text table of ``run_bench``'s result."""
    m = out["machine"]
    lines = [f"machine: {m['cpu']}, {m['cores']} cores; body {out['body']['name']} "
             f"({out['body']['triangles']} triangles); best of repeats, seconds",
             f"{'triangles':>10} {'cold':>7} {'reused':>7} {'paper':>7} {'x cold':>7} {'x reused':>8}"
             f" {'exact':>8} {'solver':>16}   stages (cold)"]
    for r in out["sizes"]:
        stages = " ".join(f"{k}={v:.3f}" for k, v in r["cold"].items()
                          if k not in ("wall", "total", "penetrating_vertices"))
        paper = f"{r['paper_seconds']:.3f}" if r["paper_seconds"] else "-"
        sc = f"{r['speedup_cold']:.1f}" if r["speedup_cold"] else "-"
        sr = f"{r['speedup_reused']:.1f}" if r["speedup_reused"] else "-"
        ex = f"{r['exact']:.1e}" if r.get("exact") is not None else "-"
        lines.append(f"{r['triangles']:>10} {r['cold']['wall']:7.3f} {r['reused']['wall']:7.3f} "
                     f"{paper:>7} {sc:>7} {sr:>8} {ex:>8} {solver_text(r):>16}   {stages}")
    mt = out.get("multi_target")
    if mt:
        lines.append(f"one garment ({mt['triangles']} triangles) to {len(mt['targets'])} bodies: "
                     f"{mt['total_seconds']:.2f} s with the factor reused "
                     f"(prepare {mt['prepare_seconds']:.2f} s, then "
                     f"{np.mean(mt['per_target_seconds']):.3f} s per body) against "
                     f"{mt['without_reuse_seconds']:.2f} s cold each time")
    lines.append("paper: Shi et al., published times on an i7-8750H laptop; exact: largest relative difference "
                 "of the closest points near the result from a brute-force search; solver: the Poisson "
                 "solve cold/reused")
    return lines


def solver_text(r):
    s = r.get("solver") or {}
    return f"{s.get('cold') or 'factor'}/{s.get('reused') or 'factor'}"
