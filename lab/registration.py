"""Registration study: the source body fitted onto target bodies of other meshes, families and units.

Run ``python -m lab.registration [--quick] [--out DIR]``. It prints its figures (and writes
``registration.json`` in DIR when given).

1. **Ground truth by re-meshing.** Every MakeHuman body is re-meshed by libigl (quadric edge-collapse
   decimation, after one loop of midpoint upsampling when more triangles are wanted) to about 5K and
   50K triangles, vertex order shuffled. ``female_average`` is registered onto each and compared
   vertex by vertex with the true same-topology target.
2. **Garments** are transferred (``direct``) through the registered body and through the true target;
   the difference is compared with the untransferred error (the source garment against the transfer
   through the true target), and vertices inside the re-meshed target are counted.
3. **Another family**: MakeHuman garments onto the procedural mannequin (metres, Z up), and a demo
   garment onto a MakeHuman body: residuals and penetration.
4. **Speed** (``--speed``): registration of the 13K-vertex source onto the 50K-triangle re-mesh,
   wall and CPU time, three runs.
5. **Shape prior, leave-one-out** (``--prior both``, the default; ``off``, ``on``): each target is also
   registered with a shape basis of the source's mesh: the other MakeHuman bodies less the source
   (``female_average``), never the target body itself (nor its re-mesh). The figures are given
   without and with it.
6. **Body model** (``--prior makehuman``): the basis is MakeHuman's own targets
   (``garment_transfer.body_model``), read from ``--body-model PATH/targets.npz`` or, by default,
   from the ``makehuman`` wheel that ``pip download`` puts in ``$GARMENT_TRANSFER_LAB_CACHE`` (else
   ``~/.cache/garment_transfer/lab``). The fixture bodies were made from these targets, so this is
   an in-model test; ``--exclude-groups measure hip buttocks`` leaves out the groups that made the
   female targets (an out-of-model test).

Units: the MakeHuman files are in decimetres, so 1 unit = 100 mm.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

from garment_transfer.fitting.registration import register
from garment_transfer.fitting.shape_basis import shape_basis_from_bodies
from garment_transfer.geometry.mesh import mesh_from_triangles
from garment_transfer.geometry.obj import read_obj
from garment_transfer.geometry.proximity import TriangleSurface
from garment_transfer.pipeline.any_body import transfer_to_any_body
from garment_transfer.pipeline.transfer import transfer_garment

from .paths import DEMO_DATA as DEMO
from .paths import MAKEHUMAN_SOURCE as SOURCE
from .paths import SHARED_MAKEHUMAN, makehuman_folder

MAKEHUMAN_WHEEL = "makehuman==1.3.2"

MAKEHUMAN = makehuman_folder() or SHARED_MAKEHUMAN
MM_PER_UNIT = 100.0


def remesh(V, F, triangles, seed=0):
    """Another topology of the same surface: libigl decimation (upsampled first to go finer),
    vertices shuffled.

    Returns
    -------
    U : (k,3) float64
    G : (l,3) int64
    """
    import igl

    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    if triangles > F.shape[0]:
        V, F = igl.upsample(V, F)
    U, G = igl.decimate(V, F, int(triangles))[:2]
    perm = np.random.default_rng(seed).permutation(U.shape[0])
    new_index = np.empty_like(perm)
    new_index[perm] = np.arange(perm.size)
    return np.ascontiguousarray(U[perm]), new_index[np.asarray(G, dtype=np.int64)]


def stats_mm(d):
    d = np.asarray(d) * MM_PER_UNIT
    return {"mean": float(d.mean()), "p95": float(np.quantile(d, 0.95)), "max": float(d.max())}


def body_regions(V):
    """(n,) region names of the MakeHuman body's vertices (Y up, X lateral, +Z forward; decimetres),
    from the source body's own shape, for per-region error figures.
    """
    x, y, z = V[:, 0], V[:, 1], V[:, 2]
    h = (y - y.min()) / np.ptp(y)
    lat = np.abs(x)
    r = np.full(V.shape[0], "torso", dtype=object)
    r[h < 0.06] = "feet"
    r[(h >= 0.06) & (h < 0.47)] = "legs"
    r[(h >= 0.40) & (h < 0.52) & (lat < 0.9)] = "hips/crotch"
    r[(h > 0.82) & (h <= 0.87)] = "neck"
    r[h > 0.87] = "head"
    r[(lat > 1.55) & (h > 0.5)] = "arms"
    r[lat > 3.9] = "hands"
    r[(lat > 1.2) & (lat <= 1.9) & (h > 0.72)] = "shoulders"
    r[(h > 0.63) & (h < 0.78) & (lat < 1.2) & (z > 0.3)] = "chest"
    return r


REGIONS = ("head", "neck", "shoulders", "chest", "torso", "arms", "hands", "hips/crotch", "legs", "feet")


def region_errors(fitted, truth, F):
    """Per region: mean and p95 vertex error, and its mean tangential and normal parts (mm).

    The normal part is along the true target's vertex normal: a fit that lies on the target's
    surface but slides along it has a small normal and a large tangential part.
    """
    from garment_transfer.geometry.mesh import vertex_areas, vertex_normals

    d = fitted - truth
    N = vertex_normals(truth, F)
    dn = np.einsum("ij,ij->i", d, N)
    dt = np.linalg.norm(d - dn[:, None] * N, axis=1)
    e = np.linalg.norm(d, axis=1)
    area = vertex_areas(truth, F)
    out = {"all": {"mean": float(e.mean() * MM_PER_UNIT),
                   "area_weighted_mean": float((e * area).sum() / area.sum() * MM_PER_UNIT),
                   "tangential_mean": float(dt.mean() * MM_PER_UNIT),
                   "normal_mean": float(np.abs(dn).mean() * MM_PER_UNIT)}}
    regions = body_regions(read_obj(MAKEHUMAN / "bodies" / f"{SOURCE}.obj").V)
    for name in REGIONS:
        m = regions == name
        out[name] = {"vertices": int(m.sum()), "mean": float(e[m].mean() * MM_PER_UNIT),
                     "p95": float(np.quantile(e[m], 0.95) * MM_PER_UNIT),
                     "tangential_mean": float(dt[m].mean() * MM_PER_UNIT),
                     "normal_mean": float(np.abs(dn[m]).mean() * MM_PER_UNIT),
                     "vertical_mean": float(d[m, 1].mean() * MM_PER_UNIT)}
    return out


def leave_one_out_basis(source, target_name, bodies):
    """The shape basis for a target: the other bodies less the source, never the target itself.

    Returns
    -------
    names : list of str
    basis : (k,n,3) float64 or None
    """
    names = [b for b in bodies if b not in (target_name, SOURCE)]
    if not names:
        return names, None
    return names, shape_basis_from_bodies(source, [read_obj(MAKEHUMAN / "bodies" / f"{b}.obj", name=b)
                                                   for b in names])


def makehuman_targets(path=None):
    """MakeHuman's ``targets.npz``: ``path`` if given, else from the ``makehuman`` wheel, fetched once
    with ``pip download`` into the lab's cache folder and unpacked there."""
    import subprocess
    import sys
    import zipfile

    if path:
        return Path(path)
    folder = Path(os.environ.get("GARMENT_TRANSFER_LAB_CACHE") or Path.home() / ".cache" / "garment_transfer" / "lab")
    out = folder / "makehuman-targets.npz"
    if out.is_file():
        return out
    folder.mkdir(parents=True, exist_ok=True)
    wheels = sorted(folder.glob("makehuman-*.whl"))
    if not wheels:
        subprocess.run([sys.executable, "-m", "pip", "download", "--no-deps", MAKEHUMAN_WHEEL, "-d", str(folder)],
                       check=True)
        wheels = sorted(folder.glob("makehuman-*.whl"))
    with zipfile.ZipFile(wheels[-1]) as zf:
        data = zf.read("makehuman/data/targets.npz")
    tmp = out.with_suffix(".tmp")
    tmp.write_bytes(data)
    os.replace(tmp, out)
    return out


