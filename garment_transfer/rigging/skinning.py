"""Skinning weights and linear blend skinning.

Weights are named groups (a bone's name, as Blender's vertex groups) with a weight per vertex, stored sparse:
most vertices hang from a few bones. On disk they are JSON, ``{"weights": {group: [[vertex, weight], ...]}}``
(the shared ``rig/weights.json``), or the bare ``{group: [[vertex, weight], ...]}``.

Linear blend skinning moves a vertex by the weighted mean of its bones' transforms,
``x' = sum_b w_b (A_b x + t_b)`` with the weights normalised to sum 1 (``normalised``), as MakeHuman and
Blender's Armature modifier do; a vertex with no weight stays where it is.
"""

from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from ..errors import RigError
from ..files import write_json_atomic
from .skeleton import Skeleton

#: Weights below this are dropped when weights are limited or written (Blender's vertex groups keep them,
#: but they move nothing visible and cost an influence).
SMALLEST_WEIGHT = 1e-4


@dataclass
class SkinWeights:
    """Per-vertex weights of named groups.

    Attributes
    ----------
    groups : tuple of str
        (g,) group names.
    W : (n,g) scipy.sparse.csr_matrix of float64
        Weights, vertices by groups.
    name : str
    """

    groups: tuple
    W: sp.csr_matrix
    name: str = "weights"

    @property
    def n_vertices(self) -> int:
        return int(self.W.shape[0])

    def dense(self):
        """(n,g) float64."""
        return self.W.toarray()

    def influences(self):
        """(n,) int: the groups with a weight above 0 at each vertex."""
        return np.diff(self.W.indptr)

    def sums(self):
        """(n,) float64: each vertex's total weight."""
        return np.asarray(self.W.sum(axis=1)).ravel()

    def normalised(self) -> "SkinWeights":
        """The weights scaled to sum 1 at every vertex that has any."""
        s = self.sums()
        scale = np.divide(1.0, s, out=np.zeros_like(s), where=s > 0)
        return SkinWeights(self.groups, sp.csr_matrix(sp.diags(scale) @ self.W), self.name)

    def limited(self, k) -> "SkinWeights":
        """At most ``k`` groups per vertex (its largest weights), then normalised.

        Parameters
        ----------
        k : int
            At least 1 (game engines take 4 or 8).
        """
        if int(k) < 1:
            raise ValueError(f"the number of influences must be at least 1, got {k}")
        W = self.W.tocsr(copy=True)
        W.data[W.data < SMALLEST_WEIGHT] = 0.0
        W.eliminate_zeros()
        counts = np.diff(W.indptr)
        if counts.max(initial=0) > k:
            rows = np.repeat(np.arange(W.shape[0]), counts)
            # Within each vertex, rank its weights from the largest (ties: the lower group index first).
            order = np.lexsort((W.indices, -W.data, rows))
            rank = np.empty_like(order)
            rank[order] = np.arange(order.size) - np.repeat(W.indptr[:-1], counts)
            W.data[rank >= k] = 0.0
            W.eliminate_zeros()
        return SkinWeights(self.groups, W, self.name).normalised()

    def subset(self, groups) -> "SkinWeights":
        """Only the named groups, in that order (groups not present come out empty)."""
        where = {g: i for i, g in enumerate(self.groups)}
        cols = [where.get(g, -1) for g in groups]
        W = self.W.tocsc()
        parts = [W[:, c] if c >= 0 else sp.csc_matrix((self.n_vertices, 1)) for c in cols]
        if not parts:
            return SkinWeights((), sp.csr_matrix((self.n_vertices, 0)), self.name)
        return SkinWeights(tuple(groups), sp.hstack(parts).tocsr(), self.name)


