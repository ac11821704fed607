"""What the crossing pass costs, beside the rest of the transfer, on every MakeHuman pair; and the whole command.

1. **Pairs**: every MakeHuman garment from female_average to every other body (and, with ``--heavy``, to the
   heavy bodies of ``lab.unseen_bodies``), transferred as a single command does (cold: the garment prepared for
   the one target). Per pair: the seconds of the crossing pass, of the rest of the transfer, their ratio, and the
   CPU seconds of both; the best of ``--repeats``.
2. **Whole command** (``--commands``): ``python -m garment_transfer transfer --json`` in a fresh process, a
   MakeHuman suit onto the heavy body, with and without ``--no-crossing-pass``: wall seconds from start to exit
   (imports, reading, transfer, writing, the check of the file written).

``--baseline REV`` measures the same with the package as it was at a commit (``git archive``, in a subprocess,
as ``lab.speed`` does), side by side: its pass checks one triangulation (the shorter diagonal of each quad),
the current one every triangulation of the garment's and the body's quads. Revisions before the core's move into
subpackages (9fb52f1) do not import under this layout.

    python -m lab.crossing_speed [--repeats 2] [--baseline e3e1af8] [--heavy] [--commands] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from .paths import MAKEHUMAN_SOURCE, MAKEHUMAN_TARGETS, ROOT, SHARED_MAKEHUMAN, makehuman_folder
from .speed import machine_description, package_at

MAKEHUMAN = makehuman_folder() or SHARED_MAKEHUMAN
COMMAND_GARMENTS = ("female_casualsuit01", "male_casualsuit04", "male_casualsuit01")


def measure(targets, repeats):
    """Per pair: the best of ``repeats`` transfers with the pass, its stages, and the CPU seconds."""
    from garment_transfer.geometry.obj import read_obj
    from garment_transfer.pipeline.transfer import transfer_garment

    source = read_obj(MAKEHUMAN / "bodies" / f"{MAKEHUMAN_SOURCE}.obj")
    garments = json.loads((MAKEHUMAN / "manifest.json").read_text())["garments"]
    rows = []
    for target_path in targets:
        target = read_obj(target_path)
        for g in garments:
            garment = read_obj(MAKEHUMAN / "garments" / g / f"{MAKEHUMAN_SOURCE}.obj")
            best = None
            for _ in range(repeats):
                c, t = time.process_time(), time.perf_counter()
                r = transfer_garment(source, target, garment)
                wall, cpu = time.perf_counter() - t, time.process_time() - c
                if best is None or wall < best["wall"]:
                    best = {"wall": wall, "cpu": cpu, "seconds": r.seconds,
                            "crossings_after": r.info.get("crossings_after")}
            s = best["seconds"]
            rows.append({"garment": g, "target": Path(target_path).stem, "vertices": garment.n_vertices,
                         "pass": s.get("crossings", 0.0), "rest": s["total"] - s.get("crossings", 0.0),
                         "wall": best["wall"], "cpu": best["cpu"], "crossings_after": best["crossings_after"]})
            print(json.dumps({"progress": rows[-1]}), file=sys.stderr, flush=True)
    return rows


def commands(target, package_root=None, repeats=2):
    """Whole-command wall seconds, a fresh process each, with and without the pass: the best of ``repeats``."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(([str(package_root)] if package_root else []) + [env.get("PYTHONPATH", "")])
    out = []
    with tempfile.TemporaryDirectory(prefix="crossing_speed_") as tmp:
        for g in COMMAND_GARMENTS:
            row = {"garment": g, "target": Path(target).stem}
            for label, extra in (("with", []), ("without", ["--no-crossing-pass"])):
                best = None
                for _ in range(repeats):
                    t = time.perf_counter()
                    proc = subprocess.run([sys.executable, "-m", "garment_transfer", "transfer", "--source-body",
                                           str(MAKEHUMAN / "bodies" / f"{MAKEHUMAN_SOURCE}.obj"), "--target-body",
                                           str(target), "--garment",
                                           str(MAKEHUMAN / "garments" / g / f"{MAKEHUMAN_SOURCE}.obj"),
                                           "--out", str(Path(tmp) / "out.obj"), "--json", *extra],
                                          capture_output=True, text=True, env=env, cwd=package_root or ROOT)
                    wall = time.perf_counter() - t
                    if proc.returncode != 0:
                        raise RuntimeError(f"{g}: {proc.stderr[-2000:]}")
                    best = wall if best is None else min(best, wall)
                row[label] = best
            out.append(row)
    return out


