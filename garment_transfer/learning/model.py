"""The shared deformation model (paper sect. 5): file format and inference in numpy alone.

The network learns, on the source body's triangles, the normalised deviation from identity of the
garments' deformation gradients towards each target body:

    x = ((Q - I)[active] / scale).reshape(-1)          (D,) with D = 9 * active.sum()
    encoder:  z = s(W_e,n ... s(W_e,1 [x, onehot(c)] + b) ...)      s = sigmoid, z in (0,1)^L
    decoder:  y = W_d,n s(... s(W_d,1 [z, onehot(c)] + b) ...) + b   (last layer linear)

``onehot(c)`` is the target body's label (sect. 5.2): one model serves every target.

*A new garment* has no simulation on the target, so its field cannot be encoded. Its shape field for
target c is the decoder's output at the mean latent of the training garments on c
(``body_field(c)``); the alternatives (``how=``) are there to measure that choice:
``"mean_decoded"`` (mean of the decoded training fields), ``"mean_field"`` (mean of the training fields
themselves, no network) and ``"body"`` (the body's own deformation, i.e. direct deformation transfer).

*Uncovered triangles*: body triangles that no training garment covered (``active`` is False: head,
hands, feet for most garments) carry no learned value; they take the source body's own deformation
gradient towards the target (what direct deformation transfer would use), so a new garment reaching
there follows the body instead of an arbitrary untrained output.

*Another body*: a model file also holds the body it was trained on (``source_V``, and its polygons as
``source_face_vertices`` and ``source_face_start``). A garment dressed on another body mesh (another
topology, family, units or axes) is then served through ``field_mapping.model_field``: the model's
body is registered onto that body and the field carried across.

File format: an ``.npz`` of plain numeric arrays and one JSON string ``metadata`` (format version,
source body counts and faces hash, target labels, latent size, normalisation, training settings,
losses). It is read with ``allow_pickle=False`` only: a model file cannot run code.
"""

from __future__ import annotations

import json
import logging
import os
import zipfile

import numpy as np

from ..errors import ModelError
from ..files import write_atomic
from ..geometry.mesh import Mesh, check_polygons, faces_hash, triangulate

log = logging.getLogger(__name__)

FORMAT = "garment_transfer.shared_deformation_model"
FORMAT_VERSION = 1
HOW = ("mean_latent", "mean_decoded", "mean_field", "body")


def sigmoid(a):
    """Logistic function, without overflow warnings for large |a|."""
    from scipy.special import expit

    return expit(a)


