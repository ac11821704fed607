"""Skinning weights carried from a body to a garment.

Two rules:

- ``surface_weights``, the nearest surface point: each garment vertex takes the weights at its closest point
  on the body, blended from that triangle's corners by barycentric coordinates (Blender's Data Transfer with
  "Nearest Face Interpolated"). Right where the cloth lies on the skin; wrong where it hangs free: a skirt's
  panel between the legs takes each leg's weights in turn and tears apart when the legs part, a loose sleeve's
  underside takes the torso's.
- ``inpainted_weights``, after Abdrashitov et al., "Robust Skin Weights Transfer via Weight Inpainting"
  (SIGGRAPH Asia 2023): the body's weights are taken only where the garment vertex is close to the body and
  faces the same way, or touches it (*matched*); the rest is filled by the smoothest field over the garment
  with the matched vertices fixed (minimising ``tr(W^T Q W)``, ``Q = -L + L M^-1 L``: the cotangent Laplacian
  ``L`` and the lumped mass ``M``, harmonic and biharmonic), then each vertex keeps its few largest weights,
  normalised.
"""

from __future__ import annotations

import logging

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..errors import MeshError, RigError
from ..geometry.embedding import body_scale
from ..geometry.mesh import connected_pieces, vertex_areas, vertex_normals, vertex_places
from ..geometry.proximity import TriangleSurface
from .skinning import SkinWeights, skin_weights

log = logging.getLogger(__name__)

#: A garment vertex is matched when it is within this share of the body's scale from the body (about 4 cm on
#: a 1.7 m body; the paper's 5% of the bounding box diagonal is about 10 cm) ...
MATCH_DISTANCE_SHARE = 0.02
#: ... and its normal is within this angle of the body's at its closest point (the paper's 30 degrees) ...
MATCH_ANGLE = 30.0
#: ... or it touches the body, closer than this share of the body's scale (about 1 cm), facing any way: a
#: cuff's rim at the wrist, a collar's edge at the neck follow the skin they touch.
TOUCH_SHARE = 0.005
#: Influences kept per vertex by default: 8, what game engines take at most (4 is their other limit).
#: MakeHuman's body has up to 9 per vertex; keeping 4 moves the garment off the skin it was matched to: more
#: crossings and more stretch in motion than 8, which is as good as all (``lab/notes/motion-study.md``).
MAX_INFLUENCES = 8
#: A garment whose median distance from the body exceeds this share of the body's scale is not dressed on it.
FAR_SHARE = 0.2
#: A garment vertex rides the posed body's surface fully (``riding_share``) when it lies closer to the body than
#: this share of its scale (about 1 cm), whichever way it faces ...
RIDE_FULL_SHARE = 0.005
#: ... and not at all from this share on (about 4 cm, the match distance), or when it faces away farther than
#: ``RIDE_FULL_SHARE``; in between, the share falls linearly.
RIDE_NONE_SHARE = 0.02
#: Rounds of neighbour averaging of the share, so that no garment edge joins a riding vertex to a free one.
RIDE_SMOOTHING = 3


def surface_weights(body_V, body_F, weights, points, surface=None):
    """Per-vertex weights of a body, read at the points' closest places on its surface.

    Parameters
    ----------
    body_V : (n,3) float
    body_F : (m,3) int
        The body's triangles.
    weights : (n,k) float or scipy sparse
        ``k`` weight layers (vertex groups) of the body's vertices.
    points : (p,3) float
        The garment's vertices, in the body's space.
    surface : TriangleSurface, optional
        The body prepared for queries, to reuse.

    Returns
    -------
    W : (p,k) float64, or sparse csr when ``weights`` is sparse
    """
    body_V = np.asarray(body_V, dtype=np.float64)
    sparse = sp.issparse(weights)
    weights = sp.csr_matrix(weights, dtype=np.float64) if sparse else np.asarray(weights, dtype=np.float64)
    if weights.ndim != 2 or weights.shape[0] != body_V.shape[0]:
        raise ValueError(f"weights must be (n,k) with n = {body_V.shape[0]} body vertices, "
                         f"got {weights.shape}")
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if points.shape[0] == 0 or weights.shape[1] == 0:
        return sp.csr_matrix((points.shape[0], weights.shape[1])) if sparse else np.zeros((points.shape[0],
                                                                                           weights.shape[1]))
    surface = surface or TriangleSurface(body_V, body_F)
    _, _, tri, bary = surface.closest(points)
    return _barycentric(weights, np.asarray(body_F, dtype=np.int64)[tri], bary)