def run_worker(args, package_root=None):
    """This module's measurement in a fresh process (optionally on another copy of the package)."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(([str(package_root)] if package_root else [])
                                        + [str(ROOT), env.get("PYTHONPATH", "")])
    proc = subprocess.run([sys.executable, "-m", "lab.crossing_speed", "--worker", *args], capture_output=True,
                          text=True, env=env, cwd=package_root or ROOT)
    if proc.returncode != 0:
        raise RuntimeError(f"worker failed:\n{proc.stderr[-3000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def heavy_targets(folder):
    """The heavy and past-the-pear bodies of ``lab.unseen_bodies``, written into ``folder``."""
    from garment_transfer import write_obj

    from .unseen_bodies import unseen_bodies

    out = []
    for name, mesh in unseen_bodies().items():
        if name in ("female_heavy", "male_heavy", "female_beyond_pear"):
            path = Path(folder) / f"{name}.obj"
            write_obj(path, mesh)
            out.append(path)
    return out


def report(ours, base):
    print(f"{'garment':20s} {'target':20s} {'verts':>6s} | {'pass':>6s} {'rest':>6s} {'ratio':>6s} {'cpu':>6s} |"
          f" {'base pass':>9s} {'base rest':>9s} {'ratio':>6s} | {'pass/base':>9s}")
    base_by = {(r["garment"], r["target"]): r for r in base or []}
    worst = 0.0
    for r in ours:
        b = base_by.get((r["garment"], r["target"]))
        ratio = r["pass"] / r["rest"]
        worst = max(worst, ratio)
        line = (f"{r['garment']:20s} {r['target']:20s} {r['vertices']:6d} | {r['pass']:6.2f} {r['rest']:6.2f} "
                f"{ratio:6.2f} {r['cpu']:6.2f} |")
        if b:
            line += f" {b['pass']:9.2f} {b['rest']:9.2f} {b['pass'] / b['rest']:6.2f} | {r['pass'] / b['pass']:9.2f}"
        print(line)
    print(f"worst pass / rest of the transfer: {worst:.2f} (ours)"
          + (f", {max(b['pass'] / b['rest'] for b in base):.2f} (baseline)" if base else ""))


def main(argv=None):
    p = argparse.ArgumentParser(prog="python -m lab.crossing_speed", description=__doc__.splitlines()[0])
    p.add_argument("--repeats", type=int, default=2)
    p.add_argument("--baseline", metavar="REV")
    p.add_argument("--heavy", action="store_true", help="also the heavy and past-the-pear bodies")
    p.add_argument("--commands", action="store_true", help="also whole commands onto the heavy body")
    p.add_argument("--json", type=Path)
    p.add_argument("--worker", nargs="*", help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.worker is not None:
        kind, rest = args.worker[0], args.worker[1:]
        if kind == "pairs":
            result = measure(rest[1:], int(rest[0]))
        else:
            result = commands(rest[0], None, int(rest[1]))
        import garment_transfer

        print(json.dumps({"package": garment_transfer.__file__, "result": result}))
        return 0
    load0 = os.getloadavg()
    with tempfile.TemporaryDirectory(prefix="crossing_speed_bodies_") as bodies:
        targets = [str(MAKEHUMAN / "bodies" / f"{t}.obj") for t in MAKEHUMAN_TARGETS]
        heavy = [str(p) for p in heavy_targets(bodies)] if args.heavy or args.commands else []
        targets += heavy if args.heavy else []
        ours = run_worker(["pairs", str(args.repeats), *targets])["result"]
        base = base_commands = our_commands = None
        with tempfile.TemporaryDirectory(prefix="crossing_speed_baseline_") as tmp:
            pkg = package_at(args.baseline, tmp) if args.baseline else None
            if pkg:
                base = run_worker(["pairs", str(args.repeats), *targets], pkg)["result"]
            if args.commands:
                our_commands = commands(heavy[0], None, args.repeats)
                base_commands = commands(heavy[0], pkg, args.repeats) if pkg else None
    load1 = os.getloadavg()
    m = machine_description()
    print(f"machine: {m['cpu']}, {m['cores']} cores; load average {load0[0]:.1f} before, {load1[0]:.1f} after; "
          f"baseline {args.baseline or '-'}")
    report(ours, base)
    if our_commands:
        print("\nwhole command (fresh process), best of the repeats, wall seconds:")
        base_by = {r["garment"]: r for r in base_commands or []}
        for r in our_commands:
            b = base_by.get(r["garment"])
            print(f"{r['garment']:20s} -> {r['target']}: with the pass {r['with']:.2f} s, without {r['without']:.2f} s"
                  + (f"; baseline {b['with']:.2f} s and {b['without']:.2f} s" if b else ""))
    if args.json:
        args.json.write_text(json.dumps({"machine": m, "load": [load0, load1], "baseline_rev": args.baseline,
                                         "ours": ours, "baseline": base, "commands": our_commands,
                                         "baseline_commands": base_commands}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
