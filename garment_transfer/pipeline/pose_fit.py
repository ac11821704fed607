"""A garment fitted to a posed body: the transfer from the rest body to the same mesh posed, kept outside it.

Skinning moves a garment with the character, but linear blend skinning folds cloth into the skin at the bends
(elbows, knees, hips) and tears or squashes its design. The transfer itself carries a garment from the rest body
to the posed one, which is the same mesh in another shape: the body's own deformation gradients, read at each
garment vertex, turn and stretch the cloth as the skin under it turns, and the Poisson solve keeps the folds
(``transfer.transfer_garment``, prepared once per garment: every pose after the first is a solve).

Then the crossing pass (``clearance.separate``) removes every garment edge through the body and body edge through
the garment, with one exception: where the posed body crosses itself (an arm into the torso, a heel into the
thigh, a hand into the hip; skinned bodies do) no garment between the two surfaces can be outside both, so the
body's triangles there, and ``CONTACT_RINGS`` rings of triangles around them, are left out of the pass. The
crossings left there are reported apart (``crossings_at_contact``), as are the body's own crossings.

Every count is made under every split of the quads and n-gons, of the garment and of the body (``every_split``):
a reader of the written file may split a quad along either diagonal.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from ..errors import GarmentTransferError, MeshError
from ..files import check_outputs, write_json_atomic
from ..geometry import clearance
from ..geometry.intersections import crossings, self_intersections
from ..geometry.obstacle import Obstacle, edge_length, garment_crossings
from ..geometry.mesh import Mesh, require_same_topology
from ..geometry.obj import read_obj, write_obj
from ..geometry.mdd import is_mdd_name, read_mdd, write_mdd
from ..geometry.pc2 import is_pc2, read_pc2, write_pc2
from ..geometry.penetration import vertex_adjacency
from ..geometry.proximity import TriangleSurface, made_of
from ..geometry.self_check import beyond_source, pairs_in_full
from ..geometry.threads import WORKERS, in_threads
from ..geometry.readings import (Readings, kept_triangle_readings, polygon_triangles_readings, readings_of,
                                 readings_with_graph, split_readings)
from .shape_keys import shapes_outputs
from .transfer import PreparedGarment, TransferResult, prepare_garment, transfer_garment

log = logging.getLogger(__name__)


class _Untangling(logging.Filter):
    """Drops the crossing pass's own log records in the threads that are untangling a fit: each try's passing state
    ("crossings left after 12 rounds") is judged by ``untangle_fit`` and may be thrown away, and what is kept is
    counted and said on what is written (``posed_counts``)."""

    def __init__(self):
        super().__init__()
        self.threads = set()

    def filter(self, record):
        return record.thread not in self.threads


_untangling = _Untangling()
logging.getLogger(clearance.__name__).addFilter(_untangling)

#: Rings of body triangles around the body's own crossings left out of the crossing pass (about 2 cm on the
#: MakeHuman body).
CONTACT_RINGS = 2
#: Two body parts pressed closer than this many cloth offsets (and farther apart at rest) are contact too: no
#: cloth fits between them.
CONTACT_GAP = 4.0
#: Crossing passes at most, each from the last one's result, while each leaves fewer crossings than the last.
PASSES = 3
#: Untangling a fit (``untangle``): rings of garment vertices around each crossing it made where the body crosses or
#: closes on itself that take back their positions from before it, and how many times that is done before the fit is
#: kept as it was.
UNTANGLE_RINGS = 2
UNTANGLE_TRIES = 3
#: Poses fitted at once by ``fit_poses`` (threads): a fit is numpy's, scipy's and libigl's work on whole arrays,
#: which runs outside Python's lock, so two poses at once on 2 cores take about 0.6 of the time of one after the
#: other (``python -m lab.motion --speed``).
POSE_WORKERS = WORKERS
#: A pose keeps the body's size: a posed body whose triangles' sides are, in the median, more than this many times
#: (or less than one over it) those of the rest body is in other units or scaled (``require_same_size``).
POSE_SIZE_RATIO = 1.5


def every_split(mesh: Mesh):
    """Every triangle of any split of the mesh's polygons: both diagonals of a quad, every fan of an n-gon.

    Parameters
    ----------
    mesh : Mesh

    Returns
    -------
    F : (k,3) int64
        The triangles the mesh is read as (``mesh.F``), then those of the other splits (a quad adds its two
        other triangles), each once.
    """
    fs, fv = mesh.face_start, mesh.face_vertices
    sizes = np.diff(fs)
    extra = []
    for k in np.unique(sizes[sizes > 3]):
        faces = np.flatnonzero(sizes == k)
        P = fv[fs[faces][:, None] + np.arange(k)]
        for apex in range(k):
            for j in range(1, k - 1):
                a, b = (apex + j) % k, (apex + j + 1) % k
                extra.append(P[:, [apex, a, b]])
    if not extra:
        return mesh.F
    F = np.concatenate([mesh.F] + extra)
    _, first = np.unique(np.sort(F, axis=1), axis=0, return_index=True)
    return F[np.sort(first)]


def kept_split(mesh: Mesh):
    """``every_split(mesh)``, kept per mesh (by the identity of its polygon arrays, which ``Mesh.with_vertices``
    keeps: every pose of one body)."""
    return _kept(_kept_splits, (mesh.face_vertices, mesh.face_start), lambda: every_split(mesh))


#: Meshes whose ``every_split`` is kept.
KEPT = 4
_kept_splits = []


def kept_rest_pairs(garment: Mesh):
    """The garment's own self-intersecting pairs at rest (``self_check.pairs_in_full`` of ``garment.V`` on
    ``garment_readings``), kept per garment (by the identity of its positions and polygons: every pose of a bake
    counts against the same rest garment)."""
    return _kept(_kept_rest_pairs, (garment.V, garment.face_vertices),
                 lambda: pairs_in_full(garment.V, garment_readings(garment)))


_kept_rest_pairs = []


def _kept(store, arrays, make):
    """What ``make()`` gives, kept in ``store`` (the latest ``KEPT``) for these very ``arrays`` (by identity)."""
    for kept, value in store:
        if all(a is b for a, b in zip(kept, arrays)):
            return value
    value = make()
    store.insert(0, (arrays, value))
    del store[KEPT:]
    return value


def self_contact(V, F, rings=CONTACT_RINGS, rest_V=None, gap=0.0):
    """Body vertices where the body crosses itself or closes on itself, and ``rings`` rings around them.

    Parameters
    ----------
    V : (n,3) float
        The posed body.
    F : (m,3) int or Readings
        Its triangles, or ``readings.split_readings`` of its mesh (the same triangles, checked faster).
    rings : int
    rest_V : (n,3) float, optional
        The body at rest: with ``gap``, two vertices that came closer than ``gap`` and were more than twice
        ``gap`` farther apart at rest (two body parts pressed together) are contact too.
    gap : float

    Returns
    -------
    contact : (n,) bool
    pairs : int
        The body's own edge-triangle crossings.
    """
    R = F if isinstance(F, Readings) else kept_triangle_readings(F)
    F = R.split
    count, edges, triangles = self_intersections(V, R)
    contact = np.zeros(V.shape[0], dtype=bool)
    contact[edges.reshape(-1)] = True
    contact[R.F[triangles].reshape(-1)] = True
    if rest_V is not None and gap > 0:
        close = cKDTree(V).query_pairs(gap, output_type="ndarray")
        if close.size:
            contact[close[_apart_at_rest(rest_V, close, 3.0 * gap)].reshape(-1)] = True
    if contact.any() and rings:
        contact = _grown(contact, vertex_adjacency(V.shape[0], np.asarray(F)), rings)
    return contact, count


def _grown(mask, A, rings):
    """(n,) bool: ``mask`` and ``rings`` rings of neighbours around it in the graph ``A`` ((n,n) sparse)."""
    mask = np.array(mask, dtype=bool)
    for _ in range(rings):
        mask |= (A @ mask.astype(np.float64)) > 0
    return mask


def _apart_at_rest(rest_V, pairs, distance):
    """(k,) bool: the vertex ``pairs`` (k,2) farther apart than ``distance`` in ``rest_V``. Gathered one
    coordinate column at a time (a posed body has about 700,000 pairs closer than the contact gap, nearly all
    neighbours on the skin: a row gather of them took as long as the body's own crossings)."""
    i, j = pairs[:, 0], pairs[:, 1]
    rest_V = np.asarray(rest_V)
    squared = np.zeros(pairs.shape[0])
    for k in range(3):
        x = np.ascontiguousarray(rest_V[:, k], dtype=np.float64)
        d = x[i] - x[j]
        squared += d * d
    return squared > distance * distance


def crossing_counts(V, F, body_V, body_F):
    """Garment edges through the body and body edges through the garment (each edge once)."""
    c = crossings(V, F, body_V, body_F)
    return c["a_edges_through_b"], c["b_edges_through_a"]


def fit_to_pose(rest_body: Mesh, posed_V, garment: Mesh, *, prepared: PreparedGarment | None = None,
                offset=None, resolve_crossings=True, contact_rings=CONTACT_RINGS, name=None,
                untangle=False) -> TransferResult:
    """Fit a garment dressed on the rest body to the same body posed.

    Parameters
    ----------
    rest_body : Mesh
        The body in its rest pose, the garment dressed on it.
    posed_V : (n,3) float
        The body's vertices in the pose (``rest_body``'s vertex order).
    garment : Mesh
        On the rest body (its rest result: a transfer's output).
    prepared : PreparedGarment, optional
        ``prepare_garment(rest_body, garment)``, made once for every pose.
    offset : float, optional
        Distance kept from the body (as ``transfer_garment``).
    resolve_crossings : bool
        Run the crossing pass (away from the body's own contact).
    contact_rings : int
        Rings around the body's own crossings left out of the pass.
    name : str, optional
        The pose's name, for messages.
    untangle : bool
        Then undo where the fit made the cloth cross itself (``untangle_fit``; seconds more a pose where it does).

    Returns
    -------
    TransferResult
        ``info`` adds ``crossings_outside_contact`` and ``crossings_at_contact`` (garment edges through the
        body plus body edges through the garment, under every split of both), ``body_self_crossings``,
        ``contact_vertices``, ``warnings`` and, untangled, ``untangle`` (``untangle_fit``'s figures); ``contact``
        is the posed body's own contact, ``obstacle`` the posed body away from it as the pass binned it
        (``free_body``), both for counting the result as written (``posed_counts``).
    """
    name = name or "pose"
    posed = rest_body.with_vertices(posed_V, name=name)
    require_same_topology(rest_body, posed)
    if prepared is None:
        prepared = prepare_garment(rest_body, garment)
    # The pose is the point here, not a difference to refuse (transfer.pose_check): the pass below clears it.
    result = transfer_garment(rest_body, posed, garment, prepared=prepared, offset=offset,
                              resolve_crossings=False, check_pose=False)
    t = time.perf_counter()
    # Pieces not joined at their seams (transferred as the joined garment): cleared as it, seams closed.
    joined = prepared.joined()
    cloth, V = (garment, result.V) if joined is None else (joined[0].garment, result.V[joined[1]])
    result.contact = body_contact(posed, result.info["offset"], rest_body.V, contact_rings)
    result.obstacle = free_body(posed, result.contact[0], cloth, V)
    V, result.penetrating_vertices = clear_posed_body(V, cloth, posed, result.info, rest_V=rest_body.V,
                                                      resolve_crossings=resolve_crossings, contact_rings=contact_rings,
                                                      name=name, contact=result.contact, free=result.obstacle,
                                                      surface=result.surface,
                                                      clear_of_body=result.penetrating_vertices == 0)
    result.V = V if joined is None else V[prepared.place]
    result.seconds["crossings"] = time.perf_counter() - t
    result.seconds["total"] += result.seconds["crossings"]
    if untangle and resolve_crossings:
        untangle_result(result, garment, posed)
    return result


def untangle_result(result: TransferResult, garment: Mesh, posed: Mesh) -> TransferResult:
    """``untangle_fit`` on a fit to a pose (``fit_to_pose``'s result, which is updated: positions, vertices inside,
    counts, warnings, ``info["untangle"]``, ``seconds["untangle"]``); ``garment`` at rest, ``posed`` the posed body
    (named after the pose)."""
    t = time.perf_counter()
    # Pieces not joined at their seams: untangled as the joined garment (as the fit cleared it).
    joined = result.prepared.joined()
    cloth, V = (garment, result.V) if joined is None else (joined[0].garment, result.V[joined[1]])
    V, result.penetrating_vertices, result.info["untangle"] = untangle_fit(
        V, cloth, posed, result.info, result.contact[0], result.obstacle, surface=result.surface,
        inside=result.penetrating_vertices)
    result.V = V if joined is None else V[result.prepared.place]
    result.info["warnings"] = pose_warnings(result.info["crossings_outside_contact"],
                                            result.info["crossings_at_contact"], result.info["body_self_crossings"],
                                            posed.name)
    result.seconds["untangle"] = time.perf_counter() - t
    result.seconds["total"] += result.seconds["untangle"]
    return result


def untangle_fit(V, garment: Mesh, body: Mesh, info, contact, free, *, surface=None, inside=None, rest_pairs=None):
    """Undo where a pose fit made the cloth cross itself.

    The transfer to a pose folds cloth through itself where the body bends (the lap sitting, the inside of an elbow,
    under the arms): measured on the MakeHuman suits in the six shared poses, 4 to 2,300 edge-triangle pairs the
    garment at rest does not have. The crossing pass is run again with the rest garment as its source shape
    (``clearance.separate``: around each such pair the cloth takes its shape from before, then its rest shape, and
    is cleared of the body again), against the body away from its own contact. Where that made the cloth cross the
    body at its contact (no cloth is outside both surfaces there, but it was not through them), those vertices and
    ``UNTANGLE_RINGS`` rings around them take back their fitted positions, up to ``UNTANGLE_TRIES`` times. The result is
    kept only if it crosses itself less than the fit and crosses the body no more, away from the contact or at it,
    with no more vertices inside.

    Parameters
    ----------
    V : (g,3) float
        The fit (``clear_posed_body``'s result).
    garment : Mesh
        At rest: its positions are the shape the cloth is given back.
    body : Mesh
        The posed body.
    info : dict
        The fit's ``info`` (``offset``, ``crossings_outside_contact``, ``crossings_at_contact``); the counts are
        updated there when the result is kept.
    contact : (n,) bool
        The posed body's own contact (``self_contact``).
    free : Obstacle
        The body away from it (``free_body``).
    surface : TriangleSurface, optional
        Of the posed body's own triangles.
    inside : int, optional
        The fit's vertices inside the posed body, when counted already.
    rest_pairs : (k,2) int, optional
        The rest garment's own self-intersecting pairs, when known.

    Returns
    -------
    V : (g,3) float64
    inside : int
    untangled : dict
        ``self_intersections_new_before`` and ``_after`` (pairs the rest garment does not have), ``kept`` (whether
        the untangled cloth was kept), ``restored_vertices``, ``given_back`` (vertices that took back their fitted
        positions at the body's contact).
    """
    V = np.asarray(V, dtype=np.float64)
    G = garment_readings(garment)
    rest_pairs = kept_rest_pairs(garment) if rest_pairs is None else rest_pairs
    before = int(beyond_source(pairs_in_full(V, G), G, garment.V, rest_pairs).shape[0])
    out = {"self_intersections_new_before": before, "self_intersections_new_after": before, "kept": False,
           "restored_vertices": 0, "given_back": 0}
    if not made_of(surface, body.V, body.F):
        surface = TriangleSurface(body.V, body.F)
    if inside is None:
        inside = int((surface.signed_distance(V)[0] < 0).sum())
    if before == 0:
        return V, inside, out
    offset = float(info["offset"])
    body_F = kept_split(body)
    near = (Obstacle(body.V, free_readings(body, contact, at_contact=True), cell=edge_length(V, G))
            if contact[body_F].any() else None)
    obstacle = free
    if near is not None:
        # The body's contact is an obstacle too, but where the fit crosses it (and a ring around).
        fitted = garment_crossings(V, G, near)
        crossed = np.zeros(body.V.shape[0], dtype=bool)
        crossed[near.F[fitted["a_triangles"]].reshape(-1)] = True
        crossed[fitted["b_pairs"].reshape(-1)] = True
        crossed = _grown(crossed, vertex_adjacency(body.V.shape[0], body_F), 1)
        obstacle = Obstacle(body.V, free_readings(body, crossed & contact), cell=edge_length(V, G))
    _untangling.threads.add(threading.get_ident())
    try:
        W, sep = clearance.separate(V, G, body.V, obstacle, offset, keep_offset=False, source_V=garment.V,
                                    source_pairs=rest_pairs)
    finally:
        _untangling.threads.discard(threading.get_ident())
    out["restored_vertices"] = int(sep.get("restored_vertices", 0))
    at = 0
    if near is not None:
        had = _crossing_keys(fitted)
        A = vertex_adjacency(V.shape[0], G.split)
        back = np.zeros(V.shape[0], dtype=bool)
        c = garment_crossings(W, G, near)
        for _ in range(UNTANGLE_TRIES):
            new = _vertices_of(c, G, V.shape[0], had)
            if not new.any():
                break
            new = _grown(new, A, UNTANGLE_RINGS)
            W[new] = V[new]
            back |= new
            c = garment_crossings(W, G, near)
        out["given_back"] = int(back.sum())
        at = edges_crossing(c)
    outside = edges_crossing(garment_crossings(W, G, free))
    inside_after = int((surface.signed_distance(W)[0] < 0).sum())
    after = int(beyond_source(pairs_in_full(W, G), G, garment.V, rest_pairs).shape[0])
    log.debug("untangle: %d -> %d self-intersections beyond the rest garment's, %d -> %d crossings away from the "
              "body's contact, %d -> %d at it, %d -> %d vertices inside", before, after,
              info["crossings_outside_contact"], outside, info["crossings_at_contact"], at, inside, inside_after)
    if (after < before and outside <= info["crossings_outside_contact"] and at <= info["crossings_at_contact"]
            and inside_after <= inside):
        out.update(self_intersections_new_after=after, kept=True)
        info.update(crossings_outside_contact=int(outside), crossings_at_contact=int(at))
        return W, inside_after, out
    return V, inside, out


def _crossing_keys(c):
    """The crossings of a ``garment_crossings`` answer, each as a key: a garment edge through an obstacle triangle,
    an obstacle edge through a garment triangle."""
    return ({("a", int(i), int(j), int(t)) for (i, j), t in zip(np.sort(c["a_pairs"], axis=1), c["a_triangles"])}
            | {("b", int(i), int(j), int(t)) for (i, j), t in zip(np.sort(c["b_pairs"], axis=1), c["b_triangles"])})


def _vertices_of(c, G: Readings, n, had):
    """(n,) bool: the garment vertices of the crossings of ``c`` (a ``garment_crossings`` answer) not among ``had``
    (``_crossing_keys``): a crossing edge's ends, the corners of a triangle an obstacle edge crosses."""
    new = np.zeros(n, dtype=bool)
    for kind, i, j, t in _crossing_keys(c) - had:
        new[[i, j] if kind == "a" else G.F[t]] = True
    return new


def fit_poses(rest_body: Mesh, poses, garment: Mesh, *, prepared: PreparedGarment | None = None, offset=None,
              resolve_crossings=True, workers=None, untangle=False):
    """Fit a garment to many poses of its body, several at once: ``fit_to_pose`` for each, prepared once.

    Parameters
    ----------
    rest_body, garment : Mesh
        As ``fit_to_pose``.
    poses : iterable of (name, (n,3) float)
        Each pose's name and body positions. It is read in the caller's thread, one pose at a time and at most
        ``workers`` poses ahead of what was given back: a generator may make each pose when asked (Blender sets a
        frame and reads the posed body).
    prepared : PreparedGarment, optional
    offset : float, optional
    resolve_crossings : bool
    workers : int, optional
        Poses fitted at once (default ``POSE_WORKERS``; 1: one after the other in the caller's thread).
    untangle : bool
        Untangle each fit (``fit_to_pose``).

    Yields
    ------
    (name, TransferResult)
        In the order of ``poses``; each result is what ``fit_to_pose`` gives for that pose alone, less the posed body
        as its pass binned and searched it (``obstacle`` and ``surface`` are None: about 25 MB a pose for a
        MakeHuman body, which a caller keeping many results, a bake, cannot hold; ``posed_counts`` bins it again,
        the same counts). Closing the generator (a cancel) drops the poses not begun and waits for those being
        fitted.
    """
    if prepared is None:
        prepared = prepare_garment(rest_body, garment)
    workers = POSE_WORKERS if workers is None else max(1, int(workers))

    def fit(name, V):
        result = fit_to_pose(rest_body, V, garment, prepared=prepared, offset=offset,
                             resolve_crossings=resolve_crossings, name=name, untangle=untangle)
        result.obstacle = result.surface = None
        return result

    if workers == 1:
        for name, V in poses:
            yield name, fit(name, V)
        return
    pool = ThreadPoolExecutor(workers, thread_name_prefix="pose-fit")
    pending = deque()
    try:
        for name, V in poses:
            pending.append((name, pool.submit(fit, name, np.array(V, dtype=np.float64))))
            if len(pending) > workers:
                name, job = pending.popleft()
                yield name, job.result()
        while pending:
            name, job = pending.popleft()
            yield name, job.result()
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def body_contact(body: Mesh, offset, rest_V=None, rings=CONTACT_RINGS):
    """A posed body's own contact as the pose fit reads it (``self_contact`` of its every split, ``rings`` rings
    around, with ``rest_V``, the body at rest of its mesh, parts pressed closer than ``CONTACT_GAP`` cloth
    offsets): ``(contact (n,) bool, crossings)``."""
    return self_contact(body.V, split_readings(body), rings, rest_V, CONTACT_GAP * float(offset))


def free_body(body: Mesh, contact, garment: Mesh, V):
    """The posed body's triangles of every split away from its own ``contact`` ((n,) bool), binned once for the
    counts and passes of one pose (an ``Obstacle`` of ``free_readings``; its cells sized for the garment's edges
    at V)."""
    return Obstacle(body.V, free_readings(body, contact),
                    cell=edge_length(np.asarray(V, dtype=np.float64), readings_of(garment)))


def free_readings(body: Mesh, contact, at_contact=False) -> Readings:
    """The triangles of every split of the body's polygons with no ``contact`` ((n,) bool) corner (``at_contact``:
    those with one), and their edges, binned by polygon (a quad's box holds its triangles: a quarter of the boxes
    of the triangles); the vertex graph and the surface are those triangles in ``kept_split``'s order."""
    R = readings_of(body)
    body_F = kept_split(body)
    keep, keep_split = contact[R.F].any(axis=1), contact[body_F].any(axis=1)
    if not at_contact:
        keep, keep_split = ~keep, ~keep_split
    return polygon_triangles_readings(R.F[keep], R.face[keep], body_F[keep_split], R.face_vertices, R.face_start)


def clear_posed_body(V, garment: Mesh, body: Mesh, info, *, rest_V=None, resolve_crossings=True,
                     contact_rings=CONTACT_RINGS, name="pose", contact=None, free=None, surface=None,
                     clear_of_body=False):
    """The crossing pass against a posed body, without where the body crosses itself or closes on itself.

    Parameters
    ----------
    V : (g,3) float
        The garment on the posed body (after the penetration fix).
    garment : Mesh
        Its faces (the polygons, for every split).
    body : Mesh
        The posed body.
    info : dict
        A transfer's ``info`` (``offset`` is read); the counts and ``warnings`` are added to it.
    rest_V : (n,3) float, optional
        The body at rest (same mesh): with it, body parts pressed together are contact too.
    resolve_crossings : bool
        Only count (False).
    contact_rings : int
    name : str
    contact : tuple, optional
        ``body_contact(body, offset, rest_V, contact_rings)``, when made already.
    free : Obstacle, optional
        ``free_body(body, contact[0], garment, V)``, when made already.
    surface : TriangleSurface, optional
        Of ``body``'s own triangles, when made already (``TransferResult.surface`` of the transfer to it).
    clear_of_body : bool
        No vertex of V is inside the body (measured: the penetration fix's count after it ran, 0): only the
        vertices the pass moves are measured again for the count of those inside.

    Returns
    -------
    V : (g,3) float64
    inside : int
        Garment vertices inside the posed body.
    """
    offset = float(info["offset"])
    given = np.array(V, dtype=np.float64) if clear_of_body else None
    # The body without its own contact, binned once for every count and pass of this pose.
    V, garment_F, body_F, (contact, body_self), free = _posed_parts(V, garment, body, offset, rest_V, contact_rings,
                                                                    contact, free)
    c = garment_crossings(V, garment_F, free)
    outside = edges_crossing(c)
    info.update(body_self_crossings=int(body_self), contact_vertices=int(contact.sum()))
    info.setdefault("warnings", [])
    if resolve_crossings and outside:
        # The pass sees the body without its own contact: there the garment cannot be outside both surfaces.
        info["crossing_pass"] = []
        for _ in range(PASSES):
            # The garment's own pairs are checked where a round moves it, not counted in full: none is reported.
            W, sep = clearance.separate(V, garment_F, body.V, free, offset, keep_offset=False, crossings=c,
                                        count_own=False)
            # The pass's own count is exact (what it moved checked again against the same binned body): a clean
            # pass needs no count of the whole garment; one that leaves pairs is counted again by edges.
            c = garment_crossings(W, garment_F, free) if sep["crossings_after"] else None
            after = 0 if c is None else edges_crossing(c)
            info["crossing_pass"].append({"before": int(outside), "after": int(after), "rounds": sep["rounds"],
                                          "moved_vertices": sep["moved_vertices"]})
            if after >= outside:
                break
            V, outside = W, after
            if not outside:
                break
    at, inside = at_contact_and_inside(V, garment_F, body, body_F, contact, surface,
                                       outside=None if given is None else np.all(V == given, axis=1))
    info.update(crossings_outside_contact=int(outside), crossings_at_contact=at)
    info["warnings"] += pose_warnings(int(outside), at, int(body_self), name)
    return V, inside


def _posed_parts(V, garment: Mesh, body: Mesh, offset, rest_V, contact_rings, contact, free):
    """What the pose fit's pass and counts read of garment positions V on a posed body: V as float64, the garment's
    and the body's triangles of every split, the body's own contact ``(contact, crossings)`` and the body away from
    it (``free_body``); ``contact`` and ``free`` are made unless given (``free`` only when of these very body
    positions)."""
    if contact is None:
        contact = body_contact(body, offset, rest_V, contact_rings)
    V = np.asarray(V, dtype=np.float64)
    if not made_of(free, body.V):
        free = free_body(body, contact[0], garment, V)
    return V, garment_readings(garment), kept_split(body), contact, free


def garment_readings(garment: Mesh) -> Readings:
    """The garment's readings as the pose fit checks and clears them: every triangle of every split, binned by
    polygon (``readings_of``), with every split's triangles as the vertex graph the pass spreads its moves over."""
    return readings_with_graph(garment, kept_split(garment))


def edges_crossing(c):
    """Garment edges through the body and body edges through the garment (each edge once) of a ``crossings``
    answer: ``crossing_counts``' sum."""
    return int(c["a_edges_through_b"] + c["b_edges_through_a"])


def at_contact_and_inside(V, garment_F, body: Mesh, body_F, contact, surface=None, outside=None):
    """The garment's crossings with the body's triangles at its own contact (each edge once, both ways), and the
    garment vertices inside the body (``surface``: of the body's own triangles, when made already; ``outside``:
    (g,) bool, vertices known to be outside, not measured again)."""
    at = 0
    if contact[body_F].any():
        near = Obstacle(body.V, free_readings(body, contact, at_contact=True), cell=edge_length(V, garment_F))
        at = edges_crossing(garment_crossings(V, garment_F, near))
    if not made_of(surface, body.V, body.F):
        surface = TriangleSurface(body.V, body.F)
    measure = slice(None) if outside is None else ~np.asarray(outside, dtype=bool)
    return at, int((surface.signed_distance(V[measure])[0] < 0).sum())


def pose_warnings(outside, at_contact, body_self, name):
    """What a pose fit leaves, said in words."""
    warnings = []
    if outside:
        warnings.append(f"{outside} garment-body crossings are left in {name} away from where the body crosses itself")
    if at_contact:
        warnings.append(f"{at_contact} garment-body crossings in {name} where the body crosses itself or closes on "
                        f"itself ({body_self} crossings of its own): no garment can be outside both surfaces there")
    return warnings


def posed_counts(V, garment: Mesh, body: Mesh, offset, *, rest_V=None, contact_rings=CONTACT_RINGS, name="pose",
                 contact=None, free=None, surface=None, rest_pairs=None, own=True):
    """The pose fit's figures of garment positions ``V`` (a file as written, read back; an object as Blender has
    it) on the posed body, as ``clear_posed_body`` counts them: ``crossings_outside_contact``,
    ``crossings_at_contact`` (under every split of both), ``penetrating_vertices``, ``body_self_crossings``; the
    garment's own crossings, ``self_intersections`` (edge-triangle pairs under every split) and
    ``self_intersections_new`` (those the garment at rest, ``garment.V``, does not have: ``beyond_source``); and
    ``warnings``. ``contact``, ``free``, ``surface``: the body's own contact, the body away from it and its own
    triangles searched, when made already (``TransferResult.contact``, ``obstacle`` and ``surface`` of the fit to
    this body; ``free`` and ``surface`` are used only when they are of these very body positions); ``rest_pairs``:
    the rest garment's own pairs, when known (else ``kept_rest_pairs``). ``own`` False: without the garment's own
    crossings (a caller that counts them with ``check_result``, against the garment's source)."""
    V, garment_F, body_F, (contact, body_self), free = _posed_parts(V, garment, body, offset, rest_V, contact_rings,
                                                                    contact, free)
    outside = edges_crossing(garment_crossings(V, garment_F, free))
    at, inside = at_contact_and_inside(V, garment_F, body, body_F, contact, surface)
    counts = {"crossings_outside_contact": outside, "crossings_at_contact": at, "penetrating_vertices": inside,
              "body_self_crossings": int(body_self), "warnings": pose_warnings(outside, at, int(body_self), name)}
    if not own:
        return counts
    pairs = pairs_in_full(V, garment_F)
    rest_pairs = kept_rest_pairs(garment) if rest_pairs is None else rest_pairs
    new = int(beyond_source(pairs, garment_F, garment.V, rest_pairs).shape[0])
    if new:
        counts["warnings"].append(f"the garment crosses itself in {name} at {new} edge-triangle pairs it does not at "
                                  f"rest ({pairs.shape[0]} in all): look at the folds where the body bends")
    counts.update(self_intersections=int(pairs.shape[0]), self_intersections_new=new)
    return counts


def require_same_size(rest: Mesh, V, name):
    """Raise MeshError (naming ``name``) unless positions ``V`` of the rest body's mesh keep its size: the median
    length of their triangles' sides within ``POSE_SIZE_RATIO`` of the rest body's (a pose bends and turns the
    body; a file in other units, centimetres for metres, or scaled, is another body)."""
    F = rest.F
    sides = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])

    def median(P):
        return float(np.median(np.linalg.norm(P[sides[:, 0]] - P[sides[:, 1]], axis=1)))

    ratio = median(np.asarray(V, dtype=np.float64)) / max(median(rest.V), 1e-300)
    if not 1.0 / POSE_SIZE_RATIO <= ratio <= POSE_SIZE_RATIO:
        raise MeshError(name, f"is the rest body {rest.name} at {ratio:.3g} times its size (the median of its "
                              "triangles' sides): another unit or a scaled body, not a pose of it; export both in "
                              "the same units and scale")


