"""Target bodies the project never saw, made from the MakeHuman fixtures: heavier, posed, re-meshed.

The tests and the other studies use the fixture bodies as they are; the bodies made here are for checking
the transfer's promises on shapes it was never tuned on (``lab.file_check``), and are never used by a test.

- ``heavy``: the torso and limbs pushed out along the body's normals (the hands, feet and head kept), by
  ``HEAVY_PUSH`` of the height, faded over the wrists, ankles and neck;
- ``beyond``: a blend of two fixture bodies past the second (``average + k (pear - average)``, k > 1);
- ``arms_down``: both arms turned down about the shoulder joints by an angle, with MakeHuman's own
  skeleton and weights (linear blend skinning, ``../shared/data/makehuman/rig``): a target in another pose;
- ``remeshed``: another mesh of the same surface (``lab.registration.remesh``), vertices shuffled.

    python -m lab.unseen_bodies --out DIR        # writes every body as OBJ (decimetres, Y up)
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from garment_transfer import read_obj, write_obj
from garment_transfer.geometry import mesh_from_triangles, vertex_normals

from .paths import MAKEHUMAN_SOURCE, SHARED_MAKEHUMAN, makehuman_folder

MAKEHUMAN = makehuman_folder() or SHARED_MAKEHUMAN
#: How far the heavy bodies' torso and limbs are pushed out, as shares of the height (1.7 m: 2 and 3.4 cm).
HEAVY_PUSH = (0.012, 0.02)
#: Where the body faces itself along its normal, each side grows by at most this share of the gap.
GAP_SHARE = 0.4
#: Rounds in which the push is halved where the heavy body still grows into itself.
HEAVY_ROUNDS = 8
#: The arm bones turned by ``arms_down`` (with everything below them).
ARM_ROOTS = ("upperarm01.L", "upperarm01.R")
LEG_ROOTS = ("upperleg01.L", "upperleg01.R")


def body(name):
    """A fixture body as a Mesh."""
    return read_obj(MAKEHUMAN / "bodies" / f"{name}.obj")


def _rig():
    """MakeHuman's bones, and their skinning weights as {bone: (vertices (k,) int, weights (k,) float)}, normalised
    per vertex (they sum to 0.95-1.06 in the file)."""
    rig = MAKEHUMAN / "rig"
    bones = json.loads((rig / "skeleton.json").read_text())["bones"]
    raw = json.loads((rig / "weights.json").read_text())["weights"]
    pairs = {b: np.asarray(p, dtype=np.float64).reshape(-1, 2) for b, p in raw.items()}
    total = np.zeros(1 + max(int(p[:, 0].max()) for p in pairs.values() if p.size))
    for p in pairs.values():
        np.add.at(total, p[:, 0].astype(np.int64), p[:, 1])
    return bones, {b: (p[:, 0].astype(np.int64), p[:, 1] / total[p[:, 0].astype(np.int64)]) for b, p in pairs.items()}


def _ends_weight(n):
    """(n,) 1 on the torso and limbs, 0 on the hands, feet and head (MakeHuman's weights of the bones from the
    wrists, ankles and neck down their chains), blended by the weights."""
    bones, weights = _rig()
    ends = np.zeros(n)
    # In the bones' order by name: a set's order follows Python's string hashing, which changes from run to run,
    # and so would the sums' last bits.
    for name in sorted(_descendants(bones, ["wrist.L", "wrist.R", "foot.L", "foot.R", "neck01"])):
        if name in weights:
            v, w = weights[name]
            np.add.at(ends, v, w)
    return 1.0 - np.clip(ends, 0.0, 1.0)


def heavy(base, push):
    """``base`` (a Mesh) with its torso and limbs pushed out by ``push`` of its height, less where another part
    of the body is near along the normal (between the thighs, under the arms): there each side takes at most
    ``GAP_SHARE`` of the gap, so the body does not grow into itself."""
    import igl

    from garment_transfer.geometry import vertex_adjacency
    from garment_transfer.geometry.readings import readings_of
    from garment_transfer.geometry.self_check import SelfCheck

    N = vertex_normals(base.V, base.F)
    tree = igl.AABB()
    tree.init(base.V, base.F)
    face, t, _ = tree.intersect_ray_first(base.V, base.F, base.V + 1e-4 * N, N)
    gap = np.where(face >= 0, t, np.inf)
    amount = np.minimum(push * np.ptp(base.V[:, 1]), GAP_SHARE * gap) * _ends_weight(base.n_vertices)
    A = vertex_adjacency(base.n_vertices, base.F)
    degree = np.asarray(A.sum(axis=1)).ravel()
    R = readings_of(base)
    own = len(SelfCheck(base.V, R).all(base.V))
    limit = amount.copy()
    for _ in range(HEAVY_ROUNDS):
        # Neighbour averages, never above the limit: no dents or bumps.
        for _ in range(10):
            amount = np.minimum((amount + A @ amount) / (1.0 + degree), limit)
        V = base.V + amount[:, None] * N
        pairs = SelfCheck(V, R).all(V)
        if len(pairs) <= own:
            break
        # Where the body grew into itself (the crotch, the armpits), it grows half as much.
        near = np.zeros(base.n_vertices, bool)
        near[R.E[pairs[:, 0]]] = True
        near[R.F[pairs[:, 1]]] = True
        for _ in range(3):
            near |= (A @ near.astype(float)) > 0
        limit[near] *= 0.5
    return base.with_vertices(V, name=f"{base.name}_heavy")


def beyond(base, other, k):
    """``base + k (other - base)``: a body past ``other`` (k > 1)."""
    return base.with_vertices(base.V + k * (other.V - base.V))


def _descendants(bones, roots):
    out = set(roots)
    changed = True
    while changed:
        changed = False
        for name, bone in bones.items():
            if bone.get("parent") in out and name not in out:
                out.add(name)
                changed = True
    return out


def legs_apart(base, body_name, degrees):
    """Both legs of ``base`` turned outward by ``degrees`` about the hip joints, in the front plane (skinned as
    ``arms_down``)."""
    return _turned(base, body_name, degrees, LEG_ROOTS, f"{body_name}_legs_apart_{degrees:g}")


def arms_down(base, body_name, degrees):
    """Both arms of ``base`` (a fixture body named ``body_name``) turned down by ``degrees`` about the
    shoulder joints, in the front plane, by linear blend skinning with MakeHuman's weights."""
    return _turned(base, body_name, degrees, ARM_ROOTS, f"{body_name}_arms_down_{degrees:g}")


