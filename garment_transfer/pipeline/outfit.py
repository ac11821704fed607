"""Outfits of several layers: garments worn one over another, transferred together.

Layers are given from the body out. Garments draped one by one on the source body usually pass
through each other (each was simulated alone), so the outfit is first made wearable on the source:
each layer is pushed out of the body and the layers under it with its own offset (``push_out``:
an order-keeping warp of the space near what is under it, then the exact crossing pass), and the
cloth is not allowed to cross itself more than it did before. Then every layer, as given, is
transferred on its own (the method does not change), and the same separation runs on the target,
from the body out: each layer treats the body and the transferred layers under it as one obstacle.
The layers separated on the source are not what is transferred: the push-out squeezes a fold
between what is under it and its own other sheet, and the transfer's deformation then pushes
such folds through each other (measured on the demo outfits: the shift dress, separated on the
source and transferred to pear, crosses itself at 17 pairs, as given at 3; transferred as given
and separated there, at 3).

Two checks stop an outfit that cannot be worn, naming the garments, before anything is returned:

- an impossible order: most of a layer's vertices near a lower layer are inside it on the source
  (a dress given under a top it covers);
- inseparable layers: crossings between two layers (or a layer and the body) that the separation
  cannot remove.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial import cKDTree

from ..errors import Cancelled, MeshError
from ..geometry import clearance, penetration
from ..geometry.embedding import body_scale
from ..geometry.intersections import crossings, self_intersections
from ..geometry.obstacle import Obstacle, edge_length
from ..geometry.readings import Readings, as_readings, merge_readings, readings_of
from ..fitting.registration import Registration
from ..geometry.mesh import Mesh, edge_lengths_mean, joined_pieces
from ..geometry.proximity import TriangleSurface, as_same_mesh, one_mesh
from .any_body import registration_for, transfer_to_any_body
from .transfer import OFFSET_SHARE

#: A layer is in an impossible order when more than this share of its vertices near a lower layer
#: (within ``ORDER_BAND`` of its mean edge length) are inside that layer on the source.
ORDER_INSIDE_SHARE = 0.5
ORDER_BAND = 3.0

#: The ways a layer is moved out of what is under it, tried in this order until one leaves no
#: crossing, no more self-intersections than the layer had and no pair closer than the crossing
#: pass's clearance (``push_out``). A warp (``warp_out``) is (clearance it asks for, in offsets;
#: depth of the band the push fades over and radius over which a deep vertex lifts the cloth
#: around it, both as shares of the body's scale, ``embedding.body_scale``; radius None: the whole
#: layer); None is the vertex push-out (``penetration.fix_penetration``). The first warp asks for
#: half an offset more than the crossing pass keeps, so that the under layer's own folds, which
#: stand between the warped vertices, seldom poke through. Measured on the outer layers of the
#: demo outfits on banana, pear and heavy (each way followed by the crossing pass): every way ends
#: with no crossing and no self-intersection added; the first warp's MDC is within 10% of the
#: lowest and below the push-out's in all 6, but it leaves a pair too close in 2 of 6, the
#: push-out in none.
WARPS = ((1.5, 0.044, 0.055), None, (1.0, 0.022, 0.055), (2.0, 0.044, 0.055), (1.0, 0.022, None))
#: Above this many vertices to lift, one per cell stands for the others in ``warp_out``.
WARP_SEEDS = 4096


log = logging.getLogger(__name__)


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
        Each layer on the source body after separation (the outfit made wearable there; each
        layer is transferred as given).
    seconds : dict
        ``separate_source``, ``transfer``, ``separate_target``, ``check``, ``total``.
    info : list of dict
        Per layer: its transfer's info, with ``source`` and ``target_separation``: what its
        push-out did on either body (``push_out``'s info, and ``self_intersections_added``).
    rest_pose : dict or None
        A target in another rest pose (``rest_pose.outfit_across_rest_poses``): how far, and whether the source and
        the layers were posed into it first.
    registration : Registration or None
        A target of another mesh: the source fitted onto it (each layer transferred through it); None for the
        source's own mesh.
    """

    V: list
    source_V: list
    seconds: dict
    info: list
    rest_pose: dict | None = None
    registration: Registration | None = None


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
    R = F if isinstance(F, Readings) else None
    F = R.split if R is not None else np.asarray(F, dtype=np.int64)
    c = V[F].mean(axis=1)
    n = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    _, closest, normal, _ = body.signed_distance(c)
    # Most triangles face the way the skin under them faces; a garment made inside out is flipped.
    if np.sum(np.einsum("ij,ij->i", n, normal) < 0) > 0.5 * F.shape[0]:
        return F[:, [0, 2, 1]] if R is None else replace(R, F=R.F[:, [0, 2, 1]], split=R.split[:, [0, 2, 1]])
    return F if R is None else R


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


