"""A learned placement: where a garment hangs relative to where the body carries it.

The binding (``binding.py``) carries each garment vertex to the target body with the body triangle it
is bound to: the anchors of the Poisson solve. A simulated garment differs from that by a
long-wavelength offset: a loose skirt drops and flares on wider hips, a tight top rides up. This module
represents that offset per source body triangle ``a`` as a 3-vector ``C[a]`` in the triangle's own
orthonormal frame (rows ``t1`` along its first edge, ``t2``, ``n`` its normal; ``garment_model``'s
frames) on the target body, so that it turns with the body under it, and moves the anchors by it::

    anchor_i = carry(binding_i, target) + T[a_i]^T C[a_i]        a_i: the triangle vertex i is bound to

The field is smoothed over the body (``smooth_on_body``): it only says where the garment lies, not
its folds, which stay the field's.

``PlacementModel`` predicts ``C`` for a new garment and target with the same per-triangle network and
inputs as ``garment_model.GarmentFitModel`` (garment features, target features, label weights) and the
garment's context around each triangle (``garment_context``). Its three outputs are the offset in the
*unrotated* frame, ``y = S[a]^T T[a] d`` (S, T: the triangle's frames on the source and target bodies),
in which neighbouring triangles agree, so that it can be learned and smoothed; ``C = S y``. File:
``.npz`` of plain arrays plus JSON metadata of format ``garment_transfer.garment_placement_model``, read
with ``allow_pickle=False``. ``PlacementEnsemble`` averages several such models trained with other seeds
(``garment_training.train_placement_ensemble``); ``model_files`` stores them in one file.
"""

from __future__ import annotations

import logging
import os
import threading
from collections import OrderedDict

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..errors import ModelError
from ..geometry.binding import Binding, carry
from ..geometry.embedding import body_scale, triangle_centroids
from ..geometry.gradients import orthonormal_frames
from ..geometry.mesh import Mesh, require_same_topology, triangle_normals
from .garment_model import (
    GARMENT_FEATURES,
    GarmentFitModel,
    garment_features,
    label_weights_cached,
    read_model_npz,
    recall_by_content,
    with_neighbourhood_means,
)

log = logging.getLogger(__name__)

FORMAT = "garment_transfer.garment_placement_model"
#: Version 1: the network predicts the offset itself; version 2 (a model with ``offset_base``): the
#: offset less the training garments' mean offset on each triangle (``mean_offsets``). Both are read.
FORMAT_VERSION = 1
BASE_FORMAT_VERSION = 2
FORMAT_VERSIONS = (FORMAT_VERSION, BASE_FORMAT_VERSION)
#: Length over which the placement is smoothed on the body, as a share of the body scale (about 2 cm on
#: a 1.7 m body). Measured on the demo's test garments on pear (``lab.garment_model
#: --placement-smoothing``), garment model with the learned placement: 0.08 gives 0.78x direct's vertex
#: error and drape 0.505, 0.04 0.68x and 0.432, 0.02 0.62x and 0.393, 0.01 0.59x and 0.398, at the same
#: MDC (1.28-1.31x direct's); shorter placements are no noisier on the cloth, since the anchors are weak
#: and only decide features longer than the stiffness length.
SMOOTHING_SHARE = 0.01
#: The garment's surroundings seen from each body triangle: its coverage, distance and normal offset
#: (``garment_model.GARMENT_FEATURES[:3]``) smoothed over the body at these lengths (shares of the
#: body scale: about 8 cm, 23 cm, 57 cm). A triangle's own distance does not tell a loose skirt's
#: waist from a tight one's; the skirt's looseness around it does (measured: the placement's error on
#: the demo's test garments 9.3 -> 6.7 mm RMS with them).
CONTEXT_SHARES = (0.04, 0.12, 0.3)
CONTEXT_COLUMNS = 3
#: Neighbourhoods (shares of the body scale, as ``garment_model.NEIGHBOURHOOD_SHARES``) of the target's
#: offset from the source body (``body_offset_features``), an optional input of the placement model.
BODY_OFFSET_SHARES = (0.035, 0.11)


def bound_counts(binding: Binding, n_triangles):
    """(M,) float64: how many bound points each body triangle carries."""
    return np.bincount(binding.triangle, minlength=n_triangles).astype(np.float64)


def triangle_laplacian(F, n_triangles=None):
    """(M,M) csr graph Laplacian of the triangles sharing an edge."""
    F = np.asarray(F, dtype=np.int64)
    M = F.shape[0] if n_triangles is None else n_triangles
    e = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    e.sort(axis=1)
    owner = np.tile(np.arange(F.shape[0]), 3)
    key = e[:, 0] * (int(e.max()) + 1) + e[:, 1]
    order = np.argsort(key, kind="stable")
    key, owner = key[order], owner[order]
    same = key[1:] == key[:-1]
    i, j = owner[1:][same], owner[:-1][same]
    A = sp.coo_matrix((np.ones(2 * len(i)), (np.concatenate([i, j]), np.concatenate([j, i]))), shape=(M, M)).tocsr()
    A.data[:] = 1.0
    return (sp.diags(np.asarray(A.sum(axis=1)).ravel()) - A).tocsr()