def body_study(bodies, sizes, garments, prior="both", all_bodies=None, body_model=None, exclude_groups=()):
    source = read_obj(MAKEHUMAN / "bodies" / f"{SOURCE}.obj", name=SOURCE)
    variants = {"off": [False], "on": [True], "both": [False, True], "makehuman": ["makehuman"]}[prior]
    model = None
    if prior == "makehuman":
        from garment_transfer.fitting.body_model import makehuman_shape_basis

        model = makehuman_shape_basis(source, makehuman_targets(body_model), exclude_groups=exclude_groups)
        print(f"body model: {model.basis.shape[0]} sliders from {model.path}"
              f"{' without ' + ', '.join(exclude_groups) if exclude_groups else ''}", flush=True)
    rows = []
    for name in bodies:
        truth = read_obj(MAKEHUMAN / "bodies" / f"{name}.obj", name=name)
        if model is not None:
            basis_names, basis = model.names, model.basis
        else:
            basis_names, basis = leave_one_out_basis(source, name, all_bodies or bodies)
        # The garments through the true target are the same for every variant.
        truths = {g: transfer_garment(source, truth, read_obj(MAKEHUMAN / "garments" / g / f"{SOURCE}.obj",
                                                              name=g), method="direct").V for g in garments}
        for size in sizes:
            U, G = remesh(truth.V, truth.F, size)
            target = mesh_from_triangles(U, G, name=f"{name}_{size}")
            for use_prior in variants:
                if use_prior and basis is None:
                    continue
                t, c = time.perf_counter(), time.process_time()
                reg = register(source, target, cache=False, shape_basis=basis if use_prior else None,
                               shape_bounds=model.bounds if model is not None else (0.0, 1.0),
                               body_model=model is not None)
                wall, cpu = time.perf_counter() - t, time.process_time() - c
                err = np.linalg.norm(reg.V - truth.V, axis=1)
                row = {"target": name, "triangles": int(G.shape[0]), "vertices": int(U.shape[0]),
                       "prior": use_prior, "vertex_error_mm": stats_mm(err),
                       "untransferred_mm": stats_mm(np.linalg.norm(source.V - truth.V, axis=1)),
                       "residual_mm": {k: v * MM_PER_UNIT for k, v in reg.quality.items()
                                       if k.endswith(("_mean", "_p95", "_max")) and "share" not in k},
                       "distorted": reg.quality["distorted"], "wall_s": wall, "cpu_s": cpu,
                       "seconds": reg.seconds,
                       "regions_mm": region_errors(reg.V, truth.V, np.asarray(truth.F)),
                       "garments": garment_study(source, truths, target, reg, garments)}
                if use_prior:
                    row["basis"] = basis_names
                    row["shape_weights"] = [float(v) for v in reg.shape_weights]
                    if model is not None:
                        row["exclude_groups"] = list(exclude_groups)
                        keep = np.flatnonzero(np.abs(reg.shape_weights) >= 0.02)
                        row["basis"] = [basis_names[i] for i in keep]
                        row["shape_weights"] = [float(reg.shape_weights[i]) for i in keep]
                    row["shape_explained"] = reg.quality["shape_explained"]
                    row["shape_used"] = bool(reg.quality["shape_used"])
                rows.append(row)
                print(format_body_row(row), flush=True)
    return rows


