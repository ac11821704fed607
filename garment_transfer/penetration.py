"""Garment-body penetration: measuring it and removing it while keeping the folds.

Vertices inside the body, or closer to it than a thickness offset, are moved to the offset surface
along the body's outward normal. That push is spread to the surrounding garment as a smooth
displacement field (a screened Laplace problem on the garment's own graph, solved only in a band
around the pushed vertices), so the cloth moves as a whole and its folds, which are high-frequency,
stay. A few rounds settle vertices that the spreading itself moved; the last round projects any
vertex still too close, so no vertex is left inside.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .mesh import edge_lengths_mean
from .proximity import TriangleSurface


def vertex_adjacency(n, F):
    """(n,n) csr 0/1 adjacency of the triangles' edges."""
    i = np.concatenate([F[:, 0], F[:, 1], F[:, 2], F[:, 1], F[:, 2], F[:, 0]])
    j = np.concatenate([F[:, 1], F[:, 2], F[:, 0], F[:, 0], F[:, 1], F[:, 2]])
    A = sp.csr_matrix((np.ones(i.shape[0]), (i, j)), shape=(n, n))
    A.data[:] = 1.0
    return A


def penetration(V, surface: TriangleSurface):
    """Share of vertices inside the body and the depth of the deepest.

    Parameters
    ----------
    V : (n,3) float
        Garment vertices.
    surface : TriangleSurface
        The body.

    Returns
    -------
    ratio : float
        Share of vertices inside (0..1).
    max_depth : float
        Depth of the deepest vertex (0 if none is inside).
    inside : (n,) bool
    """
    sd = surface.signed_distance(V)[0]
    inside = sd < 0
    depth = float(-sd[inside].min()) if inside.any() else 0.0
    return float(inside.mean()), depth, inside


def spread_displacement(A, fixed, displacement, decay_rings):
    """A smooth displacement equal to ``displacement`` on ``fixed`` vertices and fading around them.

    Solves ``(L + mu I) d = 0`` on the free vertices of a band of about ``3 * decay_rings`` rings
    around the fixed ones (zero beyond), with the graph Laplacian L and ``mu = 1/decay_rings^2``.

    Parameters
    ----------
    A : (n,n) sparse adjacency
    fixed : (n,) bool
    displacement : (k,3) float
        For the fixed vertices, in order.
    decay_rings : float

    Returns
    -------
    D : (n,3) float64
    """
    n = A.shape[0]
    D = np.zeros((n, 3))
    D[fixed] = displacement
    band = fixed.copy()
    for _ in range(int(np.ceil(3 * decay_rings))):
        grown = band | (A @ band.astype(np.float64) > 0)
        if grown.sum() == band.sum():
            break
        band = grown
    free = band & ~fixed
    if not free.any():
        return D
    deg = np.asarray(A.sum(axis=1)).ravel()
    L = sp.diags(deg) - A
    mu = 1.0 / max(decay_rings, 1.0) ** 2
    fi = np.flatnonzero(free)
    Lff = (L[fi][:, fi] + mu * sp.identity(fi.size)).tocsc()
    rhs = -(L[fi][:, np.flatnonzero(fixed)] @ displacement)
    D[fi] = spla.splu(Lff, permc_spec="COLAMD").solve(rhs)
    return D


def signed_distance_near(surface: TriangleSurface, V, band):
    """Signed distances, searched widely (16 candidates) only where they are below ``band``.

    A first pass with 8 candidate triangles per vertex decides which vertices are clearly away
    from the body; those within ``band`` of it (or inside) are measured again with 16.

    Returns
    -------
    sd : (n,) float64
    closest : (n,3) float64
    normal : (n,3) float64
    """
    sd, closest, normal, _ = surface.signed_distance(V, k=8)
    near = sd < band
    if near.any():
        sd[near], closest[near], normal[near], _ = surface.signed_distance(V[near], k=16)
    return sd, closest, normal


def fix_penetration(V, F, surface: TriangleSurface, offset, spread_length=None, rounds=4):
    """Move garment vertices out of the body (to at least ``offset`` from it), spreading the move.

    Parameters
    ----------
    V : (n,3) float
        Garment vertices.
    F : (m,3) int
        Garment triangles.
    surface : TriangleSurface
        The body the garment must not enter.
    offset : float
        Cloth thickness: the smallest allowed distance to the body.
    spread_length : float, optional
        How far the push fades out over the garment (default: 10 garment edge lengths).
    rounds : int
        Spreading rounds before the final projection.

    Returns
    -------
    V : (n,3) float64
        The fixed vertices (a new array).
    info : dict
        ``pushed_vertices`` (vertices closer than offset at the start), ``inside_before``,
        ``inside_after``, ``rounds``.
    """
    V = np.array(V, dtype=np.float64)
    h = edge_lengths_mean(V, F)
    decay = (spread_length / h) if spread_length else 10.0
    A = vertex_adjacency(V.shape[0], F)
    sd, closest, normal = signed_distance_near(surface, V, offset + 2 * h)
    info = {"inside_before": int((sd < 0).sum()), "pushed_vertices": int((sd < offset).sum())}
    done = 0
    for done in range(1, rounds + 1):
        bad = sd < offset
        if not bad.any():
            break
        target = closest[bad] + offset * normal[bad]
        if done < rounds:
            D = spread_displacement(A, bad, target - V[bad], decay)
            moved = np.any(D != 0, axis=1)
            V[moved] += D[moved]
        else:
            moved = bad
            V[bad] = target
        # Only what moved needs measuring again.
        sd[moved], closest[moved], normal[moved], _ = surface.signed_distance(V[moved])
    # Whatever the last projection could not settle (the closest point moved) is projected again.
    bad = sd < 0
    if bad.any():
        V[bad] = closest[bad] + offset * normal[bad]
        sd[bad] = surface.signed_distance(V[bad])[0]
    info["inside_after"] = int((sd < 0).sum())
    info["rounds"] = done
    return V, info