def _barycentric(weights, corners, bary):
    """Weights at surface points: ``sum_c bary_c weights[corner_c]``, dense or sparse like ``weights``."""
    if not sp.issparse(weights):
        return np.einsum("pc,pck->pk", bary, weights[corners])
    p = corners.shape[0]
    blend = sp.csr_matrix((bary.reshape(-1), corners.reshape(-1), np.arange(0, 3 * p + 1, 3)),
                          shape=(p, weights.shape[0]))
    return sp.csr_matrix(blend @ weights)


def cotangent_laplacian(V, F):
    """The cotangent Laplacian (negative semi-definite: ``-L`` is the stiffness matrix), with degenerate
    triangles left out.

    Parameters
    ----------
    V : (n,3) float
    F : (m,3) int

    Returns
    -------
    L : (n,n) scipy.sparse.csr_matrix
        Rows sum to zero; ``L x = 0`` inside a flat mesh for every linear ``x``.
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    n = V.shape[0]
    rows, cols, vals = [], [], []
    for k in range(3):
        i, j, o = F[:, (k + 1) % 3], F[:, (k + 2) % 3], F[:, k]
        a, b = V[i] - V[o], V[j] - V[o]
        cross = np.linalg.norm(np.cross(a, b), axis=1)
        scale = np.einsum("ij,ij->i", a, a) + np.einsum("ij,ij->i", b, b)
        ok = cross > 1e-12 * scale
        cot = np.divide(np.einsum("ij,ij->i", a, b), cross, out=np.zeros_like(cross), where=ok)
        rows += [i, j]
        cols += [j, i]
        vals += [0.5 * cot, 0.5 * cot]
    W = sp.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n)).tocsr()
    return (W - sp.diags(np.asarray(W.sum(axis=1)).ravel())).tocsr()


def smoothness_matrix(V, F):
    """``Q = -L + L M^-1 L`` (n,n) sparse: the inpainting energy's matrix (positive semi-definite)."""
    L = cotangent_laplacian(V, F)
    area = vertex_areas(np.asarray(V, dtype=np.float64), np.asarray(F, dtype=np.int64))
    floor = 1e-8 * float(area[area > 0].mean()) if (area > 0).any() else 1.0
    Minv = sp.diags(1.0 / np.maximum(area, floor))
    return (-L + L @ Minv @ L).tocsc()


def inpaint(Q, known, values):
    """The values at the unknown vertices that minimise ``tr(X^T Q X)`` with the known ones fixed.

    Parameters
    ----------
    Q : (n,n) sparse
        Positive semi-definite, positive definite on the unknowns (every piece has a known vertex).
    known : (n,) bool
    values : (n,k) float
        Rows of the known vertices are used.

    Returns
    -------
    X : (n,k) float64
        The known rows as given, the others solved.
    """
    X = np.array(values, dtype=np.float64)
    unknown = np.flatnonzero(~known)
    if unknown.size == 0 or X.shape[1] == 0:
        return X
    Q = sp.csc_matrix(Q)
    Quu = Q[unknown][:, unknown]
    Quk = Q[unknown][:, np.flatnonzero(known)]
    rhs = -(Quk @ X[known])
    X[unknown] = spla.splu(Quu.tocsc()).solve(np.ascontiguousarray(rhs))
    return X


def oriented_normals(V, F, toward):
    """Garment vertex normals (n,3), each connected piece turned so that it faces mostly like ``toward``
    (n,3) (the body's normals at the closest points): a garment's faces may be wound either way."""
    N = vertex_normals(V, F)
    _, label = connected_pieces(V.shape[0], F)
    agree = np.einsum("ij,ij->i", N, toward)
    sums = np.bincount(label, weights=agree, minlength=label.max() + 1)
    return N * np.where(sums[label] < 0, -1.0, 1.0)[:, None]


