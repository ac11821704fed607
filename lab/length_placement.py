"""A placement from the cloth's length, nothing learned (a study; not part of the product).

Where the body carries a garment (the Poisson solve's anchors), the cloth is stretched with the body; the
simulated cloth keeps its length from where it hangs. Per connected piece of the garment, the arc length of
every vertex from the piece's top (its highest vertices, ``TOP_SHARE`` of its height; Dijkstra over the
garment's edges) is measured on the source garment and on the anchors; each anchor is moved back along its
shortest path towards the top by ``alpha`` times the difference. Turned into offsets per body triangle as
``placement.true_offsets`` turns a simulation, it goes where a placement model goes
(``transfer_garment``'s ``placement``), alone or mixed with a learned one (``LengthMixed``).
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components, dijkstra

from garment_transfer.geometry.binding import carry
from garment_transfer.geometry.gradients import orthonormal_frames
from garment_transfer.learning.placement import true_offsets

#: Share of a piece's height whose highest vertices are its top (where it hangs from).
TOP_SHARE = 0.03
#: Share of the length difference given back (chosen on the catalogue garments draped on the MakeHuman bodies:
#: the lowest placement error on three of four bodies; lab/notes/garment-model-study.md, "A placement from the cloth's
#: length").
ALPHA = 0.5
#: Steps up the shortest-path tree that give a vertex its direction towards the top.
STEPS = 5


def edges_of(F):
    """(E,2) int64: the unique edges of a triangle mesh."""
    E = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]).astype(np.int64)
    return np.unique(np.sort(E, axis=1), axis=0)


def length_offsets(V, A, F, up=1, top_share=TOP_SHARE):
    """Per garment vertex: the move (towards its piece's top) that gives back the length the anchors
    added, and that length.

    Parameters
    ----------
    V : (n,3) float
        The garment on the source body.
    A : (n,3) float
        Where the body carries it on the target (the anchors).
    F : (m,3) int
    up : int
        The up axis (0, 1 or 2).

    Returns
    -------
    offsets : (n,3) float64
        The full move (``alpha`` 1).
    excess : (n,) float64
        Arc length from the top on ``A`` less that on ``V``; 0 where no top is reached.
    """
    V, A = np.asarray(V, dtype=np.float64), np.asarray(A, dtype=np.float64)
    n = V.shape[0]
    E = edges_of(np.asarray(F))
    adjacency = coo_matrix((np.ones(len(E)), (E[:, 0], E[:, 1])), shape=(n, n))
    _, label = connected_components(adjacency, directed=False)
    order = np.argsort(label, kind="stable")
    starts = np.flatnonzero(np.r_[True, np.diff(label[order]) != 0])
    tops = []
    for piece in np.split(order, starts[1:]):
        h = V[piece, up]
        tops.append(piece[h >= h.max() - top_share * (h.max() - h.min())])
    tops = np.concatenate(tops)

    def graph(P):
        w = np.linalg.norm(P[E[:, 0]] - P[E[:, 1]], axis=1) + 1e-12
        return coo_matrix((w, (E[:, 0], E[:, 1])), shape=(n, n)).tocsr()

    d_source = dijkstra(graph(V), directed=False, indices=tops, min_only=True)
    d_target, pred, _ = dijkstra(graph(A), directed=False, indices=tops, min_only=True, return_predecessors=True)
    above = np.arange(n)
    for _ in range(STEPS):
        above = np.where(pred[above] >= 0, pred[above], above)
    d = A[above] - A
    length = np.linalg.norm(d, axis=1)
    direction = np.where(length[:, None] > 1e-12, d / np.maximum(length, 1e-12)[:, None], 0.0)
    excess = np.where(np.isfinite(d_target) & np.isfinite(d_source), d_target - d_source, 0.0)
    return excess[:, None] * direction, excess


class LengthPlacement:
    """``length_offsets`` as a placement: ``unrotated_offsets`` and ``frame_offsets`` as a
    ``placement.PlacementModel`` gives them (smoothed as ``true_offsets`` smooths a simulation)."""

    def __init__(self, up=1, alpha=ALPHA, top_share=TOP_SHARE):
        self.up, self.alpha, self.top_share = int(up), float(alpha), float(top_share)

    def unrotated_offsets(self, binding, source_body, target_body, garment, target=None):
        A = carry(binding, target_body.V, source_body.F)
        move, _ = length_offsets(garment.V, A, garment.F, self.up, self.top_share)
        return true_offsets(binding, source_body, target_body, A + self.alpha * move)[1]

    def frame_offsets(self, binding, source_body, target_body, garment, target=None):
        y = self.unrotated_offsets(binding, source_body, target_body, garment, target)
        return np.einsum("mij,mj->mi", orthonormal_frames(source_body.V, source_body.F), y)


class LengthMixed(LengthPlacement):
    """A learned placement (anything with ``unrotated_offsets``) mixed with the length-keeping one:
    ``(1 - share) y_learned + share y_length``."""

    def __init__(self, learned, share, up=1, alpha=ALPHA, top_share=TOP_SHARE):
        super().__init__(up, alpha, top_share)
        self.learned, self.share = learned, float(share)

    def unrotated_offsets(self, binding, source_body, target_body, garment, target=None):
        y = super().unrotated_offsets(binding, source_body, target_body, garment, target)
        learned = self.learned.unrotated_offsets(binding, source_body, target_body, garment, target)
        return (1.0 - self.share) * learned + self.share * y
