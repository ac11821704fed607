"""Study: the promise checked on the files a user gets, by another tool, on bodies the project never saw.

Every pair is transferred with the command line as a user runs it (``python -m garment_transfer transfer
--json``, in this process), once with the crossing pass and once without it (``--no-crossing-pass``: the MDC
the pass is held to). The written OBJ file is then checked twice:

- by the command's own JSON (``check``: every triangulation of the written faces and of the body's, the file
  read back, against the body given), and
- independently, in Blender (``lab/blender/triangulated_overlaps.py``): the OBJ files imported by Blender's
  importer, triangulated by Blender in four quad methods each, every pair of triangulations tested with
  Blender's own triangle-triangle overlap test; and the result's own overlaps beside its source garment's.

Sets (``--only``): ``demo`` (the demo's 5 test garments on its 5 targets), ``makehuman`` (the 8 MakeHuman
garments from female_average to the 4 other bodies), ``unseen`` (the same garments on the heavy and past-the-pear
bodies of ``lab.unseen_bodies``), ``remeshed`` (on two of them re-meshed, registered), ``family`` (MakeHuman
garments on two demo mannequins, another family in metres and Z up, registered). ``--poses``: the source with
both arms turned down by 10 to 30 degrees, same mesh and re-meshed: refused or not, the angle measured, and MDC
with and without the pass.

    python -m lab.file_check --out DIR [--only demo,makehuman] [--garments a,b]
    python -m lab.file_check --poses --out DIR
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import subprocess
import sys
import time
from pathlib import Path

from garment_transfer import read_obj, write_obj
from garment_transfer.cli import main as cli
from garment_transfer.pipeline.metrics import mdc

from .paths import DEMO_DATA, MAKEHUMAN_SOURCE, MAKEHUMAN_TARGETS, ROOT, SHARED_MAKEHUMAN, makehuman_folder
from .unseen_bodies import arms_down, body, remeshed, unseen_bodies

MAKEHUMAN = makehuman_folder() or SHARED_MAKEHUMAN
SETS = ("demo", "makehuman", "unseen", "remeshed", "family")
FAMILY_BODIES = ("heavy", "pear")
FAMILY_GARMENTS = ("female_casualsuit01", "female_sportsuit01", "male_casualsuit02", "male_casualsuit04")


def makehuman_garments():
    return json.loads((MAKEHUMAN / "manifest.json").read_text())["garments"]


def pairs(sets, folder, garments=None):
    """(set, garment name, source body path, garment path, target name, target path) of every pair."""
    out = []
    mh = [g for g in makehuman_garments() if garments is None or g in garments]
    src = MAKEHUMAN / "bodies" / f"{MAKEHUMAN_SOURCE}.obj"
    if "demo" in sets:
        man = json.loads((DEMO_DATA / "manifest.json").read_text())
        for g in man["test_garments"]:
            for t in man["targets"]:
                out.append(("demo", g, DEMO_DATA / "bodies" / f"{man['source']}.obj",
                            DEMO_DATA / "garments" / g / f"{man['source']}.obj", t, DEMO_DATA / "bodies" / f"{t}.obj"))
    if "makehuman" in sets:
        out += [("makehuman", g, src, MAKEHUMAN / "garments" / g / f"{MAKEHUMAN_SOURCE}.obj", t,
                 MAKEHUMAN / "bodies" / f"{t}.obj") for t in MAKEHUMAN_TARGETS for g in mh]
    made = {}
    if {"unseen", "remeshed"} & set(sets):
        for name, mesh in unseen_bodies().items():
            if "arms_down" not in name:
                made[name] = folder / "bodies" / f"{name}.obj"
                made[name].parent.mkdir(parents=True, exist_ok=True)
                write_obj(made[name], mesh, header=f"lab.unseen_bodies: {name}")
    if "unseen" in sets:
        out += [("unseen", g, src, MAKEHUMAN / "garments" / g / f"{MAKEHUMAN_SOURCE}.obj", t, made[t])
                for t in ("female_heavy", "male_heavy", "female_beyond_pear") for g in mh]
    if "remeshed" in sets:
        pear50 = folder / "bodies" / "female_pear_remeshed_50000.obj"
        write_obj(pear50, remeshed(body("female_pear"), 50000), header="lab.file_check: female_pear re-meshed")
        out += [("remeshed", g, src, MAKEHUMAN / "garments" / g / f"{MAKEHUMAN_SOURCE}.obj", t.stem, t)
                for t in (made["female_heavy_remeshed"], pear50) for g in mh]
    if "family" in sets:
        out += [("family", g, src, MAKEHUMAN / "garments" / g / f"{MAKEHUMAN_SOURCE}.obj", f"mannequin_{t}",
                 DEMO_DATA / "bodies" / f"{t}.obj") for t in FAMILY_BODIES for g in FAMILY_GARMENTS
                if garments is None or g in garments]
    return out


def run_cli(argv):
    """The command line in this process: (exit code, parsed JSON or None, stderr text)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = cli(argv)
    try:
        return code, json.loads(out.getvalue()), err.getvalue()
    except json.JSONDecodeError:
        return code, None, err.getvalue()