def match(body_V, body_F, garment_V, garment_F, distance=None, angle=MATCH_ANGLE, surface=None, touch=None):
    """Which garment vertices match the body: close to it and facing the same way, or touching it.

    Parameters
    ----------
    body_V : (n,3) float
    body_F : (m,3) int
    garment_V : (p,3) float
    garment_F : (q,3) int
    distance : float, optional
        Default ``MATCH_DISTANCE_SHARE`` of the body's scale.
    angle : float
        Largest angle between the garment's normal and the body's, in degrees.
    surface : TriangleSurface, optional
    touch : float, optional
        Closer than this matches whichever way it faces (default ``TOUCH_SHARE`` of the body's scale; 0: never).

    Returns
    -------
    matched : (p,) bool
    distance : (p,) float64
        Each vertex's distance from the body.
    tri : (p,) int64
        The body triangle of each vertex's closest point.
    bary : (p,3) float64
        Its barycentric coordinates.
    """
    surface = surface or TriangleSurface(body_V, body_F)
    if distance is None:
        distance = MATCH_DISTANCE_SHARE * body_scale(body_V)
    if touch is None:
        touch = TOUCH_SHARE * body_scale(body_V)
    _, dist, tri, bary = surface.closest(garment_V)
    body_N = vertex_normals(surface.V, surface.F) * surface.orientation
    at = np.einsum("pc,pcj->pj", bary, body_N[surface.F[tri]])
    at /= np.maximum(np.linalg.norm(at, axis=1, keepdims=True), 1e-300)
    N = oriented_normals(garment_V, garment_F, at)
    facing = np.einsum("ij,ij->i", N, at) >= np.cos(np.radians(angle))
    return ((dist <= distance) & facing) | (dist <= min(touch, distance)), dist, tri, bary


def _seed_lonely_pieces(matched, garment_F, distance_to_body):
    """A piece of the garment with no matched vertex gets its vertex closest to the body matched (it then
    follows that vertex's bones as a whole); a vertex in no triangle is matched itself."""
    n = matched.shape[0]
    _, label = connected_pieces(n, garment_F)
    used = np.zeros(n, dtype=bool)
    used[np.asarray(garment_F).reshape(-1)] = True
    matched = matched | ~used
    has = np.bincount(label, weights=matched.astype(float), minlength=label.max() + 1) > 0
    for piece in np.flatnonzero(~has):
        members = np.flatnonzero(label == piece)
        matched[members[np.argmin(distance_to_body[members])]] = True
    return matched