def smooth_on_body(values, weights, body_V, body_F, length):
    """Weighted low-pass of a per-triangle field over the body: ``(W + t L) X = W values``.

    Triangles with weight 0 take the values diffused from their neighbours; features shorter than about
    ``length`` go (``t = (length / h)^2``, h the mean distance between adjacent triangles' centroids).

    Parameters
    ----------
    values : (M,c) float
    weights : (M,) float
        >= 0; the data's confidence per triangle (bound points).
    body_V : (nb,3) float
    body_F : (M,3) int
    length : float

    Returns
    -------
    X : (M,c) float64
    """
    values = np.asarray(values, dtype=np.float64)
    w = np.asarray(weights, dtype=np.float64)
    M = body_F.shape[0]
    if values.shape[0] != M or w.shape != (M,):
        raise ValueError(f"values and weights must have {M} rows, got {values.shape} and {w.shape}")
    if length <= 0:
        return values.copy()
    positive = w[w > 0]
    if positive.size == 0:
        return np.zeros_like(values)
    w = w / positive.mean()
    L = triangle_laplacian(body_F, M)
    c = triangle_centroids(body_V, body_F)
    rows, cols = L.nonzero()
    off = rows != cols
    h = float(np.mean(np.linalg.norm(c[rows[off]] - c[cols[off]], axis=1)))
    t = (length / max(h, 1e-300)) ** 2
    # A faint pull to zero keeps triangles cut off from every bound point defined.
    K = (sp.diags(w + 1e-9) + t * L).tocsc()
    return spla.splu(K, permc_spec="COLAMD").solve(w[:, None] * values)


def garment_context(body_V, body_F, garment_X, shares=CONTEXT_SHARES):
    """The garment's coverage, distance and normal offset smoothed over the body at several lengths.

    Parameters
    ----------
    body_V : (nb,3) float
        The source body.
    body_F : (M,3) int
    garment_X : (M,12) float
        ``garment_model.garment_features`` of the garment on that body.
    shares : sequence of float
        Smoothing lengths as shares of the body scale.

    Returns
    -------
    (M, 3 * len(shares)) float64
    """
    return garment_contexts(body_V, body_F, [garment_X], shares)[0]


def garment_contexts(body_V, body_F, garment_Xs, shares=CONTEXT_SHARES):
    """``garment_context`` of several garments on one body: the smoothing's matrix depends on the body and
    the length alone, so each length is factored once for them all.

    Parameters
    ----------
    body_V : (nb,3) float
    body_F : (M,3) int
    garment_Xs : sequence of (M,12) float
    shares : sequence of float

    Returns
    -------
    list of (M, 3 * len(shares)) float64
    """
    V = np.asarray(body_V, dtype=np.float64)
    Xs = [np.asarray(X, dtype=np.float64)[:, :CONTEXT_COLUMNS] for X in garment_Xs]
    if not shares or not Xs:
        return [np.zeros((X.shape[0], 0)) for X in Xs]
    area = triangle_normals(V, body_F)[1]
    scale = body_scale(V)
    stacked = np.concatenate(Xs, axis=1)
    smoothed = [smooth_on_body(stacked, area, V, body_F, s * scale) for s in shares]
    c = CONTEXT_COLUMNS
    return [np.concatenate([S[:, g * c:(g + 1) * c] for S in smoothed], axis=1) for g in range(len(Xs))]


#: The last few garments' contexts, by content: the placement networks and the nearest garments' placement of
#: one transfer need the same one (about 0.19 s on a 26,756-triangle MakeHuman body, three smoothings), and a
#: body that is not a training target needs it again for every training body its placement is blended from
#: (``BlendedPlacement``). About 2 MB each on that body.
_CONTEXT_CACHE = OrderedDict()
_CONTEXT_CACHE_SIZE = 8
_CONTEXT_CACHE_LOCK = threading.Lock()


def garment_context_cached(body_V, body_F, garment_X, shares):
    """``garment_context``, kept for the last few garments; the array returned is read-only."""
    arrays = [np.asarray(body_V, dtype=np.float64), np.asarray(body_F, dtype=np.int64),
              np.asarray(garment_X, dtype=np.float64)[:, :CONTEXT_COLUMNS]]
    return recall_by_content(_CONTEXT_CACHE, _CONTEXT_CACHE_LOCK, _CONTEXT_CACHE_SIZE, arrays,
                             tuple(float(x) for x in shares),
                             lambda: (garment_context(body_V, body_F, garment_X, shares),))[0]


