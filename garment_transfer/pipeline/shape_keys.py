"""One garment fitted to many shapes of one body: shape keys that follow the body's shape keys.

A body with shape keys is a basis ``B0 (n,3)`` and keys ``B_k (n,3)`` (same vertex order) mixed
linearly by slider values ``w_k``: ``B(w) = B0 + sum_k w_k (B_k - B0)``. The garment gets one key per
body key: ``G_k`` is the garment transferred to ``B_k``, and its basis ``G0`` the garment transferred to
``B0`` (the garment itself, pushed out where it was inside the body). The garment is prepared once
(binding, embedding, Poisson factor; ``transfer.prepare_garment``) and every key reuses it.

Blended the same way, ``G(w) = G0 + sum_k w_k (G_k - G0)`` is exactly the transfer at a single key at
value 1, but only close to the transfer at a mix of keys: where two keys both move the same region
(hips that widen twice) the linear sum can clip. Two remedies are offered and measured
(``lab/shape_keys.py``, ``docs/shape-keys.md``):

- ``margin``: every key is transferred with a larger distance kept from the body;
- corrective keys for pairs of keys: the garment transferred to ``B0 + (B_a - B0) + (B_b - B0)``, stored
  as its difference from the linear blend, and mixed in with weight ``w_a * w_b`` (a driver of the two
  sliders in Blender), so that both keys at 1 are exact too.

And one is on by default, the lift of a mix (``mix_lift``): where the sliders add up to more than 1 the blend
goes beyond every fitted shape (three keys that each round the hips, at once), and a long garment edge over a
curve of the body (the buttocks) that clears it at every key at 1 can be cut through between its vertices. The
garment then moves out along the body's normals by ``mix_excess(w) = max(0, sum_k w_k - 1)`` times ``lift``,
which grows with the square of each vertex's longest edge (the sagitta of that edge over a curve); at the basis,
at every key at 1 and at any mix whose values add up to at most 1 it is 0 (a Blender key driven by the sum of
the sliders less 1, held at 0 by its slider range).
"""

from __future__ import annotations

import itertools
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from ..errors import Cancelled, MeshError, TopologyMismatchError
from ..files import check_outputs, write_json_atomic
from ..geometry.embedding import body_scale
from ..geometry.mesh import Mesh, require_same_topology
from ..geometry.obj import read_obj, write_obj
from ..geometry.proximity import TriangleSurface, common_mesh
from ..geometry.readings import readings_of, split_readings
from ..geometry.self_check import pairs_in_full
from ..geometry.threads import in_threads
from .result_check import check_result, result_warnings
from .transfer import OFFSET_SHARE, PreparedGarment, prepare_garment, transfer_garment