def cache_poses(rest: Mesh, body_cache):
    """The poses of a point cache of the rest body's mesh, a PC2 file (``POINTCACHE2``) or an MDD file (named
    ``.mdd``): ``(names, positions, timing)``, a pose per sample named by its frame (PC2: ``frame 12``) or its
    time (MDD: ``time 0.5 s``), each checked (finite, the body's size); ``timing`` is what a cache written in step
    with it needs: ``{"start_frame", "sample_rate"}`` or ``{"times"}``.

    Raises
    ------
    MeshError
        Naming the file: neither format, another mesh's points, a sample not finite or of another size."""
    name = str(body_cache)
    if is_pc2(body_cache):
        samples, start, rate = read_pc2(body_cache)
        timing = {"start_frame": start, "sample_rate": rate}
        labels = [f"frame {start + i * rate:.6g}" for i in range(samples.shape[0])]
    elif is_mdd_name(body_cache):
        samples, times = read_mdd(body_cache)
        timing = {"times": [float(t) for t in times]}
        labels = [f"time {t:.6g} s" for t in times]
    else:
        raise MeshError(name, "is neither a PC2 point cache (it does not start with POINTCACHE2) nor an MDD file "
                              "(named .mdd)")
    if samples.shape[1] != rest.n_vertices:
        raise MeshError(name, f"holds {samples.shape[1]} points a sample, but the rest body {rest.name} has "
                              f"{rest.n_vertices} vertices: the point cache of another mesh")
    names, positions = [], []
    for i, (pose, P) in enumerate(zip(labels, samples)):
        if pose in names:
            pose = f"{pose} (sample {i})"
        if not np.isfinite(P).all():
            raise MeshError(name, f"sample {i} ({pose}) has coordinates that are not numbers (NaN or infinite)")
        V = P.astype(np.float64)
        require_same_size(rest, V, f"{name}, sample {i} ({pose}),")
        names.append(pose)
        positions.append(V)
    return names, positions, timing


