"""The source body decimated for the non-rigid fit's first stages, and its vertices carried back.

The stiff stages of the non-rigid fit move the body as a whole (a limb swings, the torso grows); a body
of a few thousand vertices does that as well as one of 13K, at a fifth of the cost of a step. The
source is decimated (libigl's edge collapse, shortest edge first, so its triangles stay even), every
vertex of the source is attached to its closest point on the decimated surface (a triangle, barycentric
coordinates, and the offset from that point), and after the coarse stages the source is carried by the
decimated body: the point moves with its triangle, the offset turns with the coarse fit's rotations
there. The soft stages then run on the whole source from there.
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
    """A source body decimated, with each of its vertices attached to the decimated surface.

    Parameters
    ----------
    X : (n,3) float
        The source body.
    F : (m,3) int
        Its triangles.
    faces : int
        Triangles of the decimated body.

    Attributes
    ----------
    X : (k,3) float64
        The decimated body's vertices.
    F : (l,3) int64
        Its triangles.
    alpha_scale : float
        The factor of a regulariser weight on the decimated body that gives the balance of the
        regulariser and the data terms that the weight gives on the source (see ``regulariser_scale``).
    """

    def __init__(self, X, F, faces):
        X = np.asarray(X, dtype=np.float64)
        F = np.asarray(F, dtype=np.int64)
        U, G = igl.decimate(X, F, int(faces))[:2]
        self.X = np.ascontiguousarray(U, dtype=np.float64)
        self.F = np.ascontiguousarray(G, dtype=np.int64)
        _, _, self.tri, self.bary = TriangleSurface(self.X, self.F).closest(X)
        self.offset = X - self._points(self.X)
        self.alpha_scale = regulariser_scale(X, F, self.X, self.F)

    @classmethod
    def of(cls, X, F, faces):
        """The decimated body, or None when the source is not worth decimating (at most 1.5 times
        ``faces`` triangles) or libigl cannot decimate it (a non-manifold edge, duplicate faces, a
        triangle soup)."""
        F = np.asarray(F, dtype=np.int64)
        if F.shape[0] <= 1.5 * faces:
            return None
        body = cls(X, F, faces)
        if body.F.shape[0] < 4 or body.F.shape[0] > FACES_SLACK * faces or not np.isfinite(body.X).all():
            log.info("registration: the source body could not be decimated (%d triangles), fitted whole",
                     body.F.shape[0])
            return None
        return body

    def _points(self, Y):
        return np.einsum("ki,kij->kj", self.bary, Y[self.F[self.tri]])

    def carry(self, Y, R):
        """The source body carried by the decimated one.

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