#: One keep-outside distance for every vertex, a share of the transfer's offset (the study's uniform row; the
#: operator uses ``SHAPE_KEY_BANDS``). Measured with ``python -m lab.shape_keys`` (female_casualsuit01, ten keys,
#: 50 mixes, Blender's Shrinkwrap rule): 15 of 50 mixes cross under some triangulation and a key at 1 moves by up to
#: 13 mm (the Shrinkwrap takes some vertices at concave edges for inside); in bands: keys at 1 unmoved.
KEEP_OUTSIDE_SHARE = 0.5
#: Bands of the per-vertex keep-outside distance (``held_bands``), shares of the offset: every vertex is kept at
#: least ``KEEP_OUTSIDE_SHARE`` of the offset outside, and each further band keeps only the vertices that every shape
#: that must not move already holds at least that far. In Blender, one Shrinkwrap per band, each limited to its
#: band's vertex group, in increasing order. Rig to Body's bands (times its Keep Outside share).
KEEP_OUTSIDE_BANDS = (0.5, 0.75, 1.0)
#: Rig to Body's further bands for the cloth that hangs free of the body (``riding_share`` 0: a skirt's hem, the
#: skirt of a dress), shares of the offset (``hanging_bands``): each keeps the hanging vertices that the cloth at rest
#: holds at least that far out, so that a leg swung into a skirt pushes the cloth in front of it instead of passing
#: through it. The cloth on the skin keeps ``KEEP_OUTSIDE_BANDS`` only: kept farther out, a sleeve pressed between the
#: arm and the torso is pushed off one into the other. Measured in lab/notes/motion-study.md ("Hanging cloth kept
#: out").
HANGING_BANDS = (1.5, 2.0, 3.0, 4.0)
#: The bands of size shape keys (``keep_outside_bands``): those of ``KEEP_OUTSIDE_BANDS`` and more above the
#: offset, so that a vertex the basis and every key at 1 hold farther out than the offset is kept that far at a
#: mix too. ``python -m lab.shape_keys`` (50 mixes, seed 0), without the lift of a mix (``mix_lift``): 5 of 50 mixes
#: crossing, 6 with ``KEEP_OUTSIDE_BANDS``; with it 1 (both legs keys: the body crosses itself 23 times as often as
#: the basis; ``lab/shape_keys_mixes.py``, the diagnosis).
SHAPE_KEY_BANDS = (0.5, 0.75, 1.0, 1.1, 1.2, 1.35, 1.5, 2.0)
#: A vertex joins a band only if the basis and every key at 1 hold it at least ``band / KEEP_OUTSIDE_SLACK``
#: away: room for Blender's 32-bit coordinates and its own nearest-point search.
KEEP_OUTSIDE_SLACK = 0.999
#: The lift of a mix (``mix_lift``): per unit of ``mix_excess``, each vertex moves out by the sagitta of its longest
#: edge (sides and diagonals) over a sphere of this radius, a share of the body's scale (``body_scale``; about
#: 0.39 m on a 1.7 m body: 0.5 mm for an edge of 40 mm, 1.9 mm for one of 78 mm). ``python -m lab.shape_keys_mixes
#: --remedies`` (female_casualsuit01, 100 mixes of seeds 0 and 1): every mix whose body does not cross itself where
#: both legs keys meet is clean with it (6 cross without it, 3 of them at half this lift); the same on two more
#: suits.
MIX_LIFT_RADIUS = 0.2
#: A pair of keys is reported (``self_crossing_pairs``) when the body with both at 1 has at least this many
#: crossings of its own (an edge through a triangle of its own triangulation) that neither the basis nor either key
#: at 1 has. The ten keys of ``python -m lab.shape_keys`` (45 pairs): the male and the slim body's legs at once 466
#: (the one pair whose mixes stay crossed with the lift), every other pair at most 14. About 2.5 s for those ten
#: keys on 2 cores (56 checks of the 13,380-vertex body), against 8 s for the keys' transfers.
SELF_CROSSING_PAIRS_FROM = 50


@dataclass
class ShapeKeyFit:
    """A garment fitted to every shape key of a body.

    Attributes
    ----------
    basis : (g,3) float64
        The garment on the basis body.
    keys : dict of str to (g,3) float64
        The garment on each key's body shape (absolute positions, like a Blender shape key).
    correctives : dict of (str, str) to (g,3) float64
        For a pair of keys, what the garment on both keys at 1 adds to the linear blend (a difference,
        mixed in with the product of the two values).
    lift : (g,3) float64 or None
        The lift of a mix per unit of ``mix_excess`` (``mix_lift``), or None (no lift).
    info : dict of str to dict
        Per key (and per corrective ``"a+b"``): ``seconds`` by stage, ``penetrating_vertices``, ``offset``.
    seconds : dict
        ``prepare``, ``keys``, ``correctives``, ``total``.
    prepared : PreparedGarment
        The garment's preparation (its readings and its own self-intersections, for checking the keys).
    """

    basis: np.ndarray
    keys: dict
    correctives: dict = field(default_factory=dict)
    info: dict = field(default_factory=dict)
    seconds: dict = field(default_factory=dict)
    prepared: PreparedGarment | None = field(default=None, repr=False)
    lift: np.ndarray | None = None

    def blend(self, weights, correctives=True, lift=True):
        """The garment at slider values ``weights`` (a dict name -> value; missing keys are 0), with the lift of
        the mix (``lift``) as Blender's keys make it.

        Returns
        -------
        V : (g,3) float64
        """
        V = self.basis.copy()
        for name, w in weights.items():
            if w:
                V += w * (self.keys[name] - self.basis)
        if correctives:
            for (a, b), delta in self.correctives.items():
                w = weights.get(a, 0.0) * weights.get(b, 0.0)
                if w:
                    V += w * delta
        excess = mix_excess(weights)
        if lift and self.lift is not None and excess:
            V += excess * self.lift
        return V


