"""What the user waits for on another body mesh: registration cold and cached, and the whole ``transfer``
command with and without one, beside a baseline commit measured in the same session.

    python -m lab.registration_speed                          # this checkout
    python -m lab.registration_speed --baseline 9fb52f1       # and the package at that commit, side by side
    python -m lab.registration_speed --repeats 1 --targets mh_50k --no-crossing-pass --json out.json

Targets (written once as OBJ files in a temporary folder; both packages read the same files), the source
being MakeHuman's ``female_average`` (13,380 vertices, decimetres, Y up):

- ``mh_5k``, ``mh_50k``: MakeHuman's ``female_pear`` re-meshed to about 5K and 50K triangles
  (``lab.registration.remesh``: libigl's decimation, vertices shuffled);
- ``family_50k``: the procedural mannequin ``heavy`` of the demo data (metres, Z up, another mesh family)
  re-meshed to about 50K triangles. (The mannequin ``pear`` re-meshed so is refused, before and after
  the coarse-to-fine fit: 2.5-2.7% of the fitted triangles distorted, against a limit of 2%.)

Measured, for each package:

- **register** (in one worker process, after one untimed fit that loads the libraries): the cold fit (no
  cache) and the cached one (read back from a cache folder and checked, as ``transfer`` does), the best and
  the median of ``--repeats`` (wall and process CPU seconds);
- **command** (``python -m garment_transfer transfer`` in a fresh process, as a user runs it, wall and CPU
  seconds of the child, the best of ``--repeats``): a MakeHuman suit onto each target, the registration
  cold (``--no-cache``) and cached, with and without the crossing pass; the same onto the true
  ``female_pear`` (the source's mesh: no registration); and a demo dress from the mannequin ``banana``
  onto the mannequin ``heavy`` (its mesh) and onto its 50K re-mesh (registered).

Ratios: each figure over the baseline's, and each registered command over the same-mesh command of its
garment (the issue's "three times the same-mesh command"). Speed is printed, never asserted: on a shared
machine wall time follows the load (the load average is printed before and after), the CPU time less so.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from .bench import machine_description
from .paths import DEMO_DATA, MAKEHUMAN_SOURCE, makehuman_folder
from .speed import ROOT, package_at

SUIT = "female_casualsuit01"
DRESS = "formal_dress"
REMESHED = {"mh_5k": ("makehuman", "female_pear", 5000), "mh_50k": ("makehuman", "female_pear", 50000),
            "family_50k": ("demo", "heavy", 50000)}


def write_targets(folder, names):
    """The re-meshed targets as OBJ files in ``folder``: {name: path}."""
    from garment_transfer.geometry.mesh import mesh_from_triangles
    from garment_transfer.geometry.obj import read_obj, write_obj

    from .registration import remesh

    paths = {}
    for name in names:
        family, body, size = REMESHED[name]
        root = makehuman_folder() if family == "makehuman" else DEMO_DATA
        truth = read_obj(root / "bodies" / f"{body}.obj")
        U, G = remesh(truth.V, truth.F, size)
        paths[name] = str(Path(folder) / f"{name}.obj")
        write_obj(paths[name], mesh_from_triangles(U, G, name=name), header=f"{body} re-meshed to {size} triangles")
    return paths


def _stats(runs):
    walls = [r["wall"] for r in runs]
    best = min(runs, key=lambda r: r["wall"])
    return {"best": best["wall"], "median": statistics.median(walls), "cpu": best["cpu"], "runs": walls}


def measure_register(targets, repeats):
    """Cold and cached registrations onto each target file, in this process."""
    from garment_transfer import register
    from garment_transfer.geometry.obj import read_obj

    source = read_obj(makehuman_folder() / "bodies" / f"{MAKEHUMAN_SOURCE}.obj", name=MAKEHUMAN_SOURCE)
    out = {}
    with tempfile.TemporaryDirectory(prefix="registration_speed_cache_") as cache:
        for name, path in targets.items():
            target = read_obj(path, name=name)
            register(source, target, cache=False)
            cold, cached = [], []
            for _ in range(repeats):
                t, c = time.perf_counter(), time.process_time()
                reg = register(source, target, cache=False)
                cold.append({"wall": time.perf_counter() - t, "cpu": time.process_time() - c})
            register(source, target, cache=cache)
            for _ in range(repeats):
                t, c = time.perf_counter(), time.process_time()
                hit = register(source, target, cache=cache)
                cached.append({"wall": time.perf_counter() - t, "cpu": time.process_time() - c})
            out[name] = {"cold": _stats(cold), "cached": _stats(cached), "hit": bool(hit.cached),
                         "stages": {k: float(v) for k, v in reg.seconds.items()},
                         "p95_share": max(reg.quality["from_target_p95_share"], reg.quality["to_target_p95_share"]),
                         "triangles": int(target.n_triangles)}
    return out


def imported_package_root():
    """The folder holding the ``garment_transfer`` this process imported (the checkout or a baseline's)."""
    import garment_transfer

    return Path(garment_transfer.__file__).resolve().parents[1]


def _command_env(root, cache):
    env = dict(os.environ, GARMENT_TRANSFER_CACHE=cache or "off", OPENBLAS_NUM_THREADS=os.environ.get(
        "OPENBLAS_NUM_THREADS", "1"))
    env["PYTHONPATH"] = os.pathsep.join([str(root), env.get("PYTHONPATH", "")])
    return env


def check_command_package(root):
    """Raise unless ``python -m garment_transfer`` run as ``run_command`` runs it imports the package in
    ``root`` (``-m`` puts the working folder first on the path: it must be the package's)."""
    proc = subprocess.run([sys.executable, "-c", "import garment_transfer; print(garment_transfer.__file__)"],
                          capture_output=True, text=True, env=_command_env(root, None), cwd=root, check=True)
    used = Path(proc.stdout.strip()).resolve()
    if Path(root).resolve() not in used.parents:
        raise RuntimeError(f"the command would import {used}, not the package in {root}")


def run_command(args, root, cache):
    """``python -m garment_transfer transfer ARGS --json`` in a fresh process on the package in ``root``:
    wall and CPU seconds of the child, and its JSON."""
    env = _command_env(root, cache)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "garment_transfer", "transfer", *args, "--json"],
                          capture_output=True, text=True, env=env, cwd=root)
    wall = time.perf_counter() - t
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        raise RuntimeError(f"transfer {' '.join(args)} failed:\n{proc.stderr[-3000:]}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {"wall": wall, "cpu": cpu, "json": json.loads(proc.stdout)}


def command_cases(targets):
    """(name, source body, target body, garment) of the timed commands."""
    mh, demo = makehuman_folder(), DEMO_DATA
    suit = (str(mh / "bodies" / f"{MAKEHUMAN_SOURCE}.obj"), str(mh / "garments" / SUIT / f"{MAKEHUMAN_SOURCE}.obj"))
    cases = [("suit", "same mesh", suit[0], str(mh / "bodies" / "female_pear.obj"), suit[1])]
    cases += [("suit", name, suit[0], path, suit[1]) for name, path in targets.items()]
    if demo is not None and "family_50k" in targets:
        # The mannequin heavy re-meshed: for the dress's own source (the mannequin banana) another mesh of
        # its family.
        dress = (str(demo / "bodies" / "banana.obj"), str(demo / "garments" / DRESS / "banana.obj"))
        cases += [("dress", "same mesh", dress[0], str(demo / "bodies" / "heavy.obj"), dress[1]),
                  ("dress", "family_50k", dress[0], targets["family_50k"], dress[1])]
    return cases


def measure_commands(targets, repeats, root, crossing):
    """Each command case, registered cold and cached where the target is another mesh."""
    check_command_package(root)
    out = []
    for garment, target_name, source, target, cloth in command_cases(targets):
        with tempfile.TemporaryDirectory(prefix="registration_speed_cmd_") as tmp:
            args = ["--source-body", source, "--target-body", target, "--garment", cloth,
                    "--out", str(Path(tmp) / "out.obj")] + ([] if crossing else ["--no-crossing-pass"])
            cache = str(Path(tmp) / "cache")
            variants = {"cold": None}
            if target_name != "same mesh":
                run_command(args, root, cache)
                variants["cached"] = cache
            for variant, folder in variants.items():
                runs = [run_command(args, root, folder) for _ in range(repeats)]
                best = min(runs, key=lambda r: r["wall"])
                seconds = best["json"]["seconds"]
                out.append({"garment": garment, "target": target_name, "variant": variant, "crossing": crossing,
                            "wall": best["wall"], "cpu": best["cpu"], "runs": [r["wall"] for r in runs],
                            "registered": best["json"]["registered"],
                            "register": float(seconds.get("register", 0.0)),
                            "core": float(seconds["total"]) - float(seconds.get("register", 0.0)),
                            "load": float(seconds.get("load", 0.0))})
    return out


def worker(args):
    targets = json.loads(args.worker[1])
    if args.worker[0] == "register":
        return measure_register(targets, args.repeats)
    return measure_commands(targets, args.repeats, imported_package_root(), args.worker[0] == "commands-crossing")


def run_worker(what, targets, repeats, package_root=None):
    """This module as a worker in a fresh process, on this checkout or a baseline package."""
    env = dict(os.environ, OPENBLAS_NUM_THREADS=os.environ.get("OPENBLAS_NUM_THREADS", "1"))
    env["PYTHONPATH"] = os.pathsep.join(([str(package_root)] if package_root else []) + [str(ROOT),
                                                                                       env.get("PYTHONPATH", "")])
    proc = subprocess.run([sys.executable, "-m", "lab.registration_speed", "--repeats", str(repeats),
                           "--worker", what, json.dumps(targets)], capture_output=True, text=True, env=env,
                          cwd=package_root or ROOT)
    if proc.returncode != 0:
        raise RuntimeError(f"worker {what} failed:\n{proc.stderr[-3000:]}")
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    used = Path(out["package"]).resolve()
    if package_root and Path(package_root).resolve() not in used.parents:
        raise RuntimeError(f"the baseline worker imported {used}, not the package in {package_root}")
    return out["result"]


def measure(targets, repeats, package_root=None, crossing=True):
    """Every figure for one package."""
    out = {"register": run_worker("register", targets, repeats, package_root),
           "commands": run_worker("commands", targets, repeats, package_root)}
    if crossing:
        out["commands"] += run_worker("commands-crossing", targets, repeats, package_root)
    return out


def _ratio(a, b):
    return f"{a / b:5.2f}" if a and b else f"{'-':>5}"


def report(ours, base):
    lines = [f"registration of {MAKEHUMAN_SOURCE} (13,380 vertices): seconds, best (median) of the repeats; "
             "x: ours / baseline",
             f"{'target':>11} {'triangles':>9} | {'cold':>13} {'cpu':>5} {'base':>13} {'cpu':>5} {'x':>5} "
             f"{'x cpu':>5} | {'cached':>15} {'base':>15} | ours: stages"]
    for name, r in ours["register"].items():
        b = base["register"].get(name) if base else None
        cell = lambda s: f"{s['best']:5.2f} ({s['median']:5.2f})"  # noqa: E731
        fine = lambda s: f"{s['best']:6.3f} ({s['median']:6.3f})"  # noqa: E731
        stages = " ".join(f"{k} {v:.2f}" for k, v in r["stages"].items())
        lines.append(f"{name:>11} {r['triangles']:>9} | {cell(r['cold'])} {r['cold']['cpu']:5.2f} "
                     + (f"{cell(b['cold'])} {b['cold']['cpu']:5.2f} " if b else f"{'-':>13} {'-':>5} ")
                     + f"{_ratio(r['cold']['best'], b and b['cold']['best'])} "
                     f"{_ratio(r['cold']['cpu'], b and b['cold']['cpu'])} | {fine(r['cached'])} "
                     f"{fine(b['cached']) if b else '-':>15} | {stages}")
    lines += ["", "the transfer command (a fresh process; best of the repeats): wall s (CPU s), of which the "
              "registration and the core transfer (the command's own JSON, wall); /same: wall over the same-mesh "
              "command of that garment and pass; x: ours / baseline, wall and CPU",
              f"{'garment':>7} {'target':>10} {'pass':>5} {'fit':>6} | {'ours':>13} {'register':>8} {'core':>6} "
              f"{'/same':>5} | {'baseline':>13} {'register':>8} {'/same':>5} | {'x':>5} {'x cpu':>5}"]
    same = {}
    for rows, key in ((ours["commands"], "ours"), ((base or {}).get("commands", []), "base")):
        for r in rows:
            if r["target"] == "same mesh":
                same[(key, r["garment"], r["crossing"])] = r["wall"]
    base_rows = {(r["garment"], r["target"], r["variant"], r["crossing"]): r for r in (base or {}).get("commands", [])}
    for r in ours["commands"]:
        k = (r["garment"], r["target"], r["variant"], r["crossing"])
        b = base_rows.get(k)
        s_ours = same.get(("ours", r["garment"], r["crossing"]))
        s_base = same.get(("base", r["garment"], r["crossing"]))
        passed = "on" if r["crossing"] else "off"
        lines.append(f"{r['garment']:>7} {r['target']:>10} {passed:>5} {r['variant']:>6} | "
                     f"{r['wall']:6.2f} ({r['cpu']:4.2f}) {r['register']:8.2f} {r['core']:6.2f} "
                     f"{_ratio(r['wall'], s_ours)} | "
                     + (f"{b['wall']:6.2f} ({b['cpu']:4.2f}) {b['register']:8.2f} {_ratio(b['wall'], s_base)} | "
                        f"{_ratio(r['wall'], b['wall'])} {_ratio(r['cpu'], b['cpu'])}" if b else "-"))
    return lines


def main(argv=None):
    ap = argparse.ArgumentParser(prog="python -m lab.registration_speed", description=__doc__.split("\n\n")[0])
    ap.add_argument("--baseline", metavar="REV", help="also measure the package at this git commit (9fb52f1 or later)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--targets", nargs="+", choices=sorted(REMESHED), default=list(REMESHED))
    ap.add_argument("--no-crossing-pass", action="store_true", help="time the commands without the crossing pass only")
    ap.add_argument("--json", type=Path, help="write all figures to this file")
    ap.add_argument("--worker", nargs=2, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.worker is not None:
        result = worker(args)
        import garment_transfer

        print(json.dumps({"package": garment_transfer.__file__, "result": result}))
        return 0
    if makehuman_folder() is None:
        raise SystemExit("the MakeHuman fixtures are needed (../shared/data/makehuman or $GARMENT_TRANSFER_MAKEHUMAN)")
    load0 = os.getloadavg()
    with tempfile.TemporaryDirectory(prefix="registration_speed_") as tmp:
        targets = write_targets(tmp, args.targets)
        ours = measure(targets, args.repeats, crossing=not args.no_crossing_pass)
        base = None
        if args.baseline:
            with tempfile.TemporaryDirectory(prefix="registration_speed_baseline_") as btmp:
                base = measure(targets, args.repeats, package_at(args.baseline, btmp),
                               crossing=not args.no_crossing_pass)
    load1 = os.getloadavg()
    machine = machine_description()
    print(f"machine: {machine['cpu']}, {machine['cores']} cores; load average {load0[0]:.1f} before, "
          f"{load1[0]:.1f} after; baseline {args.baseline or '-'}")
    print("\n".join(report(ours, base)))
    if args.json:
        data = {"machine": machine, "load": [load0, load1], "baseline_rev": args.baseline, "ours": ours,
                "baseline": base}
        args.json.write_text(json.dumps(data, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