def format_summary(rows):
    """One line per target and size: without and with the prior side by side."""
    lines = ["summary (mm; garment difference mean over the garments and its share of the untransferred "
             "error; inside = garment vertices inside the re-meshed target, all garments):",
             f"{'target':>20} {'tris':>6} | {'no prior: body mean/p95':>24} {'garment':>8} {'share':>6} "
             f"{'inside':>6} {'s':>5} | {'prior: body mean/p95':>21} {'garment':>8} {'share':>6} {'inside':>6} "
             f"{'s':>5} weights (explained, used)"]
    keyed = {}
    for r in rows:
        keyed.setdefault((r["target"], r["triangles"]), {})[bool(r["prior"])] = r

    def cells(r):
        if r is None:
            return "", f"{'-':>24} {'':>8} {'':>6} {'':>6} {'':>5}"
        e, gs = r["vertex_error_mm"], r["garments"]
        g = np.mean([x["difference_mm"]["mean"] for x in gs]) if gs else float("nan")
        share = np.mean([x["share_of_untransferred"] for x in gs]) if gs else float("nan")
        inside = sum(x["inside_remeshed_target"] for x in gs)
        return r, f"{e['mean']:>12.2f}/{e['p95']:<11.2f} {g:>8.2f} {share:>6.0%} {inside:>6} {r['wall_s']:>5.1f}"

    for (name, tris), pair in keyed.items():
        _, off = cells(pair.get(False))
        r, on = cells(pair.get(True))
        extra = ""
        if r:
            w = ", ".join(f"{b} {v:.2f}" for b, v in zip(r["basis"], r["shape_weights"]))
            extra = f" {w} ({r['shape_explained']:.0%}, {'used' if r['shape_used'] else 'not used'})"
        lines.append(f"{name:>20} {tris:>6} | {off} | {on[3:] if len(on) > 3 else on}{extra}")
    return "\n".join(lines)