def pair_warnings(fit: ShapeKeyFit, body_name="the body"):
    """The pairs of keys of ``fit.info["self_crossing_pairs"]``, said in words."""
    return [f"{body_name} with {p['keys'][0]} and {p['keys'][1]} both at 1 crosses itself "
            f"({p['new_crossings']} crossings of its own that neither key alone nor the basis has): a mix with both "
            f"near 1 puts body parts inside each other, and the garment there is not kept outside both"
            for p in fit.info.get("self_crossing_pairs", [])]


def mix_excess(weights):
    """How far slider values ``weights`` (dict name -> value) reach beyond the fitted shapes: ``max(0, sum w - 1)``;
    0 at the basis, at each key at 1 and wherever the values add up to at most 1 (in Blender a Sum driver of the
    sliders, less 1, held at 0 by the key's slider range)."""
    return max(0.0, float(sum(float(w) for w in weights.values())) - 1.0)


def mix_lift(source_body: Mesh, garment: Mesh, V, radius=MIX_LIFT_RADIUS):
    """The lift of a mix per unit of ``mix_excess``: each vertex of the garment at V (on ``source_body``) along the
    body's outward normal at its closest point, by ``l**2 / (8 r)``, l its longest edge (the polygons' sides and
    diagonals: every triangulation's) and r ``radius`` times the body's scale.

    Returns
    -------
    lift : (g,3) float64
    """
    V = np.asarray(V, dtype=np.float64)
    E = readings_of(garment).E
    length = np.linalg.norm(V[E[:, 0]] - V[E[:, 1]], axis=1)
    longest = np.zeros(V.shape[0])
    np.maximum.at(longest, E[:, 0], length)
    np.maximum.at(longest, E[:, 1], length)
    normal = TriangleSurface(source_body.V, source_body.F).signed_distance(V)[2]
    return normal * (longest ** 2 / (8.0 * radius * body_scale(source_body.V)))[:, None]


def self_crossing_pairs(source_body: Mesh, shapes, garment_V, offset, least=SELF_CROSSING_PAIRS_FROM):
    """Pairs of keys whose body with both at 1 crosses itself where neither the basis nor either key at 1 does (its
    own triangulation, as the pose fit counts a body's own crossings): a mix with both near 1 is a body with parts
    inside each other, and no garment there can be outside both.

    Only keys that move the body under the garment are paired (by more than ``offset`` somewhere within ten offsets
    of ``garment_V``): a face's or a hand's keys are left out.

    Parameters
    ----------
    source_body : Mesh
    shapes : dict of str to (n,3) float
    garment_V : (g,3) float
        The garment on the basis.
    offset : float
    least : int
        New crossings (edge, triangle) from which a pair is reported.

    Returns
    -------
    list of (str, str, int)
        The pair and its new crossings, in the order of ``all_pairs``.
    """
    R = split_readings(source_body)
    near = np.isfinite(cKDTree(np.asarray(garment_V, dtype=np.float64)).query(
        source_body.V, distance_upper_bound=10.0 * offset)[0])
    moving = [k for k, V in shapes.items()
              if near.any() and np.linalg.norm(V[near] - source_body.V[near], axis=1).max() > offset]
    pairs = all_pairs(moving)
    if not pairs:
        return []

    def own(V):
        found = pairs_in_full(V, R)
        return found[:, 0] * R.n_triangles + found[:, 1]

    bodies = [source_body.V] + [shapes[k] for k in moving] + [body_at(source_body.V, shapes, {a: 1.0, b: 1.0})
                                                             for a, b in pairs]
    found = in_threads(own, bodies)
    basis, single = found[0], dict(zip(moving, found[1:1 + len(moving)]))
    out = []
    for (a, b), both in zip(pairs, found[1 + len(moving):]):
        new = np.setdiff1d(both, np.concatenate([basis, single[a], single[b]])).size
        if new >= least:
            out.append((a, b, int(new)))
    return out