def body_offset_features(source_V, target_V, F, shares=BODY_OFFSET_SHARES):
    """Where the target body lies from the source body around each triangle, in the triangle's frame.

    The label tells the training bodies apart; this exists for any body and changes continuously with
    its shape, so a body between two training bodies gets values between theirs. Per triangle: the
    displacement of its centroid from the source to the target body, less the bodies' mean displacement,
    in the source triangle's frame (``t1``, ``t2``, normal: the last is how far the body grew outward
    there), over the body scale; then its area-weighted mean over each neighbourhood.

    Parameters
    ----------
    source_V, target_V : (nb,3) float
        The body in its source and target shapes (same topology).
    F : (M,3) int
    shares : sequence of float
        Neighbourhood radii as shares of the source body scale.

    Returns
    -------
    (M, 3 * (1 + len(shares))) float64
    """

    S_V = np.asarray(source_V, dtype=np.float64)
    T_V = np.asarray(target_V, dtype=np.float64)
    if S_V.shape != T_V.shape:
        raise ValueError(f"the source and target bodies differ in shape: {S_V.shape} and {T_V.shape}")
    cs, ct = triangle_centroids(S_V, F), triangle_centroids(T_V, F)
    area = triangle_normals(S_V, F)[1]
    d = ct - cs
    d -= (area[:, None] * d).sum(axis=0) / max(area.sum(), 1e-300)
    scale = body_scale(S_V)
    local = np.einsum("mij,mj->mi", orthonormal_frames(S_V, F), d) / scale
    return with_neighbourhood_means(local, cs, area, scale, shares)


def unrotate(source_V, target_V, F):
    """(M,3,3) per triangle ``S^T T``: a vector on the target body in the source body's orientation."""
    S = orthonormal_frames(source_V, F)
    T = orthonormal_frames(target_V, F)
    return np.einsum("mji,mjk->mik", S, T)


def true_offsets(binding: Binding, source_body: Mesh, target_body: Mesh, garment_on_target, length=None):
    """The placement of a garment whose shape on the target body is known (the simulation): its offset
    from where the body carries it, smoothed, per body triangle in the triangle's frame on the target.

    Parameters
    ----------
    binding : Binding
        The garment bound to the source body.
    source_body, target_body : Mesh
    garment_on_target : (n,3) float
        The garment on the target body (same vertex order as the bound garment).
    length : float, optional
        Smoothing length (default ``SMOOTHING_SHARE`` of the source body scale); 0: none.

    Returns
    -------
    C : (M,3) float64
        Per body triangle: the offset in the target triangle's frame (``placement_displacements``).
    y : (M,3) float64
        The same in each triangle's unrotated frame (``C = S y``), as ``PlacementModel`` predicts it.
    weights : (M,) float64
        Bound garment vertices per triangle.
    """
    require_same_topology(source_body, target_body)
    F = source_body.F
    M = F.shape[0]
    d = np.asarray(garment_on_target, dtype=np.float64) - carry(binding, target_body.V, F)
    Rst = unrotate(source_body.V, target_body.V, F)
    per_vertex = np.einsum("pij,pj->pi", Rst[binding.triangle], d)
    w = bound_counts(binding, M)
    y = np.zeros((M, 3))
    for c in range(3):
        y[:, c] = np.bincount(binding.triangle, weights=per_vertex[:, c], minlength=M)
    y /= np.maximum(w, 1.0)[:, None]
    length = SMOOTHING_SHARE * body_scale(source_body.V) if length is None else float(length)
    y = smooth_on_body(y, w, source_body.V, F, length)
    S = orthonormal_frames(source_body.V, F)
    return np.einsum("mij,mj->mi", S, y), y, w


def placement_displacements(binding: Binding, target_V, body_F, C):
    """How far each bound point's anchor moves: ``T[a_i]^T C[a_i]`` on the target body.

    Parameters
    ----------
    binding : Binding
    target_V : (nb,3) float
        The target body.
    body_F : (M,3) int
    C : (M,3) float
        Per body triangle, the offset in that triangle's frame on the target body.

    Returns
    -------
    D : (p,3) float64
    """
    C = np.asarray(C, dtype=np.float64)
    if C.shape != (body_F.shape[0], 3):
        raise ValueError(f"the placement must be ({body_F.shape[0]}, 3): one offset per body triangle, "
                         f"got {C.shape}")
    if not np.isfinite(C).all():
        raise ValueError("the placement has values that are not finite")
    tri = binding.triangle
    T = orthonormal_frames(target_V, body_F)[tri]
    return np.einsum("pji,pj->pi", T, C[tri])


def mean_offsets(offset, bound):
    """The training garments' mean placement per target and body triangle, weighted by bound points.

    Parameters
    ----------
    offset : (G,K,M,3) float
        Every training garment's unrotated smoothed offsets on every target (``true_offsets``' ``y``).
    bound : (G,M) float
        Bound garment points per triangle (``bound_counts``).

    Returns
    -------
    (K,M,3) float64
        Zero on triangles no training garment is bound to.
    """
    offset = np.asarray(offset, dtype=np.float64)
    w = np.asarray(bound, dtype=np.float64)
    if offset.ndim != 4 or offset.shape[3] != 3 or w.shape != (offset.shape[0], offset.shape[2]):
        raise ValueError(f"offsets (G,K,M,3) and bound counts (G,M) do not fit: {offset.shape} and {w.shape}")
    total = np.einsum("gm,gkmc->kmc", w, offset)
    return total / np.maximum(w.sum(axis=0), 1e-12)[None, :, None]