def garment_study(source, truths, target, reg, garments):
    out = []
    surface = TriangleSurface(target.V, target.F)
    for g in garments:
        garment = read_obj(MAKEHUMAN / "garments" / g / f"{SOURCE}.obj", name=g)
        through_truth = truths[g]
        through_reg, _ = transfer_to_any_body(source, target, garment, registration=reg, method="direct")
        diff = np.linalg.norm(through_reg.V - through_truth, axis=1)
        untransferred = np.linalg.norm(garment.V - through_truth, axis=1)
        inside = int((surface.signed_distance(through_reg.V)[0] < 0).sum())
        out.append({"garment": g, "difference_mm": stats_mm(diff),
                    "untransferred_mm": stats_mm(untransferred),
                    "share_of_untransferred": float(diff.mean() / max(untransferred.mean(), 1e-12)),
                    "inside_remeshed_target": inside, "vertices": garment.n_vertices})
    return out


def format_body_row(r):
    e, u = r["vertex_error_mm"], r["untransferred_mm"]
    res = r["residual_mm"]
    prior = {True: ", prior", "makehuman": ", body model"}.get(r.get("prior"), "")
    line = (f"{r['target']:>20} {r['triangles']:>6} tris{prior}: vertex error mean {e['mean']:.2f} mm, p95 "
            f"{e['p95']:.2f}, max {e['max']:.1f} (untransferred mean {u['mean']:.2f}); residual to/from "
            f"target p95 {res['to_target_p95']:.2f}/{res['from_target_p95']:.2f} mm; "
            f"{r['wall_s']:.1f} s wall, {r['cpu_s']:.1f} s CPU")
    if r.get("prior"):
        kind = "body model: weights >= 0.02" if r["prior"] == "makehuman" else "leave-one-out"
        line += (f"\n{'':>22}shape basis ({kind}) " + ", ".join(
            f"{b} {v:.3f}" for b, v in zip(r["basis"], r["shape_weights"])) +
            f"; {r['shape_explained']:.0%} of the misfit explained, {'used' if r['shape_used'] else 'not used'}; "
            + ", ".join(f"{k} {v:.2f} s" for k, v in r["seconds"].items()))
    a = r["regions_mm"]["all"]
    line += (f"\n{'':>22}area-weighted mean {a['area_weighted_mean']:.2f} mm; tangential/normal mean "
             f"{a['tangential_mean']:.2f}/{a['normal_mean']:.2f} mm; per region mean (p95) tangential "
             f"normal vertical:")
    for name in REGIONS:
        g = r["regions_mm"][name]
        line += (f"\n{'':>26}{name:>12} {g['vertices']:>5} v: {g['mean']:6.2f} ({g['p95']:6.2f}) "
                 f"{g['tangential_mean']:6.2f} {g['normal_mean']:5.2f} {g['vertical_mean']:+7.2f}")
    for g in r["garments"]:
        d, gu = g["difference_mm"], g["untransferred_mm"]
        line += (f"\n{'':>22}{g['garment']:>20}: difference mean {d['mean']:.2f} mm, p95 {d['p95']:.2f}, "
                 f"{g['share_of_untransferred']:.0%} of untransferred ({gu['mean']:.2f} mm), "
                 f"{g['inside_remeshed_target']} inside")
    return line


