"""A body's animation as a point cache, against the same poses as OBJ files: the whole ``shapes`` command each way.

A MakeHuman suit clean at rest on its study body (``lab.motion``'s), that body posed in the shared poses
(``lab.motion.pose_set``) and written two ways into a temporary folder: one PC2 point cache of every pose
(``--target-cache``, the fits into ``--cache``) and one OBJ file a pose (``--poses --target-body ...``, the fits into
OBJ files and a PC2 cache). Each command runs ``--repeats`` times in a fresh process, alternating; printed: the
whole command's seconds, the fits' seconds a pose, the ratio of the cache's command to the OBJ files', each pose's
crossings away from the body's contact and at it and its vertices inside as each command counted them on what it
wrote, and how far apart the two ways' fits are (the cache's 32-bit coordinates against the OBJ files' decimals).

    python -m lab.pose_cache_speed [--garment female_casualsuit01] [--repeats 2]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import garment_transfer as gt
from .motion import POSES, pose_set, rest_garments, rig_of
from .paths import makehuman_folder

ROOT = Path(__file__).resolve().parents[1]


def run(args, say=print):
    root = makehuman_folder()
    skeleton = gt.read_skeleton(root / "rig" / "skeleton.json")
    weights = gt.read_weights(root / "rig" / "weights.json", 13380)
    body_name, garment = rest_garments(root, [args.garment], say)[args.garment]
    body = gt.read_obj(root / "bodies" / f"{body_name}.obj")
    rig = rig_of(root, body_name, skeleton, weights)
    rotations = pose_set(root, skeleton, list(POSES), kept_back=False)
    posed = [rig.pose(body.V, rig.transforms(rotations[p])) for p in POSES]
    with tempfile.TemporaryDirectory() as folder:
        d = Path(folder)
        gt.write_obj(d / "rest.obj", body)
        gt.write_obj(d / "garment.obj", garment)
        gt.write_pc2(d / "body.pc2", np.stack(posed), start_frame=1.0)
        objs = []
        for pose, V in zip(POSES, posed):
            gt.write_obj(d / f"{pose}.obj", body, V)
            objs += ["--target-body", d / f"{pose}.obj"]
        ways = {"cache": ["--target-cache", d / "body.pc2", "--cache", d / "from_cache.pc2"],
                "OBJ files": ["--poses", *objs, "--cache", d / "from_objs.pc2"]}
        seconds, rows = {w: [] for w in ways}, {}
        for k in range(args.repeats):
            for way, extra in ways.items():
                t = time.perf_counter()
                p = subprocess.run([sys.executable, "-m", "garment_transfer", "shapes", "--source-body", d / "rest.obj",
                                    "--garment", d / "garment.obj", *extra, "--out", d / f"out_{way[:5]}_{k}",
                                    "--json"], cwd=ROOT, capture_output=True, text=True)
                whole = time.perf_counter() - t
                if p.returncode:
                    raise SystemExit(p.stderr)
                data = json.loads(p.stdout)
                seconds[way].append((whole, data["seconds"]["poses"] / len(POSES)))
                rows[way] = [(r["crossings_outside_contact"], r["crossings_at_contact"], r["penetrating_vertices"])
                             for r in data["shapes"]]
        a, b = gt.read_pc2(d / "from_cache.pc2")[0], gt.read_pc2(d / "from_objs.pc2")[0]
    apart = np.linalg.norm(a.astype(np.float64) - b, axis=2)
    say(f"{args.garment} ({garment.n_vertices} vertices) on {body_name}, {len(POSES)} poses; "
        f"{args.repeats} runs of each command, alternating")
    for way in ways:
        whole = [s[0] for s in seconds[way]]
        each = [s[1] for s in seconds[way]]
        say(f"{way:>10}: whole command {min(whole):.1f}-{max(whole):.1f} s, {min(each):.2f}-{max(each):.2f} s a pose; "
            "per pose (crossings away from contact, at it, vertices inside): "
            + ", ".join(f"{p} {r}" for p, r in zip(POSES, rows[way])))
    ratio = np.mean([s[0] for s in seconds["cache"]]) / np.mean([s[0] for s in seconds["OBJ files"]])
    say(f"the cache's command / the OBJ files' command: {ratio:.2f}x; the two ways' fits {apart.mean() * 100:.3f} mm "
        f"apart on average, {apart.max() * 100:.1f} mm at most (decimetres: the MakeHuman files)")


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--garment", default="female_casualsuit01")
    p.add_argument("--repeats", type=int, default=2)
    run(p.parse_args(argv))


if __name__ == "__main__":
    main()