class PlacementModel(GarmentFitModel):
    """A trained placement model (see the module docstring): ``GarmentFitModel``'s inputs, 3 outputs.

    Extra metadata: ``smoothing_share`` (the smoothing of its targets and predictions),
    ``context_shares`` (``garment_context``, inputs after the garment's own features) and, optionally,
    ``body_offset_shares`` (``body_offset_features``, inputs after the target's features; absent: none).
    A model of format version 2 has the array ``offset_base (K,M,3)``: the training garments' mean offset
    per target and triangle (``mean_offsets``); its network predicts the offset less that, blended by the
    label weights.
    """

    OUTPUTS = 3

    def _check(self, a, md):
        super()._check(a, md)
        has = "offset_base" in a
        if md.get("format_version", FORMAT_VERSION) == BASE_FORMAT_VERSION:
            M = int(md["source"]["n_triangles"])
            base = a.get("offset_base")
            if base is None or base.dtype.kind != "f" or base.shape != (len(md["targets"]), M, 3):
                raise ModelError(self.name, f"a placement model of format version {BASE_FORMAT_VERSION} needs the "
                                            f"array 'offset_base' of shape ({len(md['targets'])}, {M}, 3), got "
                                            f"{None if base is None else base.shape}")
            if not np.isfinite(base).all():
                raise ModelError(self.name, "'offset_base' has values that are not finite")
        elif has:
            raise ModelError(self.name, f"has 'offset_base', which format version {md.get('format_version')} "
                                        "does not have")

    def offset_base(self, weights):
        """(M,3) float64: the training garments' mean unrotated offset under label ``weights (K,)``
        (zero for a model of format version 1)."""
        base = self.arrays.get("offset_base")
        if base is None:
            return np.zeros((int(self.metadata["source"]["n_triangles"]), 3))
        return np.einsum("k,kmc->mc", np.asarray(weights, dtype=np.float64), base.astype(np.float64))

    @staticmethod
    def n_inputs(md):
        offset = md.get("body_offset_shares")
        return (GarmentFitModel.n_inputs(md) + CONTEXT_COLUMNS * len(md.get("context_shares", []))
                + (0 if offset is None else 3 * (1 + len(offset))))

    def inputs(self, source_body: Mesh, target_body: Mesh, garment: Mesh, target=None, rows=None,
               covered_only=False):
        """``GarmentFitModel.inputs`` with the garment's context after its own features (and the target's
        offset from the source body after the target's features)."""
        X, covered, dev = super().inputs(source_body, target_body, garment, target, rows, covered_only)
        n = len(GARMENT_FEATURES)
        ctx = garment_context_cached(source_body.V, source_body.F, X[:, :n],
                                      tuple(self.metadata.get("context_shares", [])))
        parts = [X[:, :n], ctx]
        offset = self.metadata.get("body_offset_shares")
        if offset is None:
            parts.append(X[:, n:])
        else:
            t_end = n + 9 * (1 + len(self.metadata["neighbourhood_shares"]))
            parts += [X[:, n:t_end], body_offset_features(source_body.V, target_body.V, source_body.F,
                                                          tuple(offset)), X[:, t_end:]]
        return np.concatenate(parts, axis=1), covered, dev

    def body_field(self, *args, **kwargs):
        raise ModelError(self.name, "is a placement model, not a field model: pass it as placement=")

    def frame_offsets(self, binding: Binding, source_body: Mesh, target_body: Mesh, garment: Mesh, target=None):
        """The predicted placement of ``garment`` on ``target_body``.

        Parameters
        ----------
        binding : Binding
            ``garment`` bound to ``source_body``.
        source_body, target_body : Mesh
        garment : Mesh
            Dressed on the source body.
        target : str, optional
            A training target's label; None (or an unknown name): label weights from the body's shape.

        Returns
        -------
        C : (M,3) float64
            Per body triangle, the offset in the triangle's frame on the target body.
        """
        self.check_source_body(source_body)
        y = self.unrotated_offsets(binding, source_body, target_body, garment, target)
        return np.einsum("mij,mj->mi", orthonormal_frames(source_body.V, source_body.F), y)

    def unrotated_offsets(self, binding: Binding, source_body: Mesh, target_body: Mesh, garment: Mesh, target=None):
        """The predicted placement in each triangle's unrotated frame (``y``; ``C = S y``), smoothed.

        Returns
        -------
        y : (M,3) float64
        """
        return _mean_unrotated_offsets([self], binding, source_body, target_body, garment, target)

    def raw_offsets(self, X):
        """The network's unrotated offsets for inputs ``X (n,P)``, before smoothing (without the
        ``offset_base`` of a version 2 model): ``(n,3)`` float64."""
        return self.forward(X) * np.asarray(self.metadata["output_scale"], dtype=np.float64)