def transfer_pair(pair, folder):
    """Both transfers of a pair and what the command said of each."""
    kind, g, src, garment, t, target = pair
    out = folder / "results" / kind / f"{g}__{t}.obj"
    plain = folder / "results" / kind / f"{g}__{t}__no_pass.obj"
    out.parent.mkdir(parents=True, exist_ok=True)
    base = ["transfer", "--source-body", str(src), "--target-body", str(target), "--garment", str(garment), "--json"]
    wall = time.perf_counter()
    code, report, err = run_cli(base + ["--out", str(out)])
    wall = time.perf_counter() - wall
    row = {"set": kind, "garment": g, "target": t, "out": str(out), "source": str(garment), "body": str(target),
           "code": code, "wall": wall}
    if code != 0 or report is None:
        row["error"] = err.strip().splitlines()[-1] if err.strip() else f"exit {code}"
        return row
    code2, report2, _ = run_cli(base + ["--out", str(plain), "--no-crossing-pass"])
    source = read_obj(garment)
    V, V0 = read_obj(out).V, read_obj(plain).V
    row.update(check=report["check"], warnings=report["warnings"], seconds=report["seconds"],
               registered=report["registered"], pose=report["info"].get("limb_angles"),
               mdc=mdc(source.V, V, source.F), mdc_no_pass=mdc(source.V, V0, source.F),
               seconds_no_pass=report2["seconds"] if code2 == 0 else None)
    return row


def blender_check(rows, folder):
    """The independent check of every written result (a Blender subprocess): {name: record}."""
    todo = [{"name": f"{r['set']}:{r['garment']}:{r['target']}", "result": r["out"], "body": r["body"],
             "source": r["source"]} for r in rows if "error" not in r]
    spec, out = folder / "blender_pairs.json", folder / "blender_check.json"
    spec.write_text(json.dumps(todo))
    proc = subprocess.run([sys.executable, "-m", "lab.blender.triangulated_overlaps", "--pairs", str(spec),
                           "--out", str(out)], cwd=ROOT, capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"the Blender check failed:\n{proc.stderr[-3000:]}")
    return {r["name"]: r for r in json.loads(out.read_text())}


def summary(rows, blender):
    """Print one line per pair and the totals."""
    print(f"{'set':10s} {'garment':20s} {'target':26s} {'json g/b':>9s} {'blender':>7s} {'self':>9s} "
          f"{'min mm':>7s} {'MDC off':>8s} {'ratio':>6s} {'pass s':>7s} {'rest s':>7s} {'whole s':>7s}")
    totals = {}
    for r in rows:
        if "error" in r:
            print(f"{r['set']:10s} {r['garment']:20s} {r['target']:26s} refused: {r['error']}")
            continue
        c, b = r["check"], blender.get(f"{r['set']}:{r['garment']}:{r['target']}", {})
        s = r["seconds"]
        rest = s["total"] - s.get("crossings", 0.0) - s.get("register", 0.0)
        ratio = r["mdc"] / r["mdc_no_pass"] if r["mdc_no_pass"] > 0 else 1.0
        mm = 1000.0 if r["set"] in ("demo",) or r["target"].startswith("mannequin") else 100.0
        print(f"{r['set']:10s} {r['garment']:20s} {r['target']:26s} "
              f"{c['garment_edges_through_body']:>4d}/{c['body_edges_through_garment']:<4d} "
              f"{b.get('body_overlaps', -1):>7d} {c['self_intersections']:>4d}/{c['self_intersections_source']:<4d} "
              f"{c['min_body_distance'] * mm:7.2f} {r['mdc_no_pass']:8.4f} {ratio:6.3f} "
              f"{s.get('crossings', 0.0):7.2f} {rest:7.2f} {r['wall']:7.2f}")
        t = totals.setdefault(r["set"], {"pairs": 0, "json_clean": 0, "blender_clean": 0, "agree": 0,
                                         "self_beyond": 0, "mdc_over_10": 0, "pass_over_rest": 0})
        t["pairs"] += 1
        clean = c["garment_edges_through_body"] + c["body_edges_through_garment"] == 0
        t["json_clean"] += clean
        t["blender_clean"] += b.get("body_overlaps", 1) == 0
        t["agree"] += clean == (b.get("body_overlaps", 1) == 0)
        t["self_beyond"] += c["self_intersections_new"] > 0
        t["mdc_over_10"] += ratio > 1.1
        t["pass_over_rest"] += s.get("crossings", 0.0) > rest
    print()
    for k, t in totals.items():
        print(f"{k}: {t['pairs']} pairs; clean by the JSON {t['json_clean']}, by Blender's triangulations and overlap "
              f"test {t['blender_clean']}, the two agree on {t['agree']}; self-intersections beyond the source in "
              f"{t['self_beyond']}; MDC more than 10% above without the pass in {t['mdc_over_10']}; the pass dearer "
              f"than the rest of the transfer in {t['pass_over_rest']}")