def family_study(garments, demo_garment):
    """MakeHuman garments onto a procedural mannequin, and a demo garment onto a MakeHuman body."""
    rows = []
    if DEMO is None:
        print("family study skipped: no demo data folder", flush=True)
        return rows
    mh = read_obj(MAKEHUMAN / "bodies" / f"{SOURCE}.obj", name=SOURCE)
    mannequin = read_obj(DEMO / "bodies" / "pear.obj", name="mannequin_pear")
    cases = [(mh, mannequin, [read_obj(MAKEHUMAN / "garments" / g / f"{SOURCE}.obj", name=g)
                              for g in garments])]
    banana = read_obj(DEMO / "bodies" / "banana.obj", name="mannequin_banana")
    cases.append((banana, mh, [read_obj(DEMO / "garments" / demo_garment / "banana.obj", name=demo_garment)]))
    for source, target, cloths in cases:
        t = time.perf_counter()
        reg = register(source, target, cache=False, check=False)
        wall = time.perf_counter() - t
        surface = TriangleSurface(target.V, target.F)
        height = reg.quality["height"]
        row = {"source": source.name, "target": target.name, "wall_s": wall,
               "residual_share": {k: reg.quality[k] for k in reg.quality if k.endswith("_share")},
               "distorted": reg.quality["distorted"], "units_scale": reg.quality["units_scale"],
               "garments": []}
        for garment in cloths:
            res, _ = transfer_to_any_body(source, target, garment, registration=reg, method="direct")
            sd = surface.signed_distance(res.V)[0]
            row["garments"].append({"garment": garment.name, "inside": int((sd < 0).sum()),
                                    "vertices": garment.n_vertices,
                                    "deepest_share": float(max(0.0, -sd.min()) / height)})
        rows.append(row)
        q = row["residual_share"]
        print(f"{source.name} -> {target.name}: units x{row['units_scale']:g}; residual to/from target p95 "
              f"{q['to_target_p95_share']:.3%}/{q['from_target_p95_share']:.3%} of the height, max "
              f"{q['to_target_max_share']:.3%}/{q['from_target_max_share']:.3%}; distorted "
              f"{row['distorted']:.2%}; {wall:.1f} s", flush=True)
        for g in row["garments"]:
            print(f"{'':>8}{g['garment']}: {g['inside']} of {g['vertices']} vertices inside the target",
                  flush=True)
    return rows


