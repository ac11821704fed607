"""Embedding per-triangle garment fields on the body mesh and back (paper sect. 4, algorithms 1-2).

A garment of any topology becomes a fixed-size field on the source body's triangles, so garments
can be stacked for learning; a field on the body is carried back onto any garment.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from .mesh import edge_lengths_mean


def triangle_centroids(V, F):
    """(m,3) float64 centroids of the triangles F over V."""
    return np.asarray(V, dtype=np.float64)[F].mean(axis=1)


def body_scale(V) -> float:
    """Twice the largest distance from the centroid (about a standing body's height): a unit-free
    length scale that does not change when the body is moved or rotated."""
    V = np.asarray(V, dtype=np.float64)
    return float(2.0 * np.sqrt(np.max(np.sum((V - V.mean(axis=0)) ** 2, axis=1))))


def default_cover_distance(body_V, cloth_V, cloth_F) -> float:
    """How far from the garment a body triangle may be and still count as covered by it:
    5% of the body scale (about 9 cm on a 1.7 m body), and never less than three garment edge lengths."""
    return max(0.05 * body_scale(body_V), 3.0 * edge_lengths_mean(cloth_V, cloth_F))


def body_to_cloth(body_V, body_F, cloth_V, cloth_F, cover_distance=None):
    """BodyToCloth (algorithm 1): for each body triangle, the garment triangle with the nearest centroid.

    Parameters
    ----------
    body_V : (nb,3) float
    body_F : (M,3) int
    cloth_V : (nc,3) float
        The garment on the same (source) body.
    cloth_F : (T,3) int
    cover_distance : float, optional
        Body triangles farther than this from every garment triangle are uncovered
        (default: ``default_cover_distance``).

    Returns
    -------
    index : (M,) int64
        Garment triangle of each body triangle.
    covered : (M,) bool
        Whether the garment is near that body triangle.
    """
    if cover_distance is None:
        cover_distance = default_cover_distance(body_V, cloth_V, cloth_F)
    tree = cKDTree(triangle_centroids(cloth_V, cloth_F))
    dist, index = tree.query(triangle_centroids(body_V, body_F), k=1, workers=-1)
    return index.astype(np.int64), dist <= cover_distance


def embed(C, index):
    """The body field ``B[a] = C[index[a]]``.

    Parameters
    ----------
    C : (T,3,3) float
        Per-garment-triangle field.
    index : (M,) int
        From ``body_to_cloth``.

    Returns
    -------
    B : (M,3,3) float64
    """
    return np.asarray(C, dtype=np.float64)[index]


def cloth_to_body(body_V, body_F, cloth_V, cloth_F, k=1, tree=None):
    """ClothToBody (algorithm 2): for each garment triangle, the nearest body triangles.

    With ``k=1`` this is the paper's nearest triangle. With ``k>1`` the k nearest body triangles
    are blended with weights that fall off smoothly with the distance beyond the nearest one (a
    Gaussian as wide as the body's mean edge), which removes the blocky seams a garment finer than
    the body otherwise shows.

    Parameters
    ----------
    body_V : (nb,3) float
    body_F : (M,3) int
    cloth_V : (nc,3) float
    cloth_F : (T,3) int
    k : int
    tree : scipy.spatial.cKDTree, optional
        A tree over the body's triangle centroids, to reuse.

    Returns
    -------
    index : (T,k) int64
    weights : (T,k) float64
        Rows sum to 1.
    """
    if tree is None:
        tree = cKDTree(triangle_centroids(body_V, body_F))
    dist, index = tree.query(triangle_centroids(cloth_V, cloth_F), k=k, workers=-1)
    if k == 1:
        return index[:, None].astype(np.int64), np.ones((index.shape[0], 1))
    h = edge_lengths_mean(body_V, body_F)
    w = np.exp(-(((dist - dist[:, :1]) / max(h, 1e-300)) ** 2))
    w /= w.sum(axis=1, keepdims=True)
    return index.astype(np.int64), w


def unembed(B, index, weights):
    """The garment field ``C~[t] = sum_j weights[t,j] B[index[t,j]]``.

    Parameters
    ----------
    B : (M,3,3) float
    index : (T,k) int
    weights : (T,k) float

    Returns
    -------
    C : (T,3,3) float64
    """
    B = np.asarray(B, dtype=np.float64)
    if index.shape[1] == 1:
        return B[index[:, 0]]
    return np.einsum("tk,tkij->tij", weights, B[index])


def vertex_field(B, F, n):
    """Area-weighted average, at each vertex, of a per-triangle field.

    Parameters
    ----------
    B : (M,3,3) float
        Field on the triangles F.
    F : (M,3) int
    n : int
        Vertex count.

    Returns
    -------
    Bv : (n,3,3) float64
    """
    import scipy.sparse as sp

    M = F.shape[0]
    incidence = sp.csr_matrix((np.ones(3 * M), (F.reshape(-1), np.repeat(np.arange(M), 3))), shape=(n, M))
    count = np.asarray(incidence.sum(axis=1)).ravel()
    Bv = (incidence @ np.asarray(B, dtype=np.float64).reshape(M, 9)) / np.maximum(count, 1)[:, None]
    return Bv.reshape(n, 3, 3)


def unembed_interpolated(B, body_F, n_body, triangle, bary, cloth_F):
    """The garment field from a body field, interpolated linearly over the body surface.

    Each garment vertex reads the body field at its closest body point (the field averaged to the
    body's vertices, then interpolated with the point's barycentric coordinates); each garment
    triangle takes the mean of its three vertices. Unlike the nearest triangle, this is continuous
    over the body, so a garment finer than the body shows no seams along body edges.

    Parameters
    ----------
    B : (M,3,3) float
        Field on the body triangles.
    body_F : (M,3) int
    n_body : int
        Body vertex count.
    triangle : (nc,) int
        Body triangle of each garment vertex's closest point.
    bary : (nc,3) float
        Barycentric coordinates of that point.
    cloth_F : (T,3) int

    Returns
    -------
    C : (T,3,3) float64
    """
    W = interpolation_matrix(body_F, n_body, triangle, bary, cloth_F)
    return unembed_with_matrix(B, body_F, W)


def interpolation_matrix(body_F, n_body, triangle, bary, cloth_F):
    """The linear map of ``unembed_interpolated`` from body vertex values to garment triangles.

    It depends only on where the garment is bound, so a garment computes it once and applies it to
    the field of every target (``unembed_with_matrix``).

    Parameters
    ----------
    body_F : (M,3) int
    n_body : int
    triangle : (nc,) int
    bary : (nc,3) float
    cloth_F : (T,3) int

    Returns
    -------
    W : (T, n_body) scipy.sparse.csr_matrix
        Rows sum to 1.
    """
    import scipy.sparse as sp

    nc = triangle.shape[0]
    # Garment vertex -> body vertices (its barycentric weights), then garment triangle -> its corners.
    P = sp.csr_matrix((np.asarray(bary, dtype=np.float64).reshape(-1),
                       (np.repeat(np.arange(nc), 3), body_F[triangle].reshape(-1))), shape=(nc, n_body))
    T = cloth_F.shape[0]
    M = sp.csr_matrix((np.full(3 * T, 1.0 / 3.0), (np.repeat(np.arange(T), 3), cloth_F.reshape(-1))),
                      shape=(T, nc))
    return (M @ P).tocsr()


def unembed_with_matrix(B, body_F, W):
    """The garment field from a body field through an ``interpolation_matrix``.

    Parameters
    ----------
    B : (M,3,3) float
        Field on the body triangles.
    body_F : (M,3) int
    W : (T, n_body) sparse

    Returns
    -------
    C : (T,3,3) float64
    """
    Bv = vertex_field(B, body_F, W.shape[1])
    return np.asarray(W @ Bv.reshape(-1, 9)).reshape(-1, 3, 3)