def inpainted_weights(body_V, body_F, body_weights: SkinWeights, garment_V, garment_F, *, distance=None,
                      angle=MATCH_ANGLE, max_influences=MAX_INFLUENCES, surface=None, name="garment", touch=None):
    """A garment's weights from a body's, matched where the surfaces agree and inpainted elsewhere.

    Parameters
    ----------
    body_V : (n,3) float
    body_F : (m,3) int
    body_weights : SkinWeights
        The body's weights (n vertices).
    garment_V : (p,3) float
    garment_F : (q,3) int
        The garment, dressed on the body (same space).
    distance : float, optional
        The largest distance of a matched vertex (default ``MATCH_DISTANCE_SHARE`` of the body's scale).
    angle : float
        The largest angle between a matched vertex's normal and the body's, in degrees.
    max_influences : int or None
        Groups kept per vertex (None: all).
    surface : TriangleSurface, optional
        The body prepared for queries.
    name : str
        The garment's name, for messages.
    touch : float, optional
        Closer than this matches whichever way the vertex faces (``match``).

    Returns
    -------
    weights : SkinWeights
        (p, g), the body's groups; normalised, at most ``max_influences`` per vertex.
    info : dict
        ``matched`` (vertices), ``inpainted`` (vertices), ``groups_used``, ``distance``, ``angle``,
        ``max_influences``, ``unweighted`` (vertices left with no weight: ``unweighted_vertices``), ``warnings``
        (a list of sentences).
    """
    garment_V = np.asarray(garment_V, dtype=np.float64)
    garment_F = np.asarray(garment_F, dtype=np.int64)
    if body_weights.n_vertices != np.asarray(body_V).shape[0]:
        raise RigError(body_weights.name, f"has weights for {body_weights.n_vertices} vertices; the body has "
                                          f"{np.asarray(body_V).shape[0]}")
    if garment_V.shape[0] == 0 or garment_F.shape[0] == 0:
        raise MeshError(name, "has no faces to carry weights to")
    # Pieces not joined at their seams (vertices at one place, ``mesh.vertex_places``): weighted as the joined
    # garment, so that the vertices of a place move alike and the seams stay closed in motion.
    place, first = vertex_places(garment_V)
    garment_V, garment_F = garment_V[first], place[garment_F]
    surface = surface or TriangleSurface(body_V, body_F)
    if distance is None:
        distance = MATCH_DISTANCE_SHARE * body_scale(surface.V)
    matched, dist, tri, bary = match(surface.V, surface.F, garment_V, garment_F, distance, angle, surface, touch)
    scale = body_scale(surface.V)
    if np.median(dist) > FAR_SHARE * scale:
        raise MeshError(name, f"is far from the body (median distance {np.median(dist):.3g}, body size "
                              f"{scale:.3g}): is it dressed on that body, in the same units and space?")
    known = _seed_lonely_pieces(matched, garment_F, dist)
    seeded = int((known & ~matched).sum())
    nearest = _barycentric(body_weights.W, surface.F[tri], bary)
    # Only groups present at a known vertex can appear anywhere in the solution (the solve is linear).
    present = np.flatnonzero(np.asarray(abs(nearest[known]).sum(axis=0)).ravel() > 0)
    values = np.zeros((garment_V.shape[0], present.size))
    values[known] = nearest[known][:, present].toarray()
    X = inpaint(smoothness_matrix(garment_V, garment_F), known, values)
    np.clip(X, 0.0, 1.0, out=X)
    p = garment_V.shape[0]
    W = sp.csr_matrix((X.ravel(), (np.repeat(np.arange(p), present.size), np.tile(present, p))),
                      shape=(p, len(body_weights.groups)))[place]
    weights = skin_weights(body_weights.groups, W, name)
    weights = weights.limited(max_influences) if max_influences else weights.normalised()
    matched, known = matched[place], known[place]
    info = {"matched": int(matched.sum()), "inpainted": int((~known).sum()), "groups_used": int(present.size),
            "distance": float(distance), "angle": float(angle),
            "max_influences": int(max_influences) if max_influences else None, "warnings": []}
    if seeded:
        info["warnings"].append(f"{seeded} pieces of {name} (or vertices in no face) have no vertex close to the "
                                "body and facing it: each follows the bones at its vertex nearest the body, as "
                                "a whole")
    info["unweighted"], warnings = unweighted_vertices(weights, body_weights, name)
    info["warnings"] += warnings
    log.debug("weights of %s: %d of %d vertices matched, %d inpainted", name, info["matched"],
              place.size, info["inpainted"])
    return weights, info


def unweighted_vertices(weights: SkinWeights, body_weights: SkinWeights, name="garment"):
    """The garment's vertices that its weights leave with none (a skinned vertex with no weight stays where it is
    when the bones move), and the sentence that says so.

    Such vertices come from a body whose weights are empty where the cloth takes them (a region left unpainted,
    a weights file of another body or of a few bones only).

    Parameters
    ----------
    weights : SkinWeights
        The garment's weights (``inpainted_weights``, ``nearest_weights``).
    body_weights : SkinWeights
        The body's weights they were carried from.
    name : str
        The garment's name, for the sentence.

    Returns
    -------
    count : int
        Garment vertices with no weight.
    warnings : list of str
        One sentence naming the garment, the count and the body's unweighted vertices; empty when every vertex has
        a weight.
    """
    count = int((weights.sums() <= 0).sum())
    if not count:
        return 0, []
    n, bare = weights.n_vertices, int((body_weights.sums() <= 0).sum())
    body = f"{bare} of the body's {body_weights.n_vertices} vertices have none in {body_weights.name}"
    if count == n:
        return count, [f"none of the {n} vertices of {name} has a weight ({body}, among them all those the "
                       "garment takes its weights from): it will not move with the bones; are these the weights "
                       "of the body it is dressed on?"]
    return count, [f"{count} of the {n} vertices of {name} have no weight ({body}, where the garment takes its "
                   "weights from them): they stay where they are when the bones move; give the body weights there"]