#: Metadata that decide a placement model's inputs and smoothing: the members of a ``PlacementEnsemble``
#: must agree on them.
ENSEMBLE_SHARED_METADATA = ("targets", "source", "use_label", "garment_inputs", "garment_features",
                            "neighbourhood_shares", "cover_distance", "context_shares", "body_offset_shares",
                            "smoothing_share")


class PlacementEnsemble:
    """Several placement models trained alike (other seeds): the prediction is the mean of theirs.

    Each member predicts the unrotated offset ``y`` of the bound triangles from the same inputs; the mean
    is smoothed once (the smoothing is linear: the same as the mean of the members' smoothed offsets).
    Used where a ``PlacementModel`` is: ``transfer_garment``'s ``placement``, ``BlendedPlacement``.

    Parameters
    ----------
    members : sequence of PlacementModel
        At least one; the same targets, source body, inputs and smoothing (``ENSEMBLE_SHARED_METADATA``)
        and the same label bodies.
    name : str, optional
        For messages (default the first member's).

    Raises
    ------
    ModelError
        Naming the member that differs from the first.
    """

    def __init__(self, members, name=None):
        members = list(members)
        if not members:
            raise ValueError("a placement ensemble needs at least one member")
        first = members[0]
        for m in members:
            if not isinstance(m, PlacementModel):
                raise TypeError(f"a placement ensemble's members must be PlacementModel, got {type(m).__name__}")
        for i, m in enumerate(members[1:], 1):
            which = f"placement member {i} differs from member 0" + ("" if m.name == first.name else
                                                                       f" ({first.name})")
            for key in ENSEMBLE_SHARED_METADATA:
                if m.metadata.get(key) != first.metadata.get(key):
                    raise ModelError(m.name, f"{which} in {key!r}: {m.metadata.get(key)!r} against "
                                             f"{first.metadata.get(key)!r}; an ensemble's members must share it")
            if not np.array_equal(m.arrays["label_bodies"], first.arrays["label_bodies"]):
                raise ModelError(m.name, f"{which} in its label bodies")
        self.members = members
        self.name = first.name if name is None else name

    @property
    def metadata(self):
        return self.members[0].metadata

    @property
    def arrays(self):
        return self.members[0].arrays

    @property
    def targets(self) -> list:
        return self.members[0].targets

    def check_source_body(self, mesh):
        self.members[0].check_source_body(mesh)

    def label_weights_for(self, target_body: Mesh, target=None):
        return self.members[0].label_weights_for(target_body, target)

    # The same as a single model's, through this ensemble's own unrotated offsets.
    frame_offsets = PlacementModel.frame_offsets

    def unrotated_offsets(self, binding: Binding, source_body: Mesh, target_body: Mesh, garment: Mesh, target=None):
        """``PlacementModel.unrotated_offsets`` of the mean of the members: (M,3) float64."""
        return _mean_unrotated_offsets(self.members, binding, source_body, target_body, garment, target)


def _mean_unrotated_offsets(models, binding: Binding, source_body: Mesh, target_body: Mesh, garment: Mesh,
                            target=None):
    """The mean of ``models``' unrotated offsets of the bound triangles (each with its ``offset_base`` under
    the target's label weights), smoothed once (with the first's smoothing; the inputs are the first's,
    which every member shares): (M,3) float64."""
    first = models[0]
    F = source_body.F
    M = F.shape[0]
    w = bound_counts(binding, M)
    sel = w > 0
    X = first.inputs(source_body, target_body, garment, target, rows=sel)[0][sel]
    y = np.zeros((M, 3))
    if any("offset_base" in m.arrays for m in models):
        weights = first.label_weights_for(target_body, target)
        y[sel] = sum(m.raw_offsets(X) + m.offset_base(weights)[sel] for m in models) / len(models)
    else:
        y[sel] = sum(m.raw_offsets(X) for m in models) / len(models)
    length = float(first.metadata["smoothing_share"]) * body_scale(source_body.V)
    return smooth_on_body(y, w, source_body.V, F, length)