def write_cache_like(path, positions, timing, inputs):
    """Write ``positions`` (k,n,3) as a point cache in step with a body's (``cache_poses``'s ``timing``): PC2 at
    its start frame and sample rate, or MDD at its times. Returns the positions as written, read back."""
    if "times" in timing:
        write_mdd(path, positions, timing["times"], inputs=inputs, what="--cache")
        return read_mdd(path)[0]
    write_pc2(path, positions, start_frame=timing["start_frame"], sample_rate=timing["sample_rate"], inputs=inputs,
              what="--cache")
    return read_pc2(path)[0]


def poses_to_files(rest_body_path, posed_body_paths, garment_path, out_dir, *, body_cache=None, offset=None,
                   progress=None, workers=None, cache=None, untangle=False):
    """OBJ files or a point cache in, OBJ files or a point cache out: the garment fitted to every pose of its
    body, prepared once.

    Every pose is fitted before anything is written; each file is written atomically, then ``poses.json``. The
    figures are counted on the files as written, read back, against each pose as given.

    Parameters
    ----------
    rest_body_path : path
    posed_body_paths : list of path
        The rest body's mesh posed (same vertices and faces); empty with ``body_cache``.
    garment_path : path
        The garment on the rest body.
    out_dir : path
        Made if missing; receives ``<garment>_on_<pose>.obj`` (not with ``body_cache``) and ``poses.json``.
    body_cache : path, optional
        A point cache of the rest body's mesh animated, PC2 or MDD (``cache_poses``): every sample is a pose. The
        fits then go to ``cache`` alone (which it needs), in the body cache's format at its frames (PC2: its start
        frame and sample rate; MDD: its times), so that the two play in step.
    offset : float, optional
    progress : callable, optional
        ``progress(fraction, pose)``, as each pose is fitted.
    workers : int, optional
        Poses fitted at once (``fit_poses``).
    cache : path, optional
        Every pose's fit as one point cache, in the order given: from OBJ files, the files as written as PC2 at frames
        1, 2, ... (``pc2.write_pc2``); from ``body_cache``, as it is written (``write_cache_like``).
    untangle : bool
        Untangle each fit (``fit_to_pose``): seconds more a pose where the fit crosses itself.

    Returns
    -------
    dict
        The summary written to ``poses.json`` (with ``warnings``).
    """
    if body_cache is not None and (posed_body_paths or cache is None):
        raise GarmentTransferError("a body's point cache gives every pose, and the fits go to a point cache: no "
                                   "posed OBJ files beside it, and a cache to write")
    if body_cache is None:
        outs, summary_path = shapes_outputs(posed_body_paths, garment_path, out_dir)
        summary_path = summary_path.with_name("poses.json")
    else:
        outs, summary_path = {}, Path(out_dir) / "poses.json"
    inputs = [rest_body_path, *posed_body_paths, *([body_cache] if body_cache is not None else []), garment_path]
    check_outputs([*outs.values(), summary_path, *([cache] if cache is not None else [])], [out_dir], inputs=inputs)
    rest = read_obj(rest_body_path)
    garment = read_obj(garment_path)
    poses, paths, frames = {}, {}, {}
    if body_cache is None:
        if cache is not None and is_mdd_name(cache):
            raise GarmentTransferError(f"--cache {cache}: the poses of OBJ files are written as one PC2 point cache "
                                       "(frames 1, 2, ...): give it a name that does not end in .mdd")
        timing = {"start_frame": 1.0, "sample_rate": 1.0}
        for path in posed_body_paths:
            name = Path(path).stem
            body = read_obj(path)
            require_same_topology(rest, body)
            require_same_size(rest, body.V, str(path))
            poses[name], paths[name] = body.V, str(path)
    else:
        names, positions, timing = cache_poses(rest, body_cache)
        if is_mdd_name(cache) != ("times" in timing):
            raise GarmentTransferError(f"--cache {cache}: the garment's cache is written in the format of the body's, "
                                       f"{'MDD' if 'times' in timing else 'PC2'}: give it a name that "
                                       f"{'ends' if 'times' in timing else 'does not end'} in .mdd")
        for i, (name, V) in enumerate(zip(names, positions)):
            poses[name], paths[name] = V, str(body_cache)
            frames[name] = {"sample": i, **({"time": timing["times"][i]} if "times" in timing else
                                            {"frame": timing["start_frame"] + i * timing["sample_rate"]})}
    t = time.perf_counter()
    prepared = prepare_garment(rest, garment)
    seconds = {"prepare": time.perf_counter() - t}
    results = {}
    for i, (name, result) in enumerate(fit_poses(rest, poses.items(), garment, prepared=prepared, offset=offset,
                                                  workers=workers, untangle=untangle)):
        if progress is not None:
            progress((i + 1) / len(poses), name)
        results[name] = result
    seconds["poses"] = time.perf_counter() - t - seconds["prepare"]
    Path(out_dir).mkdir(parents=True, exist_ok=True)
    if body_cache is None:
        for name, result in results.items():
            write_obj(outs[name], garment, result.V, inputs=inputs,
                      header=f"Garment Transfer: {Path(garment_path).name} fitted to the pose {Path(paths[name]).name}")
        # The files as written, read back: their figures against each pose as given, and the point cache.
        written = {name: read_obj(outs[name]).V for name in results}
        if cache is not None:
            write_cache_like(cache, np.stack(list(written.values())), timing, inputs)
    else:
        # The point cache as written, read back (32-bit coordinates): its figures against each sample of the body's.
        stack = np.stack([result.V for result in results.values()])
        written = dict(zip(results, write_cache_like(cache, stack, timing, inputs).astype(np.float64)))
        outs = {name: f"{cache}, sample {frames[name]['sample']}" for name in results}
    rest_pairs = kept_rest_pairs(garment)

    def written_counts(name):
        result = results[name]
        return posed_counts(written[name], garment, rest.with_vertices(poses[name], name=name),
                            float(result.info["offset"]), rest_V=rest.V, name=str(outs[name]),
                            contact=result.contact, rest_pairs=rest_pairs)

    rows, warnings = [], []
    for name, counts in zip(results, in_threads(written_counts, list(results), workers)):
        warnings += counts.pop("warnings")
        result = results[name]
        rows.append({"target": name, "target_body": paths[name], **frames.get(name, {}),
                     "out": str(cache) if body_cache is not None else str(outs[name]), **counts,
                     "offset": result.info["offset"], "seconds": result.seconds,
                     **({"untangle": result.info["untangle"]} if "untangle" in result.info else {})})
    folded = [row["target"] for row in rows if row["self_intersections_new"]]
    if folded and not untangle:
        warnings.append(f"{len(folded)} of {len(rows)} poses fold the cloth through itself where it is not at rest "
                        f"(first: {folded[0]}): untangling (--untangle) undoes it where it can, seconds more a pose")
    seconds["total"] = time.perf_counter() - t
    summary = {"source_body": str(rest_body_path), "garment": str(garment_path), "vertices": garment.n_vertices,
               "faces": garment.n_faces, "poses": True, "untangle": bool(untangle), "shapes": rows, "seconds": seconds,
               "summary": str(summary_path), "cache": None if cache is None else str(cache),
               "body_cache": None if body_cache is None else str(body_cache),
               **(timing if cache is not None else {}), "warnings": warnings}
    write_json_atomic(summary_path, summary)
    return summary