class SharedDeformationModel:
    """A trained shared deformation model.

    Parameters
    ----------
    arrays : dict of str -> ndarray
        ``enc_W{i}, enc_b{i}`` (i < n_enc), ``dec_W{i}, dec_b{i}`` (i < n_dec): layer weights (out, in)
        and biases, float; ``active (M,) bool``: body triangles the training data covered;
        ``body_deviation (K,M,9)``: the body's own ``Q - I`` per target; ``mean_field (K,M,9)``: mean
        ``Q - I`` of the training garments; ``latent_mean (K,L)`` and ``train_latents (G,K,L)``.
    metadata : dict
        See the module docstring; ``targets``, ``latent``, ``normalisation.scale`` (9 floats) and
        ``source`` (``n_vertices``, ``n_faces``, ``n_triangles``, ``faces_hash``) are used here.
    name : str
        File name, for messages.

    Raises
    ------
    ModelError
        When arrays are missing or their shapes do not fit together.
    """

    def __init__(self, arrays, metadata, name="model"):
        self.name = name
        self.metadata = metadata
        self._check(arrays, metadata)
        self.arrays = arrays
        self._cache = {}

    def _check(self, a, md):
        def need(cond, problem):
            if not cond:
                raise ModelError(self.name, problem)

        for key in ("targets", "latent", "normalisation", "source", "encoder_layers", "decoder_layers"):
            need(key in md, f"metadata lacks {key!r}")
        targets = md["targets"]
        need(isinstance(targets, list) and targets and all(isinstance(t, str) for t in targets),
             "metadata 'targets' must be a non-empty list of names")
        n_enc, n_dec, L, K = int(md["encoder_layers"]), int(md["decoder_layers"]), int(md["latent"]), \
            len(targets)
        keys = ["active", "body_deviation", "mean_field", "latent_mean", "train_latents"]
        keys += [f"enc_{w}{i}" for i in range(n_enc) for w in "Wb"]
        keys += [f"dec_{w}{i}" for i in range(n_dec) for w in "Wb"]
        for key in keys:
            need(key in a, f"array {key!r} is missing")
            need(a[key].dtype.kind in ("f", "b"), f"array {key!r} has dtype {a[key].dtype}")
        need(n_enc >= 1 and n_dec >= 1, "needs at least one encoder and one decoder layer")
        active = a["active"]
        need(active.dtype == bool and active.ndim == 1, "'active' must be a (M,) bool array")
        M = active.shape[0]
        need(M == int(md["source"].get("n_triangles", -1)), "'active' does not match the source body")
        D = 9 * int(active.sum())
        scale = np.asarray(md["normalisation"].get("scale", []), dtype=np.float64)
        need(scale.shape == (9,) and np.all(scale > 0), "normalisation 'scale' must be 9 positive numbers")
        width = D + K
        for i in range(n_enc):
            W, b = a[f"enc_W{i}"], a[f"enc_b{i}"]
            need(W.ndim == 2 and W.shape[1] == width and b.shape == (W.shape[0],),
                 f"encoder layer {i} has shape {W.shape}, expected (*, {width})")
            width = W.shape[0]
        need(width == L, f"the encoder ends in {width} values, the latent size is {L}")
        width = L + K
        for i in range(n_dec):
            W, b = a[f"dec_W{i}"], a[f"dec_b{i}"]
            need(W.ndim == 2 and W.shape[1] == width and b.shape == (W.shape[0],),
                 f"decoder layer {i} has shape {W.shape}, expected (*, {width})")
            width = W.shape[0]
        need(width == D, f"the decoder ends in {width} values, expected {D} (9 per active triangle)")
        need(a["body_deviation"].shape == (K, M, 9), "'body_deviation' must be (K,M,9)")
        need(a["mean_field"].shape == (K, M, 9), "'mean_field' must be (K,M,9)")
        need(a["latent_mean"].shape == (K, L), "'latent_mean' must be (K,L)")
        need(a["train_latents"].ndim == 3 and a["train_latents"].shape[1:] == (K, L),
             "'train_latents' must be (G,K,L)")
        body_keys = ("source_V", "source_face_vertices", "source_face_start")
        if any(k in a for k in body_keys):
            need(all(k in a for k in body_keys), "holds part of its source body (source_V, "
                                                 "source_face_vertices, source_face_start go together)")
            need(a["source_V"].shape == (int(md["source"].get("n_vertices", -1)), 3),
                 "'source_V' does not match the source body's vertex count")

    @property
    def source_body(self):
        """The body the model was trained on (a Mesh), or None when the file does not hold it."""
        if "source_V" not in self.arrays:
            return None
        if "source_body" not in self._cache:

            a = self.arrays
            V = a["source_V"].astype(np.float64)
            fv = a["source_face_vertices"].astype(np.int64)
            fs = a["source_face_start"].astype(np.int64)
            name = self.metadata["source"].get("name") or "model body"
            try:
                check_polygons(V, fv, fs, name)
            except Exception as exc:
                raise ModelError(self.name, f"its source body is damaged: {exc}") from None
            F, tri_to_face = triangulate(V, fv, fs)
            body = Mesh(V, F, fv, fs, tri_to_face, name)
            if faces_hash(body) != self.metadata["source"].get("faces_hash"):
                raise ModelError(self.name, "its source body does not match its faces hash")
            self._cache["source_body"] = body
        return self._cache["source_body"]

    @property
    def targets(self) -> list:
        """Target body labels, in the order of the one-hot condition."""
        return list(self.metadata["targets"])

    @property
    def latent_size(self) -> int:
        return int(self.metadata["latent"])

    @property
    def n_triangles(self) -> int:
        """|M|: triangles of the source body."""
        return int(self.arrays["active"].shape[0])

    @property
    def active(self):
        """(M,) bool: body triangles the training garments covered."""
        return self.arrays["active"]

    @property
    def scale(self):
        """(9,) float64: the deviation ``Q - I`` is divided by this (per matrix entry) for learning."""
        return np.asarray(self.metadata["normalisation"]["scale"], dtype=np.float64)

    def target_index(self, target) -> int:
        """Index of a target label (ModelError listing the known ones otherwise)."""
        if target not in self.metadata["targets"]:
            raise ModelError(self.name, f"unknown target {target!r}; this model knows: "
                                        f"{', '.join(self.metadata['targets'])}")
        return self.metadata["targets"].index(target)

    def same_body(self, mesh) -> bool:
        """Whether ``mesh`` has the topology of the body the model was trained on."""

        src = self.metadata["source"]
        return ((mesh.n_vertices, mesh.n_faces, mesh.n_triangles, faces_hash(mesh)) ==
                (src.get("n_vertices"), src.get("n_faces"), src.get("n_triangles"), src.get("faces_hash")))

    def check_source_body(self, mesh):
        """Raise ModelError unless the model can serve garments dressed on ``mesh``: the topology of the
        body it was trained on, or any body when the file holds that body (registered onto it)."""
        if self.source_body is not None:
            return

        src = self.metadata["source"]
        have = (mesh.n_vertices, mesh.n_faces, mesh.n_triangles, faces_hash(mesh))
        want = (src.get("n_vertices"), src.get("n_faces"), src.get("n_triangles"), src.get("faces_hash"))
        if have != want:
            raise ModelError(
                self.name,
                f"was trained on source body {src.get('name', '?')!r} ({want[0]} vertices, {want[1]} faces, "
                f"faces hash {want[3]}), but {mesh.name} has {have[0]} vertices, {have[1]} faces, faces "
                f"hash {have[3]}: use the model with the body it was trained on (a model trained by this "
                "version holds its body and serves any body)")

    def _onehot(self, k, n):
        oh = np.zeros((n, len(self.targets)))
        oh[:, k] = 1.0
        return oh

    def encode(self, x, target):
        """Latent codes of normalised deviation vectors.

        Parameters
        ----------
        x : (n,D) float
            ``((Q - I)[active] / scale).reshape(n, -1)``.
        target : str

        Returns
        -------
        z : (n,L) float64
        """
        k = self.target_index(target)
        h = np.concatenate([np.asarray(x, np.float64), self._onehot(k, len(x))], axis=1)
        for i in range(int(self.metadata["encoder_layers"])):
            h = sigmoid(h @ self.arrays[f"enc_W{i}"].T.astype(np.float64) + self.arrays[f"enc_b{i}"])
        return h

    def decode(self, z, target):
        """Normalised deviation vectors decoded from latent codes.

        Parameters
        ----------
        z : (n,L) float
        target : str

        Returns
        -------
        y : (n,D) float64
        """
        k = self.target_index(target)
        z = np.asarray(z, np.float64).reshape(-1, self.latent_size)
        h = np.concatenate([z, self._onehot(k, len(z))], axis=1)
        n = int(self.metadata["decoder_layers"])
        for i in range(n):
            W, b = self.arrays[f"dec_W{i}"], self.arrays[f"dec_b{i}"]
            h = h @ W.T.astype(np.float64) + b
            if i < n - 1:
                h = sigmoid(h)
        return h

    def field_from_output(self, y, target):
        """A decoded vector as a full deformation gradient field.

        Parameters
        ----------
        y : (D,) float
            Decoder output (normalised deviation on the active triangles).
        target : str

        Returns
        -------
        Q : (M,3,3) float64
            ``I + y * scale`` on active triangles, the body's own gradient elsewhere.
        """
        k = self.target_index(target)
        dev = self.arrays["body_deviation"][k].astype(np.float64)
        dev[self.active] = np.asarray(y, np.float64).reshape(-1, 9) * self.scale
        return dev.reshape(-1, 3, 3) + np.eye(3)

    def body_field(self, target, how="mean_latent"):
        """The predicted deformation gradient field on the source body for a new garment.

        Parameters
        ----------
        target : str
            A label of ``targets``.
        how : {"mean_latent", "mean_decoded", "mean_field", "body"}
            ``"mean_latent"`` (default): the decoder at the mean latent code of the training garments on
            the target. The others are for comparison: the mean of the decoded training fields, the mean
            of the training fields themselves, the body's own deformation gradients.

        Returns
        -------
        Q : (M,3,3) float64
            One 3x3 matrix per source body triangle. Triangles no training garment covered get the body's
            own deformation gradient towards the target.
        """
        k = self.target_index(target)
        if how not in HOW:
            raise ValueError(f"how must be one of {', '.join(HOW)}, got {how!r}")
        key = (target, how)
        if key not in self._cache:
            if how == "mean_latent":
                Q = self.field_from_output(self.decode(self.arrays["latent_mean"][k], target)[0], target)
            elif how == "mean_decoded":
                y = self.decode(self.arrays["train_latents"][:, k], target).mean(axis=0)
                Q = self.field_from_output(y, target)
            elif how == "mean_field":
                Q = self.arrays["mean_field"][k].astype(np.float64).reshape(-1, 3, 3) + np.eye(3)
            else:
                Q = self.arrays["body_deviation"][k].astype(np.float64).reshape(-1, 3, 3) + np.eye(3)
            self._cache[key] = Q
        return self._cache[key].copy()

    def save(self, path, inputs=()):
        """Write the model to ``path`` (.npz) through a temporary file in the same folder and a rename.

        ``inputs``: files the model file must not be (see ``files.check_output``).
        """
        save_npz_atomic(path, self.arrays, self.metadata, inputs=inputs)


