"""A body decimated for the non-rigid fit's first stages, and the finer body's vertices carried by it.

The stiff stages of the non-rigid fit move the body as a whole (a limb swings, the torso grows); a body
of a thousand or a few thousand vertices does that as well as one of 13K, at a fraction of the cost of a
step. The body is decimated (libigl's edge collapse, shortest edge first, so its triangles stay even),
every vertex of the finer body is attached to its closest point on the decimated surface (a triangle,
barycentric coordinates, and the offset from that point), and after the coarse stages the finer body is
carried by the decimated one: the point moves with its triangle, the offset turns with the coarse fit's
rotations there. The next stages run on the finer body from there (``nonrigid.LEVELS``).
"""

from __future__ import annotations

import logging

import igl
import numpy as np

from ..geometry.proximity import TriangleSurface

log = logging.getLogger(__name__)

#: The decimated body is used only when libigl reaches at most this share more triangles than asked
#: for (it stops early on a mesh it cannot collapse, such as a triangle soup of unwelded faces).
FACES_SLACK = 1.1


class CoarseBody:
    """A body decimated, with each vertex of the body attached to the decimated surface.

    Parameters
    ----------
    X : (n,3) float
        The body (the source, or a finer decimated body).
    F : (m,3) int
        Its triangles.
    U : (k,3) float
        The decimated body's vertices (``CoarseBody.of`` decimates).
    G : (l,3) int
        Its triangles.

    Attributes
    ----------
    X : (k,3) float64
        The decimated body's vertices.
    F : (l,3) int64
        Its triangles.
    alpha_scale : float
        The factor of a regulariser weight on the decimated body that gives the balance of the
        regulariser and the data terms that the weight gives on the body X (see ``regulariser_scale``).
    """

    def __init__(self, X, F, U, G):
        X = np.asarray(X, dtype=np.float64)
        self.X = np.ascontiguousarray(U, dtype=np.float64)
        self.F = np.ascontiguousarray(G, dtype=np.int64)
        _, _, self.tri, self.bary = TriangleSurface(self.X, self.F).closest(X)
        self.offset = X - self._points(self.X)
        self.alpha_scale = regulariser_scale(X, np.asarray(F, dtype=np.int64), self.X, self.F)

    @classmethod
    def of(cls, X, F, faces):
        """The body (X (n,3), F (m,3)) decimated to ``faces`` triangles; None when it is not worth
        decimating (at most 1.5 times ``faces`` triangles) or libigl cannot decimate it (a non-manifold
        edge, duplicate faces, a triangle soup)."""
        X = np.asarray(X, dtype=np.float64)
        F = np.asarray(F, dtype=np.int64)
        if F.shape[0] <= 1.5 * faces:
            return None
        U, G = igl.decimate(X, F, int(faces))[:2]
        if G.ndim != 2 or not 4 <= G.shape[0] <= FACES_SLACK * faces or not np.isfinite(U).all():
            log.info("registration: a body of %d triangles could not be decimated to %d (libigl gave %d); "
                     "its stages run on it", F.shape[0], faces, G.shape[0] if G.ndim == 2 else 0)
            return None
        return cls(X, F, U, G)

    def _points(self, Y):
        return np.einsum("ki,kij->kj", self.bary, Y[self.F[self.tri]])

    def carry(self, Y, R):
        """The body carried by the decimated one.

        Parameters
        ----------
        Y : (k,3) float
            The decimated body moved.
        R : (k,3,3) float
            Rotations of its vertices (rest to moved), as the non-rigid fit's regulariser finds them.

        Returns
        -------
        (n,3) float64
            Each vertex at its attachment point on Y, its offset turned by the rotations of that
            triangle's corners blended by the barycentric coordinates (smooth across triangles; the
            blend is not exactly a rotation, which on offsets of a fraction of an edge does not show).
        """
        turn = np.einsum("ki,kiab->kab", self.bary, R[self.F[self.tri]])
        return self._points(Y) + np.einsum("kab,kb->ka", turn, self.offset)


def regulariser_scale(X, F, Xc, Fc) -> float:
    """The factor of a regulariser weight on the body (Xc, Fc) that matches the weight on (X, F).

    The data terms weigh each vertex by its share of the area, normalised to a mean of 1, so they grow
    with the vertex count; the regulariser's squared edge misfits sum to about the same for one smooth
    deformation at any resolution (each edge's misfit goes as its length squared). Hence the vertex
    counts' ratio, times that of the sums of squared edge lengths (equal for even meshes of one surface).

    Parameters
    ----------
    X : (n,3) float
    F : (m,3) int
    Xc : (k,3) float
    Fc : (l,3) int

    Returns
    -------
    float
    """
    def squared_edges(V, T):
        return sum(float(np.sum((V[T[:, a]] - V[T[:, b]]) ** 2)) for a, b in ((0, 1), (1, 2), (2, 0)))

    return (Xc.shape[0] / X.shape[0]) * squared_edges(X, F) / squared_edges(Xc, Fc)