def rim_triangles(F):
    """(m,) bool: triangles with a corner on an open rim (an edge of only one triangle).

    Parameters
    ----------
    F : (m,3) int
    """
    F = np.asarray(F, dtype=np.int64)
    e = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    key, count = np.unique(e[:, 0] * (int(F.max()) + 1) + e[:, 1], return_counts=True)
    rim_vertex = np.zeros(int(F.max()) + 1, bool)
    single = key[count == 1]
    rim_vertex[single // (int(F.max()) + 1)] = True
    rim_vertex[single % (int(F.max()) + 1)] = True
    return rim_vertex[F].any(axis=1)


def obstacle_distance(surface: TriangleSurface, V, rim=None):
    """Signed distance of a layer's vertices to what is under it (the body and the lower layers).

    The side comes from the pseudonormal at the closest point, which is wrong beyond the rim of an
    open lower layer (past a T-shirt's hem the closest point is on the hem, and the cloth there is
    not under it): where the closest triangle touches a rim, a vertex counted inside is asked
    again by the winding number, and made outside, pushed away from the rim, when that says so.

    Parameters
    ----------
    surface : TriangleSurface
        The obstacle, its lower layers' triangles facing away from the body.
    V : (n,3) float
    rim : (q,) bool, optional
        ``rim_triangles(surface.F)``, if known.

    Returns
    -------
    sd : (n,) float64
    normal : (n,3) float64
        The direction out of the obstacle at each vertex.
    """
    sd, closest, normal, tri = surface.signed_distance(V)
    rim = rim_triangles(surface.F) if rim is None else rim
    ask = np.flatnonzero((sd < 0) & rim[tri])
    if ask.size:
        out = ask[~surface.inside(V[ask])]
        sd[out] = -sd[out]
        d = V[out] - closest[out]
        normal[out] = d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-300)
    return sd, normal