def nearest_weights(body_V, body_F, body_weights: SkinWeights, garment_V, *, max_influences=None, surface=None,
                    name="garment"):
    """``surface_weights`` as SkinWeights: the nearest surface rule, normalised, optionally limited.

    Returns
    -------
    SkinWeights
        (p, g).
    """
    W = surface_weights(body_V, body_F, body_weights.W, garment_V, surface)
    weights = skin_weights(body_weights.groups, W, name)
    return weights.limited(max_influences) if max_influences else weights.normalised()


def riding_share(body_V, body_F, garment_V, garment_F, *, full=None, none=None, angle=MATCH_ANGLE, surface=None,
                 smoothing=RIDE_SMOOTHING):
    """How much each garment vertex rides the posed body's surface rather than following the bones: 1 where the
    cloth lies on the skin, 0 where it hangs free, in between a ramp by the distance from the body.

    A vertex bound to the skinned body's surface (Blender's Surface Deform, bound at rest) keeps its distance
    from the skin in every pose, where linear blend skinning of the cloth itself folds it into the skin at the
    bends; a vertex that hangs free (a skirt's hem) must follow the bones instead, or it tears between the legs.

    Parameters
    ----------
    body_V : (n,3) float
    body_F : (m,3) int
    garment_V : (p,3) float
    garment_F : (q,3) int
        The garment, dressed on the body at rest.
    full : float, optional
        Closer than this rides fully, facing any way (default ``RIDE_FULL_SHARE`` of the body's scale).
    none : float, optional
        From this distance on it does not ride (default ``RIDE_NONE_SHARE`` of the body's scale).
    angle : float
        Between ``full`` and ``none`` a vertex rides only if its normal is within this angle of the body's.
    surface : TriangleSurface, optional
    smoothing : int
        Rounds of averaging with the neighbours.

    Returns
    -------
    share : (p,) float64
        In [0, 1].
    """
    garment_V = np.asarray(garment_V, dtype=np.float64)
    garment_F = np.asarray(garment_F, dtype=np.int64)
    # Pieces not joined at their seams: the joined garment's share, the vertices of a place alike.
    place, first = vertex_places(garment_V)
    garment_V, garment_F = garment_V[first], place[garment_F]
    surface = surface or TriangleSurface(body_V, body_F)
    scale = body_scale(surface.V)
    full = RIDE_FULL_SHARE * scale if full is None else float(full)
    none = RIDE_NONE_SHARE * scale if none is None else float(none)
    if not 0 <= full < none:
        raise ValueError(f"the riding distances must satisfy 0 <= full < none, got {full} and {none}")
    matched, dist, _, _ = match(surface.V, surface.F, garment_V, garment_F, none, angle, surface, full)
    share = np.clip((none - dist) / (none - full), 0.0, 1.0) * matched
    if smoothing and garment_F.shape[0]:
        n = garment_V.shape[0]
        i, j = garment_F.reshape(-1), np.roll(garment_F, 1, axis=1).reshape(-1)
        A = sp.csr_matrix((np.ones(i.size), (i, j)), shape=(n, n))
        A = ((A + A.T) > 0).astype(np.float64)
        degree = np.asarray(A.sum(axis=1)).ravel()
        mean = sp.diags(np.divide(1.0, degree, out=np.zeros(n), where=degree > 0)) @ A
        alone = degree == 0
        for _ in range(int(smoothing)):
            share = np.where(alone, share, 0.5 * share + 0.5 * (mean @ share))
    return share[place]