def check_shapes(basis: Mesh, shapes):
    """Check body shapes against the basis body: same vertex count, finite, not empty.

    Parameters
    ----------
    basis : Mesh
    shapes : dict of str to (n,3) float

    Returns
    -------
    dict of str to (n,3) float64
    """
    if not shapes:
        raise MeshError(basis.name, "has no shape keys to fit the garment to")
    checked = {}
    for name, V in shapes.items():
        V = np.asarray(V, dtype=np.float64)
        if V.shape != basis.V.shape:
            raise MeshError(f"{basis.name}: key {name}",
                            f"has {V.shape[0] if V.ndim == 2 else V.size} vertices, the basis "
                            f"{basis.n_vertices}; a shape key must move the basis mesh's own vertices")
        if not np.isfinite(V).all():
            raise MeshError(f"{basis.name}: key {name}", "has NaN or infinite coordinates")
        checked[name] = V
    return checked


def body_at(basis_V, shapes, weights):
    """The body at slider values ``weights``: ``B0 + sum_k w_k (B_k - B0)``.

    Parameters
    ----------
    basis_V : (n,3) float
    shapes : dict of str to (n,3) float
    weights : dict of str to float

    Returns
    -------
    V : (n,3) float64
    """
    V = np.array(basis_V, dtype=np.float64)
    for name, w in weights.items():
        if w:
            V += w * (np.asarray(shapes[name], dtype=np.float64) - basis_V)
    return V


def all_pairs(names):
    """Every unordered pair of key names, in order."""
    return list(itertools.combinations(list(names), 2))


def fit_steps(source_body: Mesh, shapes, garment: Mesh, *, pairs=(), offset=None, margin=0.0,
              fix_penetration=True, resolve_crossings=True, interpolate=True, stiffness=None,
              with_basis=True, prepared: PreparedGarment | None = None, lift=True, check_pairs=True):
    """Fit ``garment`` to every shape, one transfer per step: a generator.

    Yields ``(done, total, name)`` after each transfer (the basis first, then the keys, then the
    corrective pairs); its return value (``StopIteration.value``) is the ShapeKeyFit. Callers that can
    pause between steps (Blender's modal operators) advance it themselves; ``fit_shape_keys`` drains it.

    Parameters
    ----------
    source_body : Mesh
        The body's basis shape, the garment dressed on it.
    shapes : dict of str to (n,3) float
        Each key's body shape (absolute positions, the basis's vertex order).
    garment : Mesh
    pairs : sequence of (str, str)
        Pairs of keys that get a corrective key (``all_pairs(shapes)`` for every pair).
    offset : float, optional
        Distance kept from the body (default: as ``transfer_garment``, 0.25% of each shape's scale,
        about 5 mm on a 1.7 m body).
    margin : float
        Added to ``offset`` for the keys and correctives (not the basis): room for linear blending.
    fix_penetration, resolve_crossings, interpolate, stiffness
        As in ``transfer.transfer_garment`` (the crossing pass may bring single vertices a little closer
        than ``offset`` to remove an edge crossing).
    with_basis : bool
        Transfer the garment to the basis shape too (the basis of the keys); False keeps the garment as
        it is as the basis (when only the keys' shapes are wanted).
    prepared : PreparedGarment, optional
        Made by ``prepare_garment(source_body, garment)``; made here when not given.
    lift : bool
        Lift a mix whose sliders add up to more than 1 (``mix_lift``). Not with corrective ``pairs``: the blend is
        then exact at each pair of keys at 1, which the lift would move.
    check_pairs : bool
        Find the pairs of keys whose body with both at 1 crosses itself (``self_crossing_pairs``), for
        ``info["self_crossing_pairs"]`` and ``pair_warnings``.
    """
    shapes = check_shapes(source_body, shapes)
    pairs = [tuple(p) for p in pairs]
    for a, b in pairs:
        for name in (a, b):
            if name not in shapes:
                raise ValueError(f"corrective pair ({a}, {b}): no shape key {name!r}")
        if a == b:
            raise ValueError(f"corrective pair ({a}, {b}) needs two different keys")
    if margin < 0:
        raise ValueError(f"margin must be >= 0, got {margin}")
    t0 = time.perf_counter()
    seconds = {}
    if prepared is None:
        prepared = prepare_garment(source_body, garment, interpolate=interpolate, stiffness=stiffness)
    elif prepared.garment is not garment or prepared.source_body is not source_body:
        raise ValueError("prepared was made for another garment or source body")
    seconds["prepare"] = time.perf_counter() - t0
    total = 1 + len(shapes) + len(pairs)
    info = {}

    def run(V_body, name, extra):
        # The default offset is the one a single transfer to that shape uses (from its own scale).
        kept = (OFFSET_SHARE * body_scale(V_body) if offset is None else offset) + extra
        result = transfer_garment(source_body, source_body.with_vertices(V_body, name=name), garment,
                                  offset=kept, fix_penetration=fix_penetration,
                                  resolve_crossings=resolve_crossings, interpolate=interpolate,
                                  prepared=prepared)
        info[name] = {"seconds": result.seconds, "penetrating_vertices": result.penetrating_vertices,
                      "offset": kept}
        return result.V

    t = time.perf_counter()
    if with_basis:
        basis = run(source_body.V, "Basis", 0.0)
    else:
        basis = np.array(garment.V, dtype=np.float64)
    yield 1, total, "Basis"
    keys = {}
    for i, (name, V) in enumerate(shapes.items()):
        keys[name] = run(V, name, margin)
        yield 2 + i, total, name
    seconds["keys"] = time.perf_counter() - t
    t = time.perf_counter()
    correctives = {}
    for i, (a, b) in enumerate(pairs):
        both = body_at(source_body.V, shapes, {a: 1.0, b: 1.0})
        exact = run(both, f"{a}+{b}", margin)
        correctives[(a, b)] = exact - (keys[a] + keys[b] - basis)
        yield 2 + len(shapes) + i, total, f"{a}+{b}"
    seconds["correctives"] = time.perf_counter() - t
    if check_pairs:
        t = time.perf_counter()
        info["self_crossing_pairs"] = [
            {"keys": [a, b], "new_crossings": n}
            for a, b, n in self_crossing_pairs(source_body, shapes, basis,
                                               OFFSET_SHARE * body_scale(source_body.V) if offset is None else offset)]
        seconds["pairs"] = time.perf_counter() - t
    seconds["total"] = time.perf_counter() - t0
    return ShapeKeyFit(basis, keys, correctives, info, seconds, prepared,
                       mix_lift(source_body, garment, basis) if lift and not pairs else None)


