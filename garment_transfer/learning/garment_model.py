"""A garment-conditioned fit model: a new garment's own deformation field, predicted from what is
measurable on the source body alone.

The shared deformation model (``model.py``) gives every new garment the same field per target (the
decoder at the mean latent): a loose skirt and a tight one deform alike. This model predicts, per
source body triangle a, the deviation of the garment's embedded deformation gradient from the body's
own gradient there, from

- the garment near triangle a on the source body (``garment_features``): whether it covers a, how far
  the nearest garment triangle is (loose or tight), which way it lies and faces in a's own frame
  (hanging away, resting on), and where a is on the body;
- the target body (``target_features``): the body's own deformation gradient at a, and averaged over
  two neighbourhoods (a hanging skirt follows the hips above, not the thigh under it), and the
  target's label as weights over the training targets (one-hot for a training body; for any other
  body, the convex combination of training bodies closest to it, so a body between two training
  bodies gets weights between theirs).

One small multilayer perceptron is shared by every triangle, garment and target::

    x = [garment_features(a), target_features(a), label_weights]          (P,)
    y = W_n tanh(... tanh(W_1 ((x - mu) / sigma) + b_1) ...) + b_n        (9,)
    Q(a) = I + body_deviation(a) + y * scale                              on covered triangles
    Q(a) = I + body_deviation(a)                                          elsewhere

File format: ``.npz`` of plain numeric arrays (``W{i}``, ``b{i}``, ``input_mean``, ``input_std``,
``label_bodies (K,nb,3)``) and one JSON string ``metadata`` (format, version, source body counts and
faces hash, targets, feature names, neighbourhood radii, normalisation, training settings); read with
``allow_pickle=False`` only. Inference is numpy; training (``garment_training.py``) uses torch.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import threading
import zipfile
from collections import OrderedDict

import numpy as np
from scipy.spatial import cKDTree

from ..errors import ModelError
from ..geometry.embedding import body_scale, body_to_cloth, triangle_centroids
from ..geometry.gradients import deformation_gradients, orthonormal_frames
from ..geometry.mesh import Mesh, faces_hash, require_same_topology, triangle_normals
from .model import reads_version, save_npz_atomic, versions_text

log = logging.getLogger(__name__)

FORMAT = "garment_transfer.garment_fit_model"
FORMAT_VERSION = 1

GARMENT_FEATURES = ("covered", "distance", "normal_offset", "offset_t1", "offset_t2", "offset_n",
                    "facing_t1", "facing_t2", "facing_n", "x", "y", "z")
#: Radii of the neighbourhoods the body's deformation is averaged over, as shares of the body scale
#: (about 6 cm and 19 cm on a 1.7 m body).
NEIGHBOURHOOD_SHARES = (0.035, 0.11)
#: Triangles per block of ``neighbourhood_mean`` (128: 1.4 s for the larger neighbourhood of a MakeHuman
#: body; 512: 1.9 s).
NEIGHBOURHOOD_CHUNK = 128


def garment_features(body_V, body_F, garment_V, garment_F, cover_distance=None):
    """What the garment is like near every source body triangle (``GARMENT_FEATURES``).

    Parameters
    ----------
    body_V : (nb,3) float
        The source body.
    body_F : (M,3) int
    garment_V : (n,3) float
        The garment dressed on that body.
    garment_F : (T,3) int
    cover_distance : float, optional
        See ``embedding.body_to_cloth``.

    Returns
    -------
    X : (M,12) float64
        Per body triangle: covered (0/1); distance from the triangle's centroid to the nearest garment
        triangle's centroid and its component along the body normal (both over the body scale); the
        unit direction of that offset and the garment triangle's unit normal, in the body triangle's
        frame (t1, t2, n); the centroid's position relative to the body's centre (over the body scale).
        Uncovered triangles have zeros but for their position.
    covered : (M,) bool
    """
    body_V = np.asarray(body_V, dtype=np.float64)
    garment_V = np.asarray(garment_V, dtype=np.float64)
    scale = body_scale(body_V)
    index, covered = body_to_cloth(body_V, body_F, garment_V, garment_F, cover_distance)
    cb = triangle_centroids(body_V, body_F)
    cg = triangle_centroids(garment_V, garment_F)[index]
    R = orthonormal_frames(body_V, body_F)
    off = cg - cb
    dist = np.linalg.norm(off, axis=1)
    local = np.einsum("mij,mj->mi", R, off)
    direction = local / np.maximum(dist, 1e-300)[:, None]
    gn = orthonormal_frames(garment_V, garment_F)[index, 2]
    facing = np.einsum("mij,mj->mi", R, gn)
    X = np.zeros((body_F.shape[0], len(GARMENT_FEATURES)))
    X[:, 0] = 1.0
    X[:, 1] = dist / scale
    X[:, 2] = local[:, 2] / scale
    X[:, 3:6] = direction
    X[:, 6:9] = facing
    X[~covered, :9] = 0.0
    X[:, 9:12] = (cb - body_V.mean(axis=0)) / scale
    return X, covered


def neighbourhood_mean(centroids, values, radius, weights, chunk=NEIGHBOURHOOD_CHUNK, rows=None):
    """Area-weighted mean of per-triangle values over the triangles within ``radius`` of each one.

    Parameters
    ----------
    centroids : (M,3) float
    values : (M,k) float
    radius : float
    weights : (M,) float
        Positive.
    rows : (M,) bool, optional
        The triangles whose means are wanted (default all); the others' are NaN.

    Returns
    -------
    (M,k) float64

    The triangles are taken in blocks of ``chunk`` neighbours along a Morton curve; each block's
    candidates are those within ``radius`` of the block's bounding sphere, their squared distances to
    the block are one matrix product, and the sums over the ball another. The same pairs as a list of
    every pair within ``radius`` (up to the rounding of a distance equal to the radius) at a tenth of
    the time on a MakeHuman body, where the larger neighbourhood holds 61 million pairs.
    """
    centroids = np.asarray(centroids, dtype=np.float64)
    values = np.asarray(values, dtype=np.float64)
    tree = cKDTree(centroids)
    weighted = np.concatenate([weights[:, None], weights[:, None] * values], axis=1)
    out = np.full_like(values, np.nan)
    r2 = float(radius) ** 2
    order = _morton_order(centroids)
    if rows is not None:
        order = order[np.asarray(rows, dtype=bool)[order]]
    for start in range(0, len(order), chunk):
        rows = order[start:start + chunk]
        C = centroids[rows]
        lo, hi = C.min(axis=0), C.max(axis=0)
        centre = 0.5 * (lo + hi)
        near = np.asarray(tree.query_ball_point(centre, radius + 0.5 * np.linalg.norm(hi - lo)), dtype=np.int64)
        # About the block's centre, so the expansion |a|^2 + |b|^2 - 2ab rounds at the radius's scale.
        A, B = C - centre, centroids[near] - centre
        d2 = np.einsum("ij,ij->i", A, A)[:, None] + np.einsum("ij,ij->i", B, B)[None, :] - 2.0 * (A @ B.T)
        sums = (d2 <= r2).astype(np.float64) @ weighted[near]
        out[rows] = sums[:, 1:] / sums[:, :1]
    return out


def _morton_order(P):
    """(M,) int64: the points in the order of a Morton (Z-order) curve on a 1024^3 grid of their box."""
    q = ((P - P.min(axis=0)) / max(float(np.ptp(P, axis=0).max()), 1e-300) * 1023).astype(np.uint64)
    code = np.zeros(P.shape[0], np.uint64)
    for bit in range(10):
        for axis in range(3):
            code |= ((q[:, axis] >> np.uint64(bit)) & np.uint64(1)) << np.uint64(3 * bit + axis)
    return np.argsort(code, kind="stable")


def target_features(source_V, target_V, F, shares=NEIGHBOURHOOD_SHARES, rows=None):
    """The target body as seen from every source body triangle.

    Parameters
    ----------
    source_V, target_V : (nb,3) float
        The body in its source and target shapes (same topology).
    F : (M,3) int
    shares : tuple of float
        Neighbourhood radii as shares of the source body scale.
    rows : (M,) bool, optional
        The triangles whose neighbourhood means are wanted (default all; the others' are NaN): a garment
        covers a part of the body, and the means are nearly all of the time.

    Returns
    -------
    X : (M,9*(1+len(shares))) float64
        The body's own ``Q - I`` (row-major) at the triangle, then its area-weighted mean over each
        neighbourhood.
    dev : (M,9) float64
        The body's own ``Q - I``.
    """
    Q, _ = deformation_gradients(source_V, target_V, F)
    dev = (Q - np.eye(3)).reshape(-1, 9)
    c = triangle_centroids(source_V, F)
    area = triangle_normals(np.asarray(source_V, dtype=np.float64), F)[1]
    return with_neighbourhood_means(dev, c, area, body_scale(source_V), shares, rows), dev


def with_neighbourhood_means(values, centroids, area, scale, shares, rows=None):
    """``values`` (M,k) per body triangle, then their area-weighted means over the neighbourhoods of each
    radius ``share * scale``: (M, k * (1 + len(shares))) float64 (the means NaN outside ``rows``, if given)."""
    parts = [values] + [neighbourhood_mean(centroids, values, s * scale, area + 1e-300, rows=rows) for s in shares]
    return np.concatenate(parts, axis=1)


#: The last few ``target_features`` of the models' inputs, by content, with the triangles computed so far: the
#: field model and the placement model of one transfer need them on the triangles the garment covers and is
#: bound to (on a 26,756-triangle MakeHuman body about 0.9 s for every triangle, nearly all of it the
#: neighbourhood means), and so do further garments sent to the same target body; a body that is not a
#: training target also needs those of the training bodies its placement is blended from
#: (``placement.BlendedPlacement``). About 6 MB each on that body.
_TARGET_CACHE = OrderedDict()
_TARGET_CACHE_SIZE = 8
_TARGET_CACHE_LOCK = threading.Lock()


def target_features_cached(source_V, target_V, F, shares, rows=None):
    """``target_features``, kept for the last few bodies and computed only on triangles not computed before:
    ``rows (M,) bool`` (default all) must be read from the result, whose other rows may be NaN. The arrays
    returned are read-only."""
    arrays = [np.ascontiguousarray(source_V, dtype=np.float64), np.ascontiguousarray(target_V, dtype=np.float64),
              np.ascontiguousarray(F, dtype=np.int64)]
    shares = tuple(float(x) for x in shares)
    M = arrays[2].shape[0]
    need = np.ones(M, bool) if rows is None else np.asarray(rows, dtype=bool)
    key = content_key(arrays, shares)
    with _TARGET_CACHE_LOCK:
        entry = _TARGET_CACHE.get(key)
        if entry is not None:
            _TARGET_CACHE.move_to_end(key)
            missing = need & ~entry["done"]
        else:
            missing = need
    if entry is None or missing.any():
        X, dev = target_features(*arrays, shares, rows=missing)
        with _TARGET_CACHE_LOCK:
            entry = _TARGET_CACHE.get(key)
            if entry is None:
                entry = {"X": X, "dev": dev, "done": missing.copy()}
                _TARGET_CACHE[key] = entry
                while len(_TARGET_CACHE) > _TARGET_CACHE_SIZE:
                    _TARGET_CACHE.popitem(last=False)
            else:
                entry["X"][missing] = X[missing]
                entry["done"] |= missing
    X, dev = entry["X"].view(), entry["dev"].view()
    X.setflags(write=False)
    dev.setflags(write=False)
    return X, dev


def content_key(arrays, params):
    """A key of ``arrays``' content (shapes, types, bytes) and the hashable ``params``."""
    h = hashlib.sha256()
    for a in arrays:
        h.update(f"{a.shape}{a.dtype}".encode())
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest(), params


def recall_by_content(cache, lock, size, arrays, params, compute):
    """``compute()`` (a tuple of arrays), kept in ``cache`` (an ``OrderedDict``, at most ``size`` entries, the
    least recently used dropped first) under the content of ``arrays`` and the hashable ``params``; the arrays
    returned are read-only, and the same for the same content."""
    key = content_key(arrays, params)
    with lock:
        if key in cache:
            cache.move_to_end(key)
            return cache[key]
    value = compute()
    for a in value:
        a.setflags(write=False)
    with lock:
        cache[key] = value
        while len(cache) > size:
            cache.popitem(last=False)
    return value


def label_weights(target_V, label_bodies):
    """Weights over the training targets that best rebuild a body's shape (convex, least squares).

    Parameters
    ----------
    target_V : (nb,3) float
    label_bodies : (K,nb,3) float
        The training target bodies.

    Returns
    -------
    w : (K,) float64
        Non-negative, summing to 1; one-hot for a training body itself.
    """
    from scipy.optimize import nnls

    K = label_bodies.shape[0]
    A = np.asarray(label_bodies, dtype=np.float64).reshape(K, -1).T
    b = np.asarray(target_V, dtype=np.float64).reshape(-1)
    # The sum-to-one constraint as a heavily weighted extra row.
    big = 1e3 * np.sqrt(b.size)
    w, _ = nnls(np.vstack([A, big * np.ones((1, K))]), np.concatenate([b, [big]]))
    return w / max(w.sum(), 1e-300)


#: The last few ``label_weights``, by content: the field model and each placement network of one transfer ask
#: for the same body's (on a MakeHuman body about 0.1 s each).
_LABEL_CACHE = OrderedDict()
_LABEL_CACHE_SIZE = 8
_LABEL_CACHE_LOCK = threading.Lock()


def label_weights_cached(target_V, label_bodies):
    """``label_weights``, kept for the last few bodies and label sets (read-only)."""
    arrays = [np.ascontiguousarray(target_V, dtype=np.float64), np.ascontiguousarray(label_bodies)]
    return recall_by_content(_LABEL_CACHE, _LABEL_CACHE_LOCK, _LABEL_CACHE_SIZE, arrays, (),
                             lambda: (label_weights(*arrays),))[0]


class GarmentFitModel:
    """A trained garment-conditioned fit model (see the module docstring).

    Parameters
    ----------
    arrays : dict of str -> ndarray
        ``W{i} (out,in)``, ``b{i} (out,)`` per layer; ``input_mean``, ``input_std`` (P,);
        ``label_bodies (K,nb,3)``.
    metadata : dict
        ``targets``, ``layers``, ``use_label``, ``output_scale`` (9), ``source`` (``n_vertices``,
        ``n_faces``, ``n_triangles``, ``faces_hash``), ``neighbourhood_shares``, ``cover_distance``,
        ``garment_inputs`` (False: the garment's distance and direction are withheld, coverage and
        position kept; an ablation).
    name : str
        File name, for messages.
    """

    #: ``transfer_garment`` passes the garment and both bodies to ``body_field``.
    conditions_on_garment = True
    #: Values the network gives per triangle.
    OUTPUTS = 9

    def __init__(self, arrays, metadata, name="garment model"):
        self.name = name
        self.metadata = metadata
        self._check(arrays, metadata)
        self.arrays = arrays
        #: How much of the predicted deviation from the body's own field is used (``with_field_share``).
        self.field_share = 1.0

    def with_field_share(self, share):
        """The same model giving ``Q_body + share * (Q - Q_body)``: its field part of the way back to the
        body's own (0: direct transfer's field; 1: the model's). With the learned placement, half
        (0.5) kept the MDC at direct transfer's (lab/notes/garment-model-study.md).

        Parameters
        ----------
        share : float
            In [0, 1].
        """
        share = float(share)
        if not 0.0 <= share <= 1.0:
            raise ValueError(f"the field share must be between 0 and 1, got {share}")
        other = type(self)(self.arrays, self.metadata, self.name)
        other.field_share = share
        return other

    def _check(self, a, md):
        def need(cond, problem):
            if not cond:
                raise ModelError(self.name, problem)

        for key in ("targets", "layers", "use_label", "output_scale", "source", "neighbourhood_shares"):
            need(key in md, f"metadata lacks {key!r}")
        need(isinstance(md["targets"], list) and md["targets"], "metadata 'targets' must be a list of names")
        n = int(md["layers"])
        need(n >= 1, "needs at least one layer")
        for key in ["input_mean", "input_std", "label_bodies"] + [f"{w}{i}" for i in range(n) for w in "Wb"]:
            need(key in a, f"array {key!r} is missing")
            need(a[key].dtype.kind == "f", f"array {key!r} has dtype {a[key].dtype}")
        K = len(md["targets"])
        P = self.n_inputs(md)
        need(a["input_mean"].shape == (P,) and a["input_std"].shape == (P,),
             f"the input normalisation must have {P} values")
        need(np.all(a["input_std"] > 0), "'input_std' must be positive")
        width = P
        for i in range(n):
            W, b = a[f"W{i}"], a[f"b{i}"]
            need(W.ndim == 2 and W.shape[1] == width and b.shape == (W.shape[0],),
                 f"layer {i} has shape {W.shape}, expected (*, {width})")
            width = W.shape[0]
        need(width == self.OUTPUTS, f"the last layer gives {width} values, expected {self.OUTPUTS}")
        need(np.asarray(md["output_scale"]).shape == (self.OUTPUTS,),
             f"'output_scale' must be {self.OUTPUTS} numbers")
        lb = a["label_bodies"]
        need(lb.ndim == 3 and lb.shape[0] == K and lb.shape[1:] == (int(md["source"]["n_vertices"]), 3),
             "'label_bodies' must be (K, source vertices, 3)")

    @staticmethod
    def n_inputs(md):
        """The network's input width for metadata ``md``."""
        K = len(md["targets"])
        return len(GARMENT_FEATURES) + 9 * (1 + len(md["neighbourhood_shares"])) + (K if md["use_label"] else 0)

    @property
    def targets(self) -> list:
        return list(self.metadata["targets"])

    def check_source_body(self, mesh):
        """Raise ModelError unless ``mesh`` has the topology of the body the model was trained on."""

        src = self.metadata["source"]
        have = (mesh.n_vertices, mesh.n_faces, mesh.n_triangles, faces_hash(mesh))
        want = (src.get("n_vertices"), src.get("n_faces"), src.get("n_triangles"), src.get("faces_hash"))
        if have != want:
            raise ModelError(self.name, f"was trained on a source body with {want[0]} vertices and {want[1]} "
                                        f"faces (hash {want[3]}), but {mesh.name} has {have[0]} vertices, "
                                        f"{have[1]} faces (hash {have[3]})")

    def label_weights_for(self, target_body: Mesh, target=None):
        """(K,) weights of the label condition: one-hot for a known label, else from the body's shape."""
        if target is not None and target in self.targets:
            w = np.zeros(len(self.targets))
            w[self.targets.index(target)] = 1.0
            return w
        return label_weights_cached(target_body.V, self.arrays["label_bodies"])

    def inputs(self, source_body: Mesh, target_body: Mesh, garment: Mesh, target=None, rows=None,
               covered_only=False):
        """The network's inputs for every source body triangle.

        Parameters
        ----------
        rows : (M,) bool, optional
            The triangles whose inputs are read (default all; ``covered_only``: those the garment covers); the
            target's neighbourhood means are computed for those only, and may be NaN elsewhere.

        Returns
        -------
        X : (M,P) float64
        covered : (M,) bool
        body_dev : (M,9) float64
        """
        require_same_topology(source_body, target_body)
        G, covered = garment_features(source_body.V, source_body.F, garment.V, garment.F,
                                      self.metadata.get("cover_distance"))
        T, dev = target_features_cached(source_body.V, target_body.V, source_body.F,
                                         tuple(self.metadata["neighbourhood_shares"]),
                                         covered if covered_only else rows)
        if not self.metadata.get("garment_inputs", True):
            G[:, 1:9] = 0.0
        parts = [G, T]
        if self.metadata["use_label"]:
            parts.append(np.broadcast_to(self.label_weights_for(target_body, target), (G.shape[0],
                                                                                       len(self.targets))))
        return np.concatenate(parts, axis=1), covered, dev

    def forward(self, X):
        """Network output, normalised, for inputs ``X (M,P)``: ``(M,OUTPUTS)`` float64."""
        h = (np.asarray(X, np.float64) - self.arrays["input_mean"]) / self.arrays["input_std"]
        n = int(self.metadata["layers"])
        for i in range(n):
            h = h @ self.arrays[f"W{i}"].T.astype(np.float64) + self.arrays[f"b{i}"]
            if i < n - 1:
                h = np.tanh(h)
        return h

    def body_field(self, target, garment=None, source_body=None, target_body=None):
        """The predicted deformation gradient field of ``garment`` on the source body.

        Parameters
        ----------
        target : str or None
            A training target's label, or None (or an unknown name) for any other body: its label
            weights then come from its shape.
        garment : Mesh
            The garment dressed on ``source_body``.
        source_body, target_body : Mesh
            The body in its two shapes (the source of the training topology).

        Returns
        -------
        Q : (M,3,3) float64
        """
        if garment is None or source_body is None or target_body is None:
            raise ModelError(self.name, "a garment-conditioned model needs the garment and both bodies")
        self.check_source_body(source_body)
        X, covered, dev = self.inputs(source_body, target_body, garment, target, covered_only=True)
        y = self.forward(X[covered]) * np.asarray(self.metadata["output_scale"], dtype=np.float64)
        out = dev.copy()
        out[covered] += self.field_share * y
        return out.reshape(-1, 3, 3) + np.eye(3)

    def save(self, path):
        """Write the model to ``path`` (.npz), atomically."""
        save_npz_atomic(path, self.arrays, self.metadata)


def load_garment_model(path) -> GarmentFitModel:
    """Read a garment fit model file, refusing anything but plain arrays (``allow_pickle=False``).

    Raises
    ------
    ModelError
        Naming the file: missing, unreadable, pickled objects, metadata missing or of another format or
        version, arrays that do not fit together.
    """
    arrays, metadata = read_model_npz(path, FORMAT, FORMAT_VERSION, "a garment fit model")
    return GarmentFitModel(arrays, metadata, os.fspath(path))


def read_model_npz(path, format_name, version, what):
    """The arrays and JSON metadata of a model file of one format and version (``allow_pickle=False``;
    ``version``: an int, or a tuple of the versions read).

    Returns
    -------
    arrays : dict of str -> ndarray
    metadata : dict

    Raises
    ------
    ModelError
        Naming the file: missing, unreadable, pickled objects, metadata missing or of another format
        or version.
    """
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise ModelError(path, "model file not found")
    try:
        with np.load(path, allow_pickle=False) as npz:
            arrays = {k: npz[k] for k in npz.files}
    except ValueError as exc:
        raise ModelError(path, f"is not a readable model file; only plain arrays are accepted ({exc})") from None
    except (OSError, EOFError, zipfile.BadZipFile) as exc:
        raise ModelError(path, f"is not a model file (.npz): {exc}") from None
    meta = arrays.pop("metadata", None)
    if meta is None or meta.dtype.kind != "U" or meta.shape != ():
        raise ModelError(path, "has no JSON 'metadata' string: not a garment transfer model")
    try:
        metadata = json.loads(str(meta))
    except json.JSONDecodeError as exc:
        raise ModelError(path, f"metadata is not valid JSON ({exc})") from None
    if not isinstance(metadata, dict) or metadata.get("format") != format_name:
        raise ModelError(path, f"is not {what} (metadata 'format' is not {format_name!r})")

    if not reads_version(metadata.get("format_version"), version):
        raise ModelError(path, f"has format version {metadata.get('format_version')}; this version reads "
                               f"{versions_text(version)}")
    return arrays, metadata