def skin_weights(groups, W, name="weights") -> SkinWeights:
    """SkinWeights from group names and a dense (n,g) or sparse matrix, checked: finite, in [0, 1]-ish
    (at least 0), one column per group."""
    W = sp.csr_matrix(W, dtype=np.float64)
    groups = tuple(str(g) for g in groups)
    if W.shape[1] != len(groups):
        raise RigError(name, f"has {W.shape[1]} weight columns for {len(groups)} groups")
    if len(set(groups)) != len(groups):
        raise RigError(name, "names a group twice")
    if W.nnz and (not np.isfinite(W.data).all() or W.data.min() < 0):
        raise RigError(name, "has a weight that is negative, NaN or infinite")
    W.eliminate_zeros()
    W.sort_indices()
    return SkinWeights(groups, W, name)


def weights_from_dict(data, n_vertices=None, name="weights") -> SkinWeights:
    """SkinWeights from ``{group: [[vertex, weight], ...]}`` (or that mapping under ``"weights"``).

    Parameters
    ----------
    data : dict
    n_vertices : int, optional
        The mesh's vertex count: a vertex index at or above it is refused. Default: the largest index + 1.
    name : str
    """
    if isinstance(data, dict) and isinstance(data.get("weights"), dict):
        data = data["weights"]
    if not isinstance(data, dict):
        raise RigError(name, "is not a mapping of group names to [[vertex, weight], ...] lists")
    rows, cols, vals = [], [], []
    for j, (group, pairs) in enumerate(data.items()):
        try:
            a = np.asarray(pairs, dtype=np.float64).reshape(-1, 2)
        except (TypeError, ValueError):
            raise RigError(name, f"group {group!r} is not a list of [vertex, weight] pairs") from None
        if a.size and (not np.isfinite(a).all() or (a[:, 0] != np.round(a[:, 0])).any() or a[:, 0].min() < 0):
            raise RigError(name, f"group {group!r} has a vertex index that is not a whole number >= 0")
        rows.append(a[:, 0].astype(np.int64))
        cols.append(np.full(a.shape[0], j, dtype=np.int64))
        vals.append(a[:, 1])
    rows = np.concatenate(rows) if rows else np.zeros(0, np.int64)
    top = int(rows.max()) + 1 if rows.size else 0
    n = top if n_vertices is None else int(n_vertices)
    if top > n:
        raise RigError(name, f"refers to vertex {top - 1}, but the mesh has {n} vertices: are these the "
                             "weights of another mesh?")
    W = sp.coo_matrix((np.concatenate(vals) if vals else np.zeros(0),
                       (rows, np.concatenate(cols) if cols else np.zeros(0, np.int64))),
                      shape=(n, len(data))).tocsr()
    return skin_weights(list(data), W, name)


def read_weights(path, n_vertices=None) -> SkinWeights:
    """Read a weights file (see ``weights_from_dict``)."""
    try:
        with open(path, encoding="utf-8") as fh:
            data = json.load(fh)
    except OSError as e:
        raise RigError(str(path), f"cannot be read ({e.strerror or e})") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise RigError(str(path), f"is not a JSON file ({e})") from None
    return weights_from_dict(data, n_vertices, str(path))


def weights_to_dict(weights: SkinWeights, digits=6):
    """``{group: [[vertex, weight], ...]}`` of the weights above ``SMALLEST_WEIGHT`` (groups with none are
    kept, empty, so that the groups survive a round trip)."""
    W = weights.W.tocsc()
    out = {}
    for j, group in enumerate(weights.groups):
        rows = W.indices[W.indptr[j]:W.indptr[j + 1]]
        vals = W.data[W.indptr[j]:W.indptr[j + 1]]
        keep = vals >= SMALLEST_WEIGHT
        order = np.argsort(rows[keep], kind="stable")
        out[group] = [[int(v), round(float(w), digits)] for v, w in zip(rows[keep][order], vals[keep][order])]
    return out