def drain(steps, progress=None):
    """Run a ``fit_steps`` generator to its end; ``progress(fraction, name)`` returning True cancels.

    Returns
    -------
    ShapeKeyFit
    """
    while True:
        try:
            done, total, name = next(steps)
        except StopIteration as stop:
            return stop.value
        if progress is not None and progress(done / total, name):
            steps.close()
            raise Cancelled(f"fitting to shape keys cancelled after {name}")


def fit_shape_keys(source_body: Mesh, shapes, garment: Mesh, *, progress=None, **options) -> ShapeKeyFit:
    """Fit ``garment`` to every shape key of ``source_body`` with one preparation.

    Parameters
    ----------
    source_body : Mesh
    shapes : dict of str to (n,3) float
    garment : Mesh
    progress : callable, optional
        ``progress(fraction, name)``; returning True cancels (raises Cancelled).
    **options
        See ``fit_steps``.

    Returns
    -------
    ShapeKeyFit
    """
    return drain(fit_steps(source_body, shapes, garment, **options), progress)


def transfer_to_shapes(source_body: Mesh, shapes, garment: Mesh, **options):
    """The garment on each of ``shapes`` (one preparation for all): each shape on its own, not keys to mix (no lift
    of a mix, no check of pairs).

    Returns
    -------
    positions : dict of str to (g,3) float64
    info : dict of str to dict
        Per shape: ``seconds`` by stage, ``penetrating_vertices``, ``offset``; ``"prepare"``: seconds.
    """
    fit = fit_shape_keys(source_body, shapes, garment, **dict(dict(lift=False, check_pairs=False), **options))
    info = {name: fit.info[name] for name in fit.keys}
    info["prepare"] = {"seconds": fit.seconds["prepare"]}
    return fit.keys, info


