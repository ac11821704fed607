"""Outfits of several layers: garments worn one over another, transferred together.

Layers are given from the body out. Garments draped one by one on the source body usually pass
through each other (each was simulated alone), so the outfit is first made wearable on the source:
each layer is pushed out of the body and the layers under it (vertex push-out, then the exact
crossing pass) with its own offset. Then every layer is transferred on its own (the method does
not change), and the same separation runs again on the target, from the body out: each layer
treats the body and the transferred layers under it as one obstacle.

Two checks stop an outfit that cannot be worn, naming the garments, before anything is returned:

- an impossible order: most of a layer's vertices near a lower layer are inside it on the source
  (a dress given under a top it covers);
- inseparable layers: crossings between two layers (or a layer and the body) that the separation
  cannot remove.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from . import clearance, penetration
from .embedding import body_scale
from .errors import MeshError
from .intersections import crossings
from .mesh import Mesh, edge_lengths_mean
from .proximity import TriangleSurface
from .transfer import OFFSET_SHARE, transfer_garment

#: A layer is in an impossible order when more than this share of its vertices near a lower layer
#: (within ``ORDER_BAND`` of its mean edge length) are inside that layer on the source.
ORDER_INSIDE_SHARE = 0.5
ORDER_BAND = 3.0


class OutfitError(MeshError):
    """Layers that cannot be worn in the order given."""


@dataclass
class OutfitResult:
    """A transferred outfit.

    Attributes
    ----------
    V : list of (n_k,3) float64
        Each layer's vertices on the target body, in the order given.
    source_V : list of (n_k,3) float64
        Each layer on the source body after separation (what was transferred).
    seconds : dict
        ``separate_source``, ``transfer``, ``separate_target``, ``check``, ``total``.
    info : list of dict
        Per layer: its transfer's info, and ``source_moved`` / ``target_crossings`` figures.
    """

    V: list
    source_V: list
    seconds: dict
    info: list


def oriented_outward(V, F, body: TriangleSurface):
    """F with its triangles turned so that their normals point away from the body.

    Parameters
    ----------
    V : (n,3) float
    F : (m,3) int
    body : TriangleSurface

    Returns
    -------
    F : (m,3) int64
    """
    F = np.asarray(F, dtype=np.int64)
    c = V[F].mean(axis=1)
    n = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    _, closest, normal, _ = body.signed_distance(c)
    # Most triangles face the way the skin under them faces; a garment made inside out is flipped.
    if np.sum(np.einsum("ij,ij->i", n, normal) < 0) > 0.5 * F.shape[0]:
        return F[:, [0, 2, 1]]
    return F


def merge_meshes(parts):
    """One mesh from several: list of (V (n_k,3), F (m_k,3)) -> (V (sum n,3), F (sum m,3))."""
    Vs, Fs, base = [], [], 0
    for V, F in parts:
        Vs.append(np.asarray(V, dtype=np.float64))
        Fs.append(np.asarray(F, dtype=np.int64) + base)
        base += Vs[-1].shape[0]
    return np.concatenate(Vs), np.concatenate(Fs)


def check_order(garments, Vs, body: TriangleSurface):
    """Raise OutfitError when a layer lies mostly inside a layer given under it.

    Parameters
    ----------
    garments : list of Mesh
    Vs : list of (n_k,3) float
        The layers' vertices (on the source body).
    body : TriangleSurface
    """
    for k in range(1, len(garments)):
        for i in range(k):
            lower = TriangleSurface(Vs[i], oriented_outward(Vs[i], garments[i].F, body))
            band = ORDER_BAND * edge_lengths_mean(Vs[i], garments[i].F)
            sd = lower.signed_distance(Vs[k])[0]
            near = np.abs(sd) < band
            if near.sum() >= 10 and np.mean(sd[near] < 0) > ORDER_INSIDE_SHARE:
                raise OutfitError(
                    garments[k].name,
                    f"is given over {garments[i].name} but {np.mean(sd[near] < 0):.0%} of its vertices "
                    f"near {garments[i].name} are under it: give the layers from the body out "
                    f"({garments[k].name} before {garments[i].name}?)")


def separate_layers(body_V, body_F, garments, Vs, offsets):
    """Each layer pushed out of the body and of the layers under it, from the body out.

    Parameters
    ----------
    body_V : (p,3) float
    body_F : (q,3) int
    garments : list of Mesh
    Vs : list of (n_k,3) float
        The layers' vertices.
    offsets : list of float
        Each layer's clearance from what is under it.

    Returns
    -------
    Vs : list of (n_k,3) float64
        New arrays.
    info : list of dict
    """
    body = TriangleSurface(body_V, body_F)
    out, info = [], []
    under = [(np.asarray(body_V, dtype=np.float64), np.asarray(body_F, dtype=np.int64))]
    for k, (garment, V) in enumerate(zip(garments, Vs)):
        obstacle_V, obstacle_F = merge_meshes(under)
        surface = TriangleSurface(obstacle_V, obstacle_F) if k else body
        V, fix = penetration.fix_penetration(V, garment.F, surface, offsets[k])
        V, sep = clearance.separate(V, garment.F, obstacle_V, obstacle_F, offsets[k], surface=surface)
        out.append(V)
        info.append({"pushed_vertices": fix["pushed_vertices"], "crossings_before": sep["crossings_before"],
                     "crossings_after": sep["crossings_after"],
                     "self_intersections_added": sep["self_intersections_added"]})
        under.append((V, oriented_outward(V, garment.F, body)))
    return out, info


def outfit_crossings(body_V, body_F, garments, Vs):
    """Crossings of every layer with the body and with every other layer.

    Returns
    -------
    list of (str, str, int)
        (name, name, edge-triangle pairs both ways) for every pair that crosses.
    """
    bad = []
    for k, (g, V) in enumerate(zip(garments, Vs)):
        c = crossings(V, g.F, body_V, body_F)
        if c["a_edge_pairs"] + c["b_edge_pairs"]:
            bad.append((g.name, "the body", c["a_edge_pairs"] + c["b_edge_pairs"]))
        for i in range(k):
            c = crossings(V, g.F, Vs[i], garments[i].F)
            if c["a_edge_pairs"] + c["b_edge_pairs"]:
                bad.append((g.name, garments[i].name, c["a_edge_pairs"] + c["b_edge_pairs"]))
    return bad


def _raise_inseparable(bad, where):
    worst = ", ".join(f"{a} and {b} ({n} crossing edge-triangle pairs)" for a, b, n in bad)
    raise OutfitError(bad[0][0], f"cannot be separated {where}: {worst}")


def transfer_outfit(source_body: Mesh, target_body: Mesh, garments, *, offsets=None, progress=None,
                    **transfer_options) -> OutfitResult:
    """Transfer several garments worn one over another, from the body out.

    Parameters
    ----------
    source_body, target_body : Mesh
    garments : sequence of Mesh
        The layers on the source body, innermost first.
    offsets : float or sequence of float, optional
        Each layer's clearance from the body and the layers under it (default: the transfer's
        default share of the source body's scale, for every layer; the same on source and target).
    progress : callable, optional
        ``progress(fraction, stage)``; returning True cancels.
    **transfer_options
        Passed to ``transfer.transfer_garment`` for every layer (method, model, target, ...).

    Returns
    -------
    OutfitResult

    Raises
    ------
    OutfitError
        Layers in an impossible order, or layers that cannot be separated (on the source or the
        target); the message names the garments.
    """
    garments = list(garments)
    if not garments:
        raise ValueError("an outfit needs at least one garment")
    names = [g.name for g in garments]
    if len(set(names)) != len(names):
        raise OutfitError(names[0], "the layers must be different garments (a name is repeated)")
    if offsets is None:
        offsets = OFFSET_SHARE * body_scale(source_body.V)
    offsets = [float(offsets)] * len(garments) if np.isscalar(offsets) else [float(o) for o in offsets]
    if len(offsets) != len(garments):
        raise ValueError(f"offsets: {len(offsets)} given for {len(garments)} layers")
    seconds = {}
    t0 = time.perf_counter()
    source_surface = TriangleSurface(source_body.V, source_body.F)
    check_order(garments, [g.V for g in garments], source_surface)
    t = time.perf_counter()
    src_Vs, src_info = separate_layers(source_body.V, source_body.F, garments, [g.V for g in garments],
                                       offsets)
    bad = outfit_crossings(source_body.V, source_body.F, garments, src_Vs)
    if bad:
        _raise_inseparable(bad, f"on the source body {source_body.name}")
    seconds["separate_source"] = time.perf_counter() - t
    t = time.perf_counter()
    results = []
    for k, (g, V) in enumerate(zip(garments, src_Vs)):
        if progress is not None and progress(0.1 + 0.6 * k / len(garments), f"transfer {g.name}"):
            from .errors import Cancelled
            raise Cancelled(f"transfer of the outfit cancelled at {g.name}")
        results.append(transfer_garment(source_body, target_body, g.with_vertices(V), offset=offsets[k],
                                        **transfer_options))
    seconds["transfer"] = time.perf_counter() - t
    t = time.perf_counter()
    tgt_Vs, tgt_info = separate_layers(target_body.V, target_body.F, garments, [r.V for r in results],
                                       offsets)
    seconds["separate_target"] = time.perf_counter() - t
    t = time.perf_counter()
    bad = outfit_crossings(target_body.V, target_body.F, garments, tgt_Vs)
    seconds["check"] = time.perf_counter() - t
    if bad:
        _raise_inseparable(bad, f"on the target body {target_body.name}")
    seconds["total"] = time.perf_counter() - t0
    info = [dict(r.info, source=s, target_separation=ti) for r, s, ti in zip(results, src_info, tgt_info)]
    return OutfitResult(tgt_Vs, src_Vs, seconds, info)