def write_weights(path, weights: SkinWeights, inputs=(), note=None):
    """Write weights as JSON, whole or not at all (the shared ``rig/weights.json`` layout)."""
    data = {"name": weights.name, "note": note or "vertex indices of the mesh (0-based); weights sum to 1",
            "weights": weights_to_dict(weights)}
    write_json_atomic(path, data, indent=None, inputs=inputs, what="weights")


def pose_transforms(skeleton: Skeleton, heads, rotations, root_position=None):
    """Each bone's skinning transform for local rotations relative to rest frames aligned with the world.

    A bone's global rotation is its parent's times its own; its head moves with its parent's transform:
    ``G_b = G_parent R_b``, ``p_b = p_parent + G_parent (h_b - h_parent)`` (a root's head stays, or goes to
    ``root_position``). The bone then moves a point ``x`` to ``G_b (x - h_b) + p_b``.

    Parameters
    ----------
    skeleton : Skeleton
    heads : (b,3) float
        Rest heads on the body (``Skeleton.rest``).
    rotations : (b,3,3) float
        Each bone's rotation relative to its parent, in the body's axes.
    root_position : (3,) float, optional
        Where the roots' heads go.

    Returns
    -------
    T : (b,3,4) float64
        ``[A | t]``: the bone moves ``x`` to ``A x + t``.
    """
    heads = np.asarray(heads, dtype=np.float64)
    R = np.asarray(rotations, dtype=np.float64)
    if R.shape != (skeleton.n_bones, 3, 3) or heads.shape != (skeleton.n_bones, 3):
        raise ValueError(f"rotations must be ({skeleton.n_bones},3,3) and heads ({skeleton.n_bones},3), "
                         f"got {R.shape} and {heads.shape}")
    G = np.empty_like(R)
    p = np.empty_like(heads)
    for b, parent in enumerate(skeleton.parents):
        if parent < 0:
            G[b] = R[b]
            p[b] = heads[b] if root_position is None else root_position
        else:
            G[b] = G[parent] @ R[b]
            p[b] = p[parent] + G[parent] @ (heads[b] - heads[parent])
    t = p - np.einsum("bij,bj->bi", G, heads)
    return np.concatenate([G, t[:, :, None]], axis=2)


def group_transforms(weights: SkinWeights, skeleton: Skeleton, T):
    """Each weight group's transform: its bone's, the identity for a group that is no bone (it does not
    move the vertex, as Blender's Armature modifier ignores it).

    Returns
    -------
    (g,3,4) float64
    """
    out = np.tile(np.hstack([np.eye(3), np.zeros((3, 1))]), (len(weights.groups), 1, 1))
    index = {name: i for i, name in enumerate(skeleton.names)}
    for j, group in enumerate(weights.groups):
        if group in index:
            out[j] = T[index[group]]
    return out


def deforming(weights: SkinWeights, skeleton: Skeleton) -> SkinWeights:
    """Only the groups that are bones of the skeleton (the ones that move a vertex)."""
    bones = set(skeleton.names)
    return weights.subset([g for g in weights.groups if g in bones])


def skin(V, weights: SkinWeights, group_T):
    """Linear blend skinning with the weights normalised.

    Parameters
    ----------
    V : (n,3) float
        Rest positions.
    weights : SkinWeights
        (n, g); normalised here (a vertex with no weight stays put).
    group_T : (g,3,4) float
        Each group's transform (``group_transforms``).

    Returns
    -------
    (n,3) float64
    """
    V = np.asarray(V, dtype=np.float64)
    if V.shape[0] != weights.n_vertices:
        raise RigError(weights.name, f"has weights for {weights.n_vertices} vertices; the mesh has {V.shape[0]}")
    W = weights.normalised().W
    blended = (W @ np.asarray(group_T, dtype=np.float64).reshape(-1, 12)).reshape(-1, 3, 4)
    out = np.einsum("nij,nj->ni", blended[:, :, :3], V) + blended[:, :, 3]
    unweighted = weights.sums() <= 0
    out[unweighted] = V[unweighted]
    return out