def inside_share(V, body_V, body_F, depth, surface=None):
    """Share of garment vertices more than ``depth`` inside the body, and the deepest.

    Parameters
    ----------
    V : (g,3) float
    body_V : (n,3) float
    body_F : (m,3) int
    depth : float
        In the body's units (1 mm is 0.001 on a body in metres, 0.01 in decimetres).

    Returns
    -------
    share : float
    deepest : float
        Depth of the deepest vertex (0 when none is inside).
    """
    surface = surface or TriangleSurface(body_V, body_F)
    sd = surface.signed_distance(np.asarray(V, dtype=np.float64))[0]
    return float((sd < -depth).mean()), float(max(0.0, -sd.min()))


def keep_outside(V, surface: TriangleSurface, distance=0.0, only=None):
    """Vertices closer to the body than ``distance`` (or inside it) moved to that distance from their closest
    point, on the outer side; the others unchanged. What Blender's Shrinkwrap modifier does in its Outside mode
    (nearest surface point), which the Blender operator adds after the shape keys to catch what linear blending
    clips: the side is the closest triangle's face normal's, and a vertex moves along the line through it and
    its closest point (along the face normal when it lies on the surface). Given the body's triangles as
    Blender splits them, it equals the modifier to within 32-bit rounding.

    Parameters
    ----------
    V : (g,3) float
    surface : TriangleSurface
        The body in the blended shape.
    distance : float
    only : (g,) bool, optional
        The vertices the rule applies to (a Shrinkwrap limited to a vertex group of weight 1); default all.

    Returns
    -------
    V : (g,3) float64
        A new array.
    """
    V = np.array(V, dtype=np.float64)
    rows = np.arange(len(V)) if only is None else np.flatnonzero(np.asarray(only, dtype=bool))
    sd, closest, away = shrinkwrap_distance(V[rows], surface)
    bad = sd < distance
    V[rows[bad]] = closest[bad] + distance * away[bad]
    return V


def shrinkwrap_distance(P, surface: TriangleSurface):
    """Signed distance as Blender's Shrinkwrap (nearest surface point) judges it: the distance to the closest
    point, negative where the point is behind the closest triangle's face normal.

    Returns
    -------
    sd : (p,) float64
    closest : (p,3) float64
    away : (p,3) float64
        Unit direction from the closest point to where a point kept outside goes: towards the point (away from
        it when behind), the face normal when it lies on the surface.
    """
    P = np.asarray(P, dtype=np.float64)
    closest, _, tri, _ = surface.closest(P)
    T = surface.V[surface.F[tri]]
    normal = np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0])
    normal /= np.maximum(np.linalg.norm(normal, axis=1), 1e-300)[:, None]
    delta = P - closest
    d = np.linalg.norm(delta, axis=1)
    side = np.where(np.einsum("ij,ij->i", delta, normal) < 0, -1.0, 1.0)
    on = d < 1e-12 * (1.0 + np.abs(closest).max(axis=1))
    away = np.where(on[:, None], normal, delta * (side / np.where(on, 1.0, d))[:, None])
    return np.where(on, 0.0, side * d), closest, away


def keep_outside_bands(fit: ShapeKeyFit, source_body: Mesh, shapes, offset=None, bands=SHAPE_KEY_BANDS,
                       slack=KEEP_OUTSIDE_SLACK):
    """The per-vertex keep-outside distance, in bands: for each band (increasing), its distance and the
    vertices it keeps. The first band keeps every vertex; a later band keeps the vertices that the basis and
    every key at 1 hold at least ``band * offset / slack`` from the body in that shape, so that the rule moves
    no key at 1 (nor the basis) while keeping a mix as far out as the keys allow. Where the basis or a key at 1
    holds some vertex nearer than the first band, every vertex is kept at that nearest distance (times
    ``slack``) and the first band, too, keeps only its vertices. A vertex the Shrinkwrap judges inside in the
    basis or a key at 1 (``shrinkwrap_distance`` < 0) is in no band.

    Parameters
    ----------
    fit : ShapeKeyFit
    source_body : Mesh
        The body's basis shape (``fit.basis`` is on it).
    shapes : dict of str to (n,3) float
        Each key's body shape (``fit.keys[name]`` is on it).
    offset : float, optional
        The transfer's offset (default ``fit.info["Basis"]["offset"]``).
    bands : sequence of float
        Shares of ``offset``, increasing.
    slack : float
        At most 1.

    Returns
    -------
    list of (float, (g,) bool)
        The first keeps every vertex unless some vertex is in no band.
    """
    if offset is None:
        offset = fit.info["Basis"]["offset"]
    held = [(TriangleSurface(source_body.V, source_body.F), fit.basis)]
    held += [(TriangleSurface(np.asarray(V_body, dtype=np.float64), source_body.F), fit.keys[name])
             for name, V_body in shapes.items()]
    return held_bands(held, offset, bands, slack)