def warp_out(V, sd, normal, clear, band, radius=None):
    """Lift a layer off what is under it, keeping the order of its sheets along the normal.

    A vertex at signed distance ``s`` below ``clear + band`` goes to ``clear + (s - s_lo) * band /
    (clear + band - s_lo)`` along the obstacle's normal: the band ``[s_lo, clear + band]`` is
    squeezed into ``[clear, clear + band]``, so the deepest vertex reaches ``clear`` and two sheets
    of a fold, one over the other, stay in that order instead of landing on one surface (what
    projecting every vertex to the offset surface does, and what makes the cloth cross itself).
    ``s_lo`` is the depth of the deepest vertex around: each vertex closer than ``clear`` lowers
    it within ``radius``, by less the farther away (continuous, so the warp stays one-to-one
    where the normals are smooth); ``radius`` None takes the deepest of the whole layer.

    Parameters
    ----------
    V : (n,3) float
    sd : (n,) float
        Signed distances to the obstacle (``obstacle_distance``).
    normal : (n,3) float
    clear, band : float
    radius : float, optional

    Returns
    -------
    V : (n,3) float64
        A new array.
    """
    V = np.asarray(V, dtype=np.float64)
    low = np.flatnonzero(sd < clear)
    if low.size == 0:
        return V.copy()
    if radius is None:
        s_lo = np.full(V.shape[0], sd[low].min())
    else:
        s_lo = np.full(V.shape[0], float(clear))
        s_lo[low] = sd[low]
        deep = low
        if deep.size > WARP_SEEDS:
            # On a fine mesh, the deepest vertex of every cell an eighth of the radius wide: the
            # pairs within the radius stay as many as on a coarse one.
            cell = np.floor(V[deep] / (radius / 8.0)).astype(np.int64)
            order = np.lexsort((sd[deep], *cell.T))
            key = cell[order]
            first = np.ones(order.size, bool)
            first[1:] = np.any(key[1:] != key[:-1], axis=1)
            deep = deep[order[first]]
        near = cKDTree(V).sparse_distance_matrix(cKDTree(V[deep]), radius, output_type="ndarray")
        j = deep[near["j"]]
        np.minimum.at(s_lo, near["i"], sd[j] + (clear - sd[j]) * near["v"] / radius)
    lift = sd < clear + band
    f = sd.copy()
    f[lift] = clear + (sd[lift] - s_lo[lift]) * band / (clear + band - s_lo[lift])
    push = np.maximum(f - sd, 0.0)
    return V + push[:, None] * normal


def push_out(V, F, obstacle_V, obstacle_F, offset, scale, surface=None):
    """A layer moved out of what is under it: no crossing, and no more self-intersections than it had.

    Each way of ``WARPS`` (a warp, ``warp_out``, or the vertex push-out), then the exact crossing
    pass (``clearance.separate`` with V as the source shape: around a self-intersection the push
    made, the cloth gets back its shape from before the push), is tried until one leaves no
    crossing, no more self-intersections than ``V`` has and no pair closer than the crossing pass's
    clearance.
    When none does, the one with the fewest crossings, then the fewest self-intersections added,
    then the fewest pairs too close, is kept.

    Parameters
    ----------
    V : (n,3) float
    F : (m,3) int or Readings
    obstacle_V : (p,3) float
    obstacle_F : (q,3) int or Readings
        The body, or the body and the layers under this one (their triangles facing away from it); with
        ``Readings``, no crossing is left under any triangulation of either.
    offset : float
        The layer's clearance.
    scale : float
        The body's scale (``embedding.body_scale``).
    surface : TriangleSurface, optional
        Of the obstacle, when already built.

    Returns
    -------
    V : (n,3) float64
    info : dict
        ``warp`` (the index in ``WARPS`` used), ``tried``,
        ``pushed_vertices``, ``crossings_before``, ``crossings_after``, ``self_intersections_before``,
        ``self_intersections_after``.
    """
    V = np.asarray(V, dtype=np.float64)
    G, under = as_readings(F), as_readings(obstacle_F)
    surface = TriangleSurface(obstacle_V, under.split) if surface is None else surface
    obstacle = Obstacle(obstacle_V, under, surface, edge_length(V, G))
    sd, normal = obstacle_distance(surface, V)
    before = self_intersections(V, G)[0]
    info = {"pushed_vertices": int((sd < offset).sum()), "self_intersections_before": before}
    best, tried = None, 0
    for k, warp in enumerate(WARPS):
        tried += 1
        if warp is None:
            W = penetration.fix_penetration(V, G.split, surface, offset)[0]
        else:
            times, band, radius = warp
            W = warp_out(V, sd, normal, times * offset, band * scale,
                         None if radius is None else radius * scale)
        # With the layer as it came as the source shape, the crossing pass also gives the cloth
        # around any self-intersection the push made its shape from before the push.
        W, sep = clearance.separate(W, G, obstacle.V, obstacle, offset, source_V=V)
        after = sep["self_intersections_after"]
        key = (sep["crossings_after"], max(after - before, 0), sep["near_after"], after)
        if best is None or key < best[0]:
            best = (key, k, W, sep)
        if key[:3] == (0, 0, 0):
            break
    (left, _, _, after), k, W, sep = best
    c = crossings(V, G, obstacle.V, under)
    info.update(warp=k, tried=tried, crossings_before=c["a_edge_pairs"] + c["b_edge_pairs"],
                crossings_after=left, self_intersections_after=after, separation=sep)
    if after > before:
        log.info("a layer crosses itself at %d edge-triangle pairs after its push-out (%d before)", after, before)
    return W, info