def _turned(base, body_name, degrees, roots, name):
    """``base`` with the bones ``roots`` (one per side) and everything below them turned by ``degrees`` in the
    front plane about their head joints: down for an arm, outward for a leg (the same turn: away from the
    body's middle at the top, towards it below)."""
    bones, weights = _rig()
    joints = json.loads((MAKEHUMAN / "rig" / "joints" / f"{body_name}.json").read_text())
    V = base.V
    move = np.zeros_like(V)
    theta = np.radians(degrees)
    for root in roots:
        pivot = np.asarray(joints[bones[root]["head"]], dtype=np.float64)
        # In the front plane (Y up, Z forward): about +Z for the left side (x > 0), -Z for the right.
        a = -np.sign(pivot[0]) * theta * (1.0 if root in ARM_ROOTS else -1.0)
        R = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])
        for bone in sorted(_descendants(bones, [root]) & set(weights)):
            v, w = weights[bone]
            np.add.at(move, v, w[:, None] * ((V[v] - pivot) @ R.T + pivot - V[v]))
    return base.with_vertices(V + move, name=name)


def remeshed(base, triangles, seed=0):
    """``base``'s surface as another mesh of about ``triangles`` triangles (vertices shuffled)."""
    from .registration import remesh

    U, G = remesh(base.V, base.F, triangles, seed)
    return mesh_from_triangles(U, G, name=f"{base.name}_remeshed_{triangles}")


def unseen_bodies():
    """{name: Mesh} of every body this study makes."""
    avg, pear, male = body(MAKEHUMAN_SOURCE), body("female_pear"), body("male_average")
    out = {
        "female_heavy": heavy(avg, HEAVY_PUSH[1]),
        "male_heavy": heavy(male, HEAVY_PUSH[0]),
        "female_beyond_pear": beyond(avg, pear, 1.8),
    }
    for d in (10, 20, 30):
        out[f"female_arms_down_{d}"] = arms_down(avg, MAKEHUMAN_SOURCE, d)
    out["female_heavy_remeshed"] = remeshed(out["female_heavy"], 30000)
    return {name: mesh.with_vertices(mesh.V, name=name) for name, mesh in out.items()}


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", required=True, help="folder for the OBJ files")
    args = p.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for name, mesh in unseen_bodies().items():
        write_obj(out / f"{name}.obj", mesh, header=f"lab.unseen_bodies: {name}")
        print(f"wrote {out / f'{name}.obj'}: {mesh.n_vertices} vertices, {mesh.n_faces} faces")


if __name__ == "__main__":
    main()