class BlendedPlacement:
    """A placement model that gives a body it was not trained on the blend of what it predicts on the
    training bodies, weighted by the body's label weights (``garment_model.label_weights``: the convex
    combination of training bodies closest to its shape).

    The network sees every training body with its own label and features only; a new body's mixed label
    and features are inputs it never saw. The blend stays between the placements it learned. A training
    body (by label, or by a shape its label weights give wholly to one training body) gets the model's own
    prediction.

    Parameters
    ----------
    model : PlacementModel or PlacementEnsemble
    """

    def __init__(self, model):
        self.model = model
        self.name = model.name

    def frame_offsets(self, binding: Binding, source_body: Mesh, target_body: Mesh, garment: Mesh, target=None):
        """``PlacementModel.frame_offsets``; for a body that is not a training target, the blend."""
        model = self.model
        if target is not None and target in model.targets:
            return model.frame_offsets(binding, source_body, target_body, garment, target)
        model.check_source_body(source_body)
        require_same_topology(source_body, target_body)
        weights = label_weights_cached(target_body.V, model.arrays["label_bodies"])
        if weights.max() >= 1.0 - 1e-6:
            # A training body by its shape (the stored bodies are float32: within 1e-6 of one-hot): the
            # network's own prediction on it.
            label = model.targets[int(np.argmax(weights))]
            return model.frame_offsets(binding, source_body, target_body, garment, label)
        y = np.zeros((source_body.F.shape[0], 3))
        for k, wk in enumerate(weights):
            if wk > 1e-6:
                body = source_body.with_vertices(np.asarray(model.arrays["label_bodies"][k], dtype=np.float64))
                y += wk * model.unrotated_offsets(binding, source_body, body, garment, model.targets[k])
        return np.einsum("mij,mj->mi", orthonormal_frames(source_body.V, source_body.F), y)


#: Format of the nearest garments' placement (``NearestGarments``), a part of a model bundle.
LIBRARY_FORMAT = "garment_transfer.nearest_garments_placement"
LIBRARY_FORMAT_VERSION = 1
#: How alike two garments are around a body triangle: the distance between their ``similarity_features``
#: there, each feature over its spread in the training garments; a training garment weighs
#: ``exp(-d^2 / (2 w^2))`` times its bound points, ``w`` this width. Chosen among 0.5, 1 and 2 on held-out
#: training garments (the demo's validation fold, pear, half the field and the mixed placement): drape error
#: 0.403, 0.411 and 0.420 (lab/notes/garment-model-study.md, "The nearest garments' placement").
SIMILARITY_WIDTH = 0.5
#: The nearest garments' share in a ``MixedPlacement`` of them and the placement networks
#: (lab/notes/garment-model-study.md, "The nearest garments' placement").
LIBRARY_SHARE = 0.5
#: Array names and dtypes of a ``NearestGarments``.
LIBRARY_ARRAYS = {"triangles": "i", "garment": "i", "features": "f", "offsets": "f", "weights": "f",
                  "feature_scale": "f", "label_bodies": "f"}


def similarity_features(garment_X, context):
    """What two garments are compared by around each body triangle: the garment's context (``garment_context``:
    coverage, distance and normal offset at every smoothing length) and the triangle's own distance and
    normal offset (``garment_model.GARMENT_FEATURES`` 1 and 2).

    Parameters
    ----------
    garment_X : (M,12) float
    context : (M,3c) float

    Returns
    -------
    (M, 3c + 2) float64
    """
    return np.concatenate([np.asarray(context, dtype=np.float64),
                           np.asarray(garment_X, dtype=np.float64)[:, 1:3]], axis=1)