def _checked_bands(bands, slack, empty=False):
    """``bands`` as floats, refused unless positive and increasing (and not empty, unless ``empty``), with ``slack``
    in (0, 1]."""
    bands = [float(b) for b in bands]
    if (not bands and not empty) or any(b <= 0 for b in bands) or any(b >= c for b, c in zip(bands, bands[1:])):
        raise ValueError(f"bands must be positive and increasing, got {bands}")
    if not 0 < slack <= 1:
        raise ValueError(f"slack must be in (0, 1], got {slack}")
    return bands


def hanging_bands(surface: TriangleSurface, V, offset, hanging, bands=HANGING_BANDS, slack=KEEP_OUTSIDE_SLACK):
    """The keep-outside bands of the cloth that hangs free, beyond those of ``held_bands``: for each band ``b`` of
    ``bands`` (shares of ``offset``, increasing), its distance ``b * offset`` and the vertices of ``hanging`` that
    the garment at rest ``V`` on the body ``surface`` holds at least that far (as the Shrinkwrap measures,
    ``shrinkwrap_distance``; times ``slack``). Like ``held_bands``, the rule moves nothing at rest.

    Parameters
    ----------
    surface : TriangleSurface
        The body at rest (as Blender splits it, for a rig's Shrinkwraps).
    V : (g,3) float
        The garment at rest.
    offset : float
    hanging : (g,) bool
        The vertices that hang free (``riding_share`` 0).
    bands : sequence of float
    slack : float
        At most 1.

    Returns
    -------
    list of (float, (g,) bool)
        Bands with no vertex left out.
    """
    bands = _checked_bands(bands, slack, empty=True)
    V = np.asarray(V, dtype=np.float64)
    hanging = np.asarray(hanging, dtype=bool)
    if hanging.shape != (V.shape[0],):
        raise ValueError(f"hanging must have one value per garment vertex ({V.shape[0]}), got shape {hanging.shape}")
    if not bands or not hanging.any():
        return []
    held = np.full(V.shape[0], -np.inf)
    held[hanging] = shrinkwrap_distance(V[hanging], surface)[0]
    out = [(b * offset, held * slack >= b * offset) for b in bands]
    return [(d, only) for d, only in out if only.any()]


def held_bands(held, offset, bands=SHAPE_KEY_BANDS, slack=KEEP_OUTSIDE_SLACK):
    """``keep_outside_bands`` for any shapes the rule must not move: ``held``, a list of (TriangleSurface of the
    body, (g,3) garment on it); ``bands``, shares of ``offset``.

    Returns
    -------
    list of (float, (g,) bool)
    """
    bands = _checked_bands(bands, slack)
    # Measured as the Shrinkwrap measures (shrinkwrap_distance), so that keep_outside moves none of the shapes.
    held = np.min([shrinkwrap_distance(V, surface)[0] for surface, V in held], axis=0)
    # The floor: the first band, or less where the basis or a key at 1 has a vertex nearer (the crossing pass may
    # bring one closer than the offset). A vertex the Shrinkwrap judges inside in some shape (behind its closest
    # triangle's face normal, at a concave edge, though outside the body) is in no band: it would move it.
    ahead = held >= 0
    floor = float(np.clip(slack * held[ahead].min(), 0.0, bands[0] * offset)) if ahead.any() else 0.0
    out = [(floor, ahead)]
    for b in bands:
        if b * offset > floor:
            out.append((b * offset, held * slack >= b * offset))
    return out