def save_npz_atomic(path, arrays, metadata, inputs=()):
    """Write arrays and a JSON metadata string to an .npz file, atomically.

    Parameters
    ----------
    path : str or Path
    arrays : dict of str -> ndarray
        Numeric or bool arrays only (never object arrays).
    metadata : dict
        JSON-serialisable.
    inputs : iterable of paths
        Files the model file must not be (see ``files.check_output``).

    Raises
    ------
    ModelError
        If an array is not numeric.
    OutputError
        If ``path`` must not or cannot be written (see ``files.write_atomic``).
    """

    for key, arr in arrays.items():
        if np.asarray(arr).dtype.kind not in "fiub":
            raise ModelError(os.fspath(path), f"array {key!r} is not numeric ({np.asarray(arr).dtype})")
    payload = dict(arrays)
    payload["metadata"] = np.array(json.dumps(metadata, sort_keys=True))
    write_atomic(path, lambda fh: np.savez(fh, **payload), inputs=inputs, what="the model file",
                 binary=True)


def load_model(path) -> SharedDeformationModel:
    """Read a model file, refusing anything but plain arrays.

    Parameters
    ----------
    path : str or Path

    Raises
    ------
    ModelError
        Naming the file: missing, not an .npz, holding pickled objects, metadata missing or invalid, a
        format version this code does not read, arrays that do not fit together.
    """
    arrays, metadata = read_model_arrays(path)
    name = os.fspath(path)
    if metadata.get("format") != FORMAT:
        raise ModelError(name, "is not a garment transfer model (metadata 'format' differs)")
    need_format_version(name, metadata, FORMAT_VERSION)
    return SharedDeformationModel(arrays, metadata, name)