class NearestGarments:
    """The placement of the training garments most like a garment, triangle by triangle.

    No network: the model keeps every training garment's placement (``true_offsets``' ``y``, per target)
    and its ``similarity_features`` on the body triangles it is bound to. A new garment's placement on a
    triangle is the mean of the training garments' there, each weighted by its bound points and by how
    alike the two garments are around that triangle (``SIMILARITY_WIDTH``); zero where no training garment
    lies. A body given by its shape gets the blend of the training targets' by its label weights (as
    ``BlendedPlacement``). The prediction is smoothed like the networks' (``smoothing_share``).

    Parameters
    ----------
    arrays : dict of str -> ndarray
        ``triangles (N,)`` int: the body triangle of each entry; ``garment (N,)`` int: its training garment;
        ``features (N,F)``; ``offsets (K,N,3)``: the garment's unrotated offset there on each target;
        ``weights (N,)``: its bound points; ``feature_scale (F,)``; ``label_bodies (K,nb,3)``.
    metadata : dict
        ``format``, ``format_version``, ``targets``, ``source`` (``n_vertices``, ``n_faces``,
        ``n_triangles``, ``faces_hash``), ``cover_distance``, ``context_shares``, ``smoothing_share``,
        ``similarity_width``, ``garments`` (the training garments' names).
    name : str
    """

    def __init__(self, arrays, metadata, name="nearest garments placement"):
        self.arrays = dict(arrays)
        self.metadata = metadata
        self.name = name
        self._check()

    def _check(self):
        a, md = self.arrays, self.metadata

        def need(cond, problem):
            if not cond:
                raise ModelError(self.name, f"its nearest garments' placement {problem}")

        missing = [k for k in LIBRARY_ARRAYS if k not in a]
        need(not missing, f"lacks the arrays {', '.join(missing)}")
        strays = sorted(set(a) - set(LIBRARY_ARRAYS))
        need(not strays, f"has arrays it does not use: {', '.join(strays)}")
        for k, kind in LIBRARY_ARRAYS.items():
            need(a[k].dtype.kind == kind or (kind == "i" and a[k].dtype.kind == "u"),
                 f"has {k!r} of dtype {a[k].dtype}")
        K, M = len(md["targets"]), int(md["source"]["n_triangles"])
        N = a["triangles"].shape[0] if a["triangles"].ndim == 1 else -1
        F = a["feature_scale"].shape[0] if a["feature_scale"].ndim == 1 else -1
        n_context = CONTEXT_COLUMNS * len(md["context_shares"])
        need(N >= 1, f"has no entries (triangles {a['triangles'].shape})")
        need(F == n_context + 2, f"has {F} features; its context shares give {n_context + 2}")
        shapes = {"garment": (N,), "features": (N, F), "offsets": (K, N, 3), "weights": (N,),
                  "label_bodies": (K, int(md["source"]["n_vertices"]), 3)}
        for k, shape in shapes.items():
            need(a[k].shape == shape, f"has {k!r} of shape {a[k].shape}, not {shape}")
        need(0 <= a["triangles"].min() and a["triangles"].max() < M,
             f"has triangle indices outside 0..{M - 1}")
        need(0 <= a["garment"].min() and a["garment"].max() < len(md["garments"]),
             "has garment indices outside its garments")
        for k in ("features", "offsets", "weights", "feature_scale", "label_bodies"):
            need(np.isfinite(a[k]).all(), f"has values in {k!r} that are not finite")
        need((a["weights"] > 0).all() and (a["feature_scale"] > 0).all(),
             "has weights or feature scales that are not positive")
        need(float(md["similarity_width"]) > 0 and float(md["smoothing_share"]) >= 0,
             "has a similarity width or smoothing that is not positive")

    @property
    def targets(self) -> list:
        return list(self.metadata["targets"])

    check_source_body = GarmentFitModel.check_source_body
    label_weights_for = GarmentFitModel.label_weights_for

    def similarity_features(self, source_body: Mesh, garment: Mesh):
        """The garment's ``similarity_features`` on every body triangle: (M,F) float64."""

        X = garment_features(source_body.V, source_body.F, garment.V, garment.F, self.metadata.get("cover_distance"))[0]
        context = garment_context_cached(source_body.V, source_body.F, X, tuple(self.metadata["context_shares"]))
        return similarity_features(X, context)

    def raw_offsets(self, bound, features, weights):
        """The weighted mean of the training garments' unrotated offsets on the triangles with ``bound > 0``,
        before smoothing.

        Parameters
        ----------
        bound : (M,) float
            The new garment's bound points per triangle.
        features : (M,F) float
            Its ``similarity_features``.
        weights : (K,) float
            Label weights over the training targets.

        Returns
        -------
        (M,3) float64
            Zero where the garment is not bound or no training garment lies.
        """
        a = self.arrays
        M = bound.shape[0]
        scale = a["feature_scale"].astype(np.float64)
        keep = bound[a["triangles"]] > 0
        t = a["triangles"][keep].astype(np.int64)
        d2 = (((a["features"][keep].astype(np.float64) - features[t]) / scale) ** 2).sum(axis=1)
        # Each triangle's weights relative to its most alike entry: the same mean, and nothing underflows.
        nearest = np.full(M, np.inf)
        np.minimum.at(nearest, t, d2)
        width = float(self.metadata["similarity_width"])
        w = a["weights"][keep].astype(np.float64) * np.exp(-(d2 - nearest[t]) / (2.0 * width ** 2))
        off = np.einsum("k,knc->nc", np.asarray(weights, dtype=np.float64), a["offsets"][:, keep].astype(np.float64))
        den = np.bincount(t, weights=w, minlength=M)
        y = np.zeros((M, 3))
        has = den > 0
        for c in range(3):
            y[has, c] = np.bincount(t, weights=w * off[:, c], minlength=M)[has] / den[has]
        return y

    def unrotated_offsets(self, binding: Binding, source_body: Mesh, target_body: Mesh, garment: Mesh, target=None):
        """``PlacementModel.unrotated_offsets``: (M,3) float64, smoothed."""
        self.check_source_body(source_body)
        require_same_topology(source_body, target_body)
        F = source_body.F
        w = bound_counts(binding, F.shape[0])
        y = self.raw_offsets(w, self.similarity_features(source_body, garment),
                             self.label_weights_for(target_body, target))
        length = float(self.metadata["smoothing_share"]) * body_scale(source_body.V)
        return smooth_on_body(y, w, source_body.V, F, length)

    frame_offsets = PlacementModel.frame_offsets