def poses(folder):
    """Arms turned down by 10 to 30 degrees, same mesh and re-meshed: refusal, angle, MDC with/without the pass."""
    avg = body(MAKEHUMAN_SOURCE)
    src = MAKEHUMAN / "bodies" / f"{MAKEHUMAN_SOURCE}.obj"
    (folder / "bodies").mkdir(parents=True, exist_ok=True)
    rows = []
    for degrees in (10, 15, 20, 25, 30):
        posed = arms_down(avg, MAKEHUMAN_SOURCE, degrees)
        same = folder / "bodies" / f"arms_down_{degrees}.obj"
        write_obj(same, posed, header=f"lab.file_check: arms {degrees} degrees down")
        targets = [("same mesh", same)]
        if degrees in (20, 30):
            other = folder / "bodies" / f"arms_down_{degrees}_remeshed.obj"
            write_obj(other, remeshed(posed, 47500), header=f"lab.file_check: arms {degrees} down, re-meshed")
            targets.append(("re-meshed", other))
        for mesh_kind, target in targets:
            for g in ("female_casualsuit01", "male_casualsuit04", "female_sportsuit01", "male_casualsuit02"):
                row = transfer_pair(("poses", g, src, MAKEHUMAN / "garments" / g / f"{MAKEHUMAN_SOURCE}.obj",
                                     f"{degrees}_{mesh_kind.replace(' ', '_')}", target), folder)
                row.update(degrees=degrees, mesh=mesh_kind)
                rows.append(row)
                if "error" in row:
                    row["unchecked"] = unchecked(src, MAKEHUMAN / "garments" / g / f"{MAKEHUMAN_SOURCE}.obj", target)
                    u = row["unchecked"]
                    print(f"arms {degrees} down, {mesh_kind}, {g}: refused: {row['error']}; transferred all the "
                          f"same: crossings left {u['crossings']}, MDC {u['mdc']:.4f}, "
                          f"{u['mdc'] / u['mdc_no_pass']:.3f}x without the pass", flush=True)
                else:
                    ratio = row["mdc"] / row["mdc_no_pass"] if row["mdc_no_pass"] > 0 else 1.0
                    c = row["check"]
                    print(f"arms {degrees} down, {mesh_kind}, {g}: measured {row['pose']['degrees']:.1f} degrees "
                          f"({row['pose']['band']}); crossings {c['garment_edges_through_body']}/"
                          f"{c['body_edges_through_garment']}; MDC {row['mdc']:.4f}, {ratio:.3f}x without the "
                          "pass", flush=True)
    return rows


def unchecked(source_path, garment_path, target_path):
    """A refused pair transferred all the same (the pose check off): what the pose check spared the user."""
    from garment_transfer import crossings, readings_of, transfer_to_any_body

    source, garment, target = read_obj(source_path), read_obj(garment_path), read_obj(target_path)
    r, _ = transfer_to_any_body(source, target, garment, check_pose=False)
    r0, _ = transfer_to_any_body(source, target, garment, check_pose=False, resolve_crossings=False)
    c = crossings(r.V, readings_of(garment), target.V, readings_of(target))
    return {"crossings": c["a_edge_pairs"] + c["b_edge_pairs"], "mdc": mdc(garment.V, r.V, garment.F),
            "mdc_no_pass": mdc(garment.V, r0.V, garment.F)}


def main(argv=None):
    p = argparse.ArgumentParser(prog="python -m lab.file_check", description=__doc__.splitlines()[0])
    p.add_argument("--out", required=True, help="folder for the bodies made, the results and the records")
    p.add_argument("--only", default=",".join(SETS), help=f"comma-separated sets of {', '.join(SETS)}")
    p.add_argument("--garments", default=None, help="MakeHuman garments (default: all)")
    p.add_argument("--poses", action="store_true", help="the pose study instead of the sets")
    p.add_argument("--no-blender", action="store_true", help="leave out the independent check in Blender")
    args = p.parse_args(argv)
    folder = Path(args.out)
    folder.mkdir(parents=True, exist_ok=True)
    if args.poses:
        rows = poses(folder)
        (folder / "poses.json").write_text(json.dumps(rows, indent=1, default=str))
        return 0
    garments = args.garments.split(",") if args.garments else None
    rows = []
    for pair in pairs(args.only.split(","), folder, garments):
        rows.append(transfer_pair(pair, folder))
        r = rows[-1]
        print(f"{r['set']} {r['garment']} -> {r['target']}: "
              + (r["error"] if "error" in r else f"{r['check']} {r['wall']:.2f} s"), flush=True)
    blender = {} if args.no_blender else blender_check(rows, folder)
    (folder / "rows.json").write_text(json.dumps({"rows": rows, "blender": blender}, indent=1, default=str))
    summary(rows, blender)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