def keep_outside_banded(V, surface: TriangleSurface, bands):
    """``keep_outside`` band after band (``keep_outside_bands``), as Blender's Shrinkwrap modifiers in a stack.

    Returns
    -------
    V : (g,3) float64
    """
    for distance, only in bands:
        V = keep_outside(V, surface, distance, only)
    return V


def shapes_outputs(target_body_paths, garment_path, out_dir):
    """The files ``shapes_to_files`` writes: ``{target name: <out_dir>/<garment>_on_<target>.obj}`` and
    ``<out_dir>/shapes.json``.

    Raises
    ------
    MeshError
        Two target files of one name (each names its output).
    """
    out_dir, g = Path(os.fspath(out_dir)), Path(os.fspath(garment_path)).stem
    outs, paths = {}, {}
    for path in target_body_paths:
        name = Path(os.fspath(path)).stem
        if name in outs:
            if os.path.abspath(os.fspath(path)) == os.path.abspath(paths[name]):
                raise MeshError(str(path), "is given twice as a target shape")
            raise MeshError(str(path), f"has the same name as {paths[name]}; each target shape needs "
                                       "its own file name (it names the output)")
        outs[name], paths[name] = out_dir / f"{g}_on_{name}.obj", str(path)
    return outs, out_dir / "shapes.json"


def shapes_to_files(source_body_path, target_body_paths, garment_path, out_dir, **options):
    """OBJ files in, OBJ files out: the garment on every target shape, with one preparation.

    The outputs are checked against the inputs before anything is read (``files.check_outputs``); every
    input is read and every transfer made before anything is written; each file is written
    atomically, then ``shapes.json`` (the summary).

    Parameters
    ----------
    source_body_path : path
    target_body_paths : list of path
        The source body's mesh in other shapes (same vertices and faces).
    garment_path : path
    out_dir : path
        Made if missing; receives ``<garment>_on_<target>.obj`` and ``shapes.json``.
    **options
        See ``fit_steps`` (``offset``, ``margin``, ``fix_penetration``, ``progress``).

    Returns
    -------
    dict
        The summary written to ``shapes.json``.
    """
    outs, summary_path = shapes_outputs(target_body_paths, garment_path, out_dir)
    check_outputs([*outs.values(), summary_path], [out_dir],
                  inputs=[source_body_path, *target_body_paths, garment_path])
    source = read_obj(source_body_path)
    garment = read_obj(garment_path)
    shapes, paths, bodies = {}, {}, {}
    # Shapes written with the other winding, or triangulated (the source too, along any diagonals), are shapes of
    # the source's mesh: fitted on the polygons they all split, so that every split of them is cleared.
    common = source
    for path in target_body_paths:
        name = Path(path).stem
        body = read_obj(path)
        common, last = common_mesh(common, body), common
        if common is None:
            require_same_topology(source, body)
            raise TopologyMismatchError(body.name, f"is a mirror image of {last.name} by its vertex order (its "
                                                   "shape encloses its volume the other way round); mirror both "
                                                   "or neither")
        shapes[name], paths[name], bodies[name] = body.V, str(path), body
    fit = fit_shape_keys(common, shapes, garment, with_basis=False, **options)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    rows, warnings = [], []
    for name, V in fit.keys.items():
        out = outs[name]
        write_obj(out, garment, V, header=f"Garment Transfer: {os.path.basename(garment_path)} on "
                                          f"{os.path.basename(paths[name])} (one of {len(shapes)} shapes)")
        # The figures of the file as written, against that shape as given.
        check = check_result(garment, read_obj(out).V, bodies[name],
                             source_pairs=fit.prepared.source_pairs(), readings=fit.prepared.readings())
        info = fit.info[name]
        warnings += result_warnings(check, str(out))
        rows.append({"target": name, "target_body": paths[name], "out": str(out),
                     "penetrating_vertices": check["inside_vertices"], "check": check, "offset": info["offset"],
                     "seconds": info["seconds"]})
    summary = {"source_body": str(source_body_path), "garment": str(garment_path),
               "vertices": garment.n_vertices, "faces": garment.n_faces, "shapes": rows, "warnings": warnings,
               "seconds": fit.seconds, "summary": str(summary_path)}
    write_json_atomic(summary_path, summary)
    return summary