def separate_layers(body_V, body_F, garments, Vs, offsets):
    """Each layer pushed out of the body and of the layers under it, from the body out.

    Parameters
    ----------
    body_V : (p,3) float
    body_F : (q,3) int or Readings
        The body (every reading of its polygons: nothing crosses under any triangulation).
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
    B = as_readings(body_F)
    body = TriangleSurface(body_V, B.split)
    scale = body_scale(body_V)
    out, info = [], []
    under = [(np.asarray(body_V, dtype=np.float64), B)]
    for k, (garment, V) in enumerate(zip(garments, Vs)):
        obstacle_V = np.concatenate([u[0] for u in under])
        obstacle_F = merge_readings([(u[0].shape[0], u[1]) for u in under])
        surface = TriangleSurface(obstacle_V, obstacle_F.split) if k else body
        G = readings_of(garment)
        joined = joined_pieces(garment)
        if joined is None:
            V, push = push_out(V, G, obstacle_V, obstacle_F, offsets[k], scale, surface=surface)
        else:
            # Pieces not joined at their seams (transferred as the joined garment): pushed out as it, seams closed.
            mesh, first, place = joined
            V, push = push_out(np.asarray(V, dtype=np.float64)[first], readings_of(mesh), obstacle_V, obstacle_F,
                               offsets[k], scale, surface=surface)
            V = V[place]
        out.append(V)
        info.append(dict(push, self_intersections_added=push["self_intersections_after"]
                         - push["self_intersections_before"]))
        under.append((V, oriented_outward(V, G, body)))
    return out, info


def outfit_crossings(body_V, body_F, garments, Vs):
    """Crossings of every layer with the body (``body_F``: triangles or Readings) and with every other layer,
    under every reading of the layers' polygons.

    Returns
    -------
    list of (str, str, int)
        (name, name, edge-triangle pairs both ways) for every pair that crosses.
    """
    bad = []
    G = [readings_of(g) for g in garments]
    for k, (g, V) in enumerate(zip(garments, Vs)):
        c = crossings(V, G[k], body_V, body_F)
        if c["a_edge_pairs"] + c["b_edge_pairs"]:
            bad.append((g.name, "the body", c["a_edge_pairs"] + c["b_edge_pairs"]))
        for i in range(k):
            c = crossings(V, G[k], Vs[i], G[i])
            if c["a_edge_pairs"] + c["b_edge_pairs"]:
                bad.append((g.name, garments[i].name, c["a_edge_pairs"] + c["b_edge_pairs"]))
    return bad


def _raise_inseparable(bad, where):
    worst = ", ".join(f"{a} and {b} ({n} crossing edge-triangle pairs)" for a, b, n in bad)
    raise OutfitError(bad[0][0], f"cannot be separated {where}: {worst}")


def transfer_outfit(source_body: Mesh, target_body: Mesh, garments, *, offsets=None, progress=None,
                    registration: Registration | None = None, cache=True, limits=None,
                    **transfer_options) -> OutfitResult:
    """Transfer several garments worn one over another, from the body out.

    Parameters
    ----------
    source_body, target_body : Mesh
        The target may be another mesh than the source's: the source is then registered onto it once
        (``registration.register``) and every layer transferred through that fit (``any_body.transfer_to_any_body``:
        solved on the fitted body, then cleared of the target itself); the layers are separated on the target the
        user gave.
    garments : sequence of Mesh
        The layers on the source body, innermost first.
    offsets : float or sequence of (float or None), optional
        Each layer's clearance from the body and the layers under it, in the target's units, as ``transfer``'s
        offset; None: the transfer's default share of the source body's scale (for every layer, or for that
        layer). The same on source and target; onto a target of another mesh, each on the other body by the
        registration's scale (its units and size).
    progress : callable, optional
        ``progress(fraction, stage)``; returning True cancels.
    registration : Registration, optional
        A registration of these two bodies made earlier (a target of another mesh).
    cache, limits
        For the registration of a target of another mesh (``registration.register``).
    **transfer_options
        Passed to ``any_body.transfer_to_any_body`` for every layer (method, model, target, ...; a
        ``target_cage`` of the source's mesh: no registration, and the layers separated on the target).

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
    # A target of the source's mesh written with the other winding is that mesh.
    target_body = as_same_mesh(source_body, target_body) or target_body
    names = [g.name for g in garments]
    if len(set(names)) != len(names):
        raise OutfitError(names[0], "the layers must be different garments (a name is repeated)")
    each = [offsets] * len(garments) if offsets is None or np.isscalar(offsets) else list(offsets)
    if len(each) != len(garments):
        raise ValueError(f"offsets: {len(each)} given for {len(garments)} layers")
    seconds = {}
    t0 = time.perf_counter()
    # A target of another mesh: the source fitted onto it once, for every layer, over the first 10% of the outfit's
    # progress (``registration_for`` gives it 60%).
    step = None if progress is None else (lambda f, *stage: progress(f / 6.0, *stage))
    cage = transfer_options.get("target_cage")
    registration = None if cage is not None and one_mesh(source_body, cage) else registration_for(
        source_body, target_body, registration, cache=cache, limits=limits, progress=step)
    scale = 1.0
    if registration is not None:
        scale = registration.alignment.scale
        seconds["register"] = float(registration.seconds.get("total", 0.0)) if not registration.cached else 0.0
    # An offset given is the target's (as one garment's), the default the source's share; each on the other body
    # by the registration's scale (its units and size).
    default = OFFSET_SHARE * body_scale(source_body.V)
    offsets = [default if o is None else float(o) * scale for o in each]
    target_offsets = [default / scale if o is None else float(o) for o in each]
    source_surface = TriangleSurface(source_body.V, source_body.F)
    check_order(garments, [g.V for g in garments], source_surface)
    t = time.perf_counter()
    source_readings = readings_of(source_body)
    src_Vs, src_info = separate_layers(source_body.V, source_readings, garments, [g.V for g in garments], offsets)
    bad = outfit_crossings(source_body.V, source_readings, garments, src_Vs)
    if bad:
        _raise_inseparable(bad, f"on the source body {source_body.name}")
    seconds["separate_source"] = time.perf_counter() - t
    t = time.perf_counter()
    results = []
    for k, g in enumerate(garments):
        if progress is not None and progress(0.1 + 0.6 * k / len(garments), f"transfer {g.name}"):
            raise Cancelled(f"transfer of the outfit cancelled at {g.name}")
        results.append(transfer_to_any_body(source_body, target_body, g, registration=registration,
                                            offset=target_offsets[k], **transfer_options)[0])
    seconds["transfer"] = time.perf_counter() - t
    t = time.perf_counter()
    target_readings = readings_of(target_body)
    tgt_Vs, tgt_info = separate_layers(target_body.V, target_readings, garments, [r.V for r in results],
                                       target_offsets)
    seconds["separate_target"] = time.perf_counter() - t
    t = time.perf_counter()
    bad = outfit_crossings(target_body.V, target_readings, garments, tgt_Vs)
    seconds["check"] = time.perf_counter() - t
    if bad:
        _raise_inseparable(bad, f"on the target body {target_body.name}")
    seconds["total"] = time.perf_counter() - t0
    info = [dict(r.info, source=s, target_separation=ti) for r, s, ti in zip(results, src_info, tgt_info)]
    return OutfitResult(tgt_Vs, src_Vs, seconds, info, registration=registration)