def need_format_version(path, metadata, version, what="it"):
    """A ModelError naming the file (and ``what`` in it, e.g. "its placement model") unless the metadata's
    ``format_version`` is ``version`` (an int, or a tuple of the versions read)."""
    have = metadata.get("format_version")
    if not reads_version(have, version):
        where = "" if what == "it" else f"{what} "
        raise ModelError(path, f"{where}has format version {have}; this version of garment_transfer reads "
                               f"{versions_text(version)}")


def reads_version(have, version):
    """Whether a file's ``format_version`` ``have`` is ``version`` (an int) or one of them (a tuple)."""
    wanted = version if isinstance(version, tuple) else (version,)
    return not isinstance(have, bool) and isinstance(have, int) and have in wanted


def versions_text(version):
    """``version 1`` or ``versions 1 and 2``."""
    if not isinstance(version, tuple) or len(version) == 1:
        return f"version {version[0] if isinstance(version, tuple) else version}"
    return f"versions {', '.join(str(v) for v in version[:-1])} and {version[-1]}"


def read_model_arrays(path):
    """The plain arrays and the JSON metadata of a model file of any kind, refusing anything else.

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    arrays : dict of str -> ndarray
        Every array but ``metadata``.
    metadata : dict
        The parsed ``metadata`` string (its ``format`` is not checked here).

    Raises
    ------
    ModelError
        Naming the file: missing, not an .npz, holding pickled objects, metadata missing or invalid.
    """
    path = os.fspath(path)
    name = path
    if not os.path.isfile(path):
        raise ModelError(name, "model file not found")
    try:
        with open(path, "rb") as fh:
            magic = fh.read(4)
    except OSError as exc:
        raise ModelError(name, f"cannot be read ({exc.strerror or exc})") from None
    if magic[:1] == b"\x80":
        raise ModelError(name, "holds Python objects (pickled data); refused: a model file must "
                               "contain plain arrays only")
    if magic != b"PK\x03\x04":
        kind = "an empty file" if not magic else (
            "a text file (an OBJ mesh?)" if all(32 <= c < 127 or c in (9, 10, 13) for c in magic)
            else "some other binary file")
        raise ModelError(name, f"is not a model file (.npz, a zip archive) but {kind}; give the .npz "
                               "file written by train")
    arrays = {}
    try:
        with np.load(path, allow_pickle=False) as npz:
            for key in npz.files:
                arrays[key] = npz[key]
    except ValueError as exc:
        if "pickle" in str(exc).lower() or "object" in str(exc).lower():
            raise ModelError(name, "holds Python objects (pickled data); refused: a model file must "
                                   "contain plain arrays only") from None
        raise ModelError(name, f"is not a readable model file ({exc})") from None
    except (OSError, EOFError, zipfile.BadZipFile) as exc:
        raise ModelError(name, f"is not a model file (.npz): {exc}") from None
    if "metadata" not in arrays:
        raise ModelError(name, "has no 'metadata': not a garment transfer model")
    meta = arrays.pop("metadata")
    if meta.dtype.kind != "U" or meta.shape != ():
        raise ModelError(name, "'metadata' must be a JSON string")
    try:
        metadata = json.loads(str(meta))
    except json.JSONDecodeError as exc:
        raise ModelError(name, f"metadata is not valid JSON ({exc})") from None
    if not isinstance(metadata, dict):
        raise ModelError(name, "is not a garment transfer model (metadata 'format' differs)")
    return arrays, metadata