def speed_study(repeats=3, prior="off", target_name="female_pear", body_model=None):
    """Registration of the 13K-vertex source onto the 50K-triangle re-mesh of a body, timed (with the
    leave-one-out shape basis too when ``prior`` is ``on`` or ``both``)."""
    source = read_obj(MAKEHUMAN / "bodies" / f"{SOURCE}.obj", name=SOURCE)
    truth = read_obj(MAKEHUMAN / "bodies" / f"{target_name}.obj")
    U, G = remesh(truth.V, truth.F, 50000)
    target = mesh_from_triangles(U, G, name=f"{target_name}_50k")
    bounds, model = (0.0, 1.0), prior == "makehuman"
    if model:
        from garment_transfer.fitting.body_model import makehuman_shape_basis

        m = makehuman_shape_basis(source, makehuman_targets(body_model))
        names, basis, bounds = ["MakeHuman targets"], m.basis, m.bounds
    else:
        manifest = json.loads((MAKEHUMAN / "manifest.json").read_text())
        names, basis = leave_one_out_basis(source, target_name, manifest["bodies"])
    rows = []
    for i in range(repeats):
        for use_prior in {"off": [False], "on": [True], "both": [False, True], "makehuman": [True]}[prior]:
            t, c = time.perf_counter(), time.process_time()
            reg = register(source, target, cache=False, shape_basis=basis if use_prior else None,
                           shape_bounds=bounds, body_model=model)
            rows.append({"wall_s": time.perf_counter() - t, "cpu_s": time.process_time() - c,
                         "stages": reg.seconds, "prior": use_prior})
            print(f"speed run {i}{' (prior: ' + ', '.join(names) + ')' if use_prior else ''}: "
                  f"{source.n_vertices} vertices onto {target.n_triangles} triangles: "
                  f"{rows[-1]['wall_s']:.1f} s wall, {rows[-1]['cpu_s']:.1f} s CPU (goal: 3 s, quiet 2 cores); "
                  + ", ".join(f"{k} {v:.2f}" for k, v in reg.seconds.items()), flush=True)
    return rows


def main(argv=None):
    p = argparse.ArgumentParser(prog="python -m lab.registration", description=__doc__.split("\n")[0])
    p.add_argument("--quick", action="store_true", help="two bodies, one size, two garments")
    p.add_argument("--out", help="folder for registration.json")
    p.add_argument("--speed", action="store_true", help="only the timing of the 50K-triangle registration")
    p.add_argument("--speed-target", default="female_pear", help="the body timed by --speed")
    p.add_argument("--prior", choices=["off", "on", "both", "makehuman"], default="both",
                   help="the leave-one-out shape basis (the other MakeHuman bodies): without it, with it, or both; "
                        "makehuman: MakeHuman's own targets as a body model")
    p.add_argument("--body-model", help="MakeHuman's targets.npz for --prior makehuman (default: fetched with pip)")
    p.add_argument("--exclude-groups", nargs="+", default=[],
                   help="target groups left out of the body model (an out-of-model test)")
    p.add_argument("--bodies", nargs="+", help="target bodies (default: all of the manifest)")
    p.add_argument("--sizes", nargs="+", type=int, help="re-mesh sizes in triangles (default 5000 50000)")
    p.add_argument("--garments", type=int, help="only the first N garments of the manifest")
    p.add_argument("--no-family", action="store_true", help="skip the other-family study")
    args = p.parse_args(argv)
    if not MAKEHUMAN.is_dir():
        raise SystemExit(f"MakeHuman data not found at {MAKEHUMAN}")
    if args.speed:
        speed_study(prior=args.prior, target_name=args.speed_target, body_model=args.body_model)
        return 0
    manifest = json.loads((MAKEHUMAN / "manifest.json").read_text())
    bodies, garments, sizes = manifest["bodies"], manifest["garments"], [5000, 50000]
    if args.quick:
        bodies, garments, sizes = ["female_average", "female_pear"], garments[:2], [5000]
    bodies = args.bodies or bodies
    sizes = args.sizes or sizes
    garments = garments[:args.garments] if args.garments else garments
    print(f"source {SOURCE}; re-meshed targets {sizes} triangles; prior {args.prior}; {os.cpu_count()} cores",
          flush=True)
    rows = body_study(bodies, sizes, garments, prior=args.prior, all_bodies=manifest["bodies"],
                      body_model=args.body_model, exclude_groups=tuple(args.exclude_groups))
    print(format_summary(rows), flush=True)
    out = {"bodies": rows,
           "family": [] if args.no_family else family_study(garments[:3] if not args.quick else garments[:1],
                                                            "tshirt")}
    if args.out:
        os.makedirs(args.out, exist_ok=True)
        Path(args.out, "registration.json").write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