def shrink_gain(y, difference, share, shrink):
    """(M,) float64 in [0, 1]: the gain ``|y|^2 / (|y|^2 + c v)`` of a ``MixedPlacement`` shrunk where its two
    predictions disagree, on each triangle: ``y`` the mix, ``v = ((1-share)^2 + share^2) |difference|^2 / 2``
    its variance estimated from the two predictions' difference (two independent estimates of equal
    spread), ``c = shrink`` (1: a Wiener filter's gain); 1 where nothing is predicted (no 0/0)."""
    yy = np.einsum("mi,mi->m", y, y)
    v = 0.5 * ((1.0 - share) ** 2 + share ** 2) * np.einsum("mi,mi->m", difference, difference)
    den = yy + shrink * v
    return np.divide(yy, den, out=np.ones_like(yy), where=den > 0)


class MixedPlacement:
    """The placement networks' prediction and the nearest garments' (``NearestGarments``), mixed:
    ``(1 - share) y_networks + share y_nearest`` in each triangle's unrotated frame; optionally shrunk
    towards no offset where the two disagree (``shrink``, ``shrink_gain``; measured, not what ``train`` writes:
    lab/notes/garment-model-study.md, "Shrinking the placement where its two predictions disagree").

    Goes wherever a ``PlacementModel`` goes (``transfer_garment``'s ``placement``, ``BlendedPlacement``).

    Parameters
    ----------
    model : PlacementModel or PlacementEnsemble
    library : NearestGarments
        Of the same targets, source body and label bodies.
    share : float
        In [0, 1]: 0 the networks alone, 1 the nearest garments alone.
    shrink : float
        ``c >= 0`` of ``shrink_gain``; 0 (the default): the plain mix.
    """

    def __init__(self, model, library, share=LIBRARY_SHARE, shrink=0.0):
        share, shrink = float(share), float(shrink)
        if not 0.0 <= share <= 1.0:
            raise ValueError(f"the nearest garments' share must be between 0 and 1, got {share}")
        if not (np.isfinite(shrink) and shrink >= 0.0):
            raise ValueError(f"the disagreement shrink must be a number >= 0, got {shrink}")
        if list(library.targets) != list(model.targets):
            raise ModelError(library.name, f"the nearest garments' placement has the targets {library.targets}, "
                                           f"the placement networks {model.targets}")
        if library.metadata["source"].get("faces_hash") != model.metadata["source"].get("faces_hash"):
            raise ModelError(library.name, "the nearest garments' placement and the placement networks were made "
                                           "on different source bodies")
        if not np.array_equal(library.arrays["label_bodies"], model.arrays["label_bodies"]):
            raise ModelError(library.name, "the nearest garments' placement and the placement networks differ in "
                                           "their label bodies")
        self.model, self.library, self.share, self.shrink = model, library, share, shrink
        self.name = model.name

    @property
    def metadata(self):
        return self.model.metadata

    @property
    def arrays(self):
        return self.model.arrays

    @property
    def targets(self) -> list:
        return self.model.targets

    def check_source_body(self, mesh):
        self.model.check_source_body(mesh)

    def label_weights_for(self, target_body: Mesh, target=None):
        return self.model.label_weights_for(target_body, target)

    def unrotated_offsets(self, binding: Binding, source_body: Mesh, target_body: Mesh, garment: Mesh, target=None):
        """(M,3) float64: the mix of the two predictions (each smoothed), shrunk where they disagree."""
        s = self.share
        a = self.model.unrotated_offsets(binding, source_body, target_body, garment, target) \
            if s < 1.0 or self.shrink else None
        b = self.library.unrotated_offsets(binding, source_body, target_body, garment, target) \
            if s > 0.0 or self.shrink else None
        y = b if s == 1.0 else a if s == 0.0 else (1.0 - s) * a + s * b
        if self.shrink:
            y = y * shrink_gain(y, a - b, s, self.shrink)[:, None]
        return y

    frame_offsets = PlacementModel.frame_offsets


def anchor_offsets(placement, binding: Binding, source_body: Mesh, target_body: Mesh, garment: Mesh, target=None):
    """The anchors' displacements for ``transfer_garment``'s ``placement``.

    Parameters
    ----------
    placement : PlacementModel, PlacementEnsemble, NearestGarments, MixedPlacement, BlendedPlacement or (M,3) array
        A model, or the offsets per body triangle in its frame on the target (``true_offsets``).

    Returns
    -------
    D : (n,3) float64
    """
    if hasattr(placement, "frame_offsets"):
        C = placement.frame_offsets(binding, source_body, target_body, garment, target)
    else:
        C = placement
    return placement_displacements(binding, target_body.V, source_body.F, C)


def load_placement_model(path) -> PlacementModel:
    """Read a placement model file (plain arrays only, ``allow_pickle=False``).

    Raises
    ------
    ModelError
        Naming the file: missing, unreadable, pickled objects, another format or version, arrays that do
        not fit together.
    """
    arrays, metadata = read_model_npz(path, FORMAT, FORMAT_VERSIONS, "a garment placement model")
    if "smoothing_share" not in metadata:
        raise ModelError(os.fspath(path), "metadata lacks 'smoothing_share'")
    return PlacementModel(arrays, metadata, os.fspath(path))
