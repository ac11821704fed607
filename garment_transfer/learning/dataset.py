"""Dataset folders of bodies and garments, and the training matrix built from them (paper sect. 4).

Layout of a dataset folder::

    bodies/<body>.obj                 every body: one topology, different shapes
    garments/<garment>/<body>.obj     a garment on each body it was simulated (or fitted) on;
                                      all files of one garment share vertex order and faces
    manifest.json                     optional: {"units": "decimetres", "up_axis": "Y",
                                      "bodies": [...], "garments": [...]}

Meshes are read lazily, when first asked for; bodies are kept once read (a few are shared by every
garment), garments are not (there can be many, and each is used once per training set).

The training matrix (algorithm 1): for each garment g and target body c, the deformation gradients
``C (T,3,3)`` of the garment from the source body to c, computed on the triangles of the garment **on
the source body** for both shapes (quads split by their shorter diagonal would otherwise differ between
shapes), are embedded on the source body's triangles: ``B[a] = C[BodyToCloth[a]]``. Body triangles far
from every garment triangle, or whose nearest garment triangle is degenerate, are *uncovered*: the
garment says nothing about them, and the masked loss ignores them.
"""

from __future__ import annotations

import json
import logging
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import Cancelled, DatasetError, MeshError, TopologyMismatchError
from ..geometry.embedding import body_to_cloth, embed
from ..geometry.gradients import deformation_gradients
from ..geometry.mesh import Mesh, require_same_topology
from ..geometry.obj import read_obj

log = logging.getLogger(__name__)

MANIFEST = "manifest.json"


@dataclass
class Dataset:
    """A dataset folder: which bodies and garments it has, and their meshes on demand.

    Attributes
    ----------
    folder : Path
    bodies : list of str
        Body names (``bodies/<name>.obj``), in the manifest's order when it lists them, else sorted.
    garments : list of str
        Garment names (``garments/<name>/``), likewise.
    units : str or None
        Length unit of the coordinates as the manifest states it (None: not stated).
    up_axis : str or None
        Up axis as the manifest states it (None: not stated).
    manifest : dict
        The manifest's content ({} without one).
    """

    folder: Path
    bodies: list
    garments: list
    units: str | None = None
    up_axis: str | None = None
    manifest: dict = field(default_factory=dict)
    _body_cache: dict = field(default_factory=dict, repr=False)

    def body_path(self, body) -> Path:
        """Path of ``bodies/<body>.obj`` (DatasetError for an unknown body)."""
        self.require_body(body)
        return self.folder / "bodies" / f"{body}.obj"

    def garment_path(self, garment, body) -> Path:
        """Path of ``garments/<garment>/<body>.obj`` (which may not exist: see ``has_garment``)."""
        self.require_garment(garment)
        return self.folder / "garments" / garment / f"{body}.obj"

    def has_garment(self, garment, body) -> bool:
        """Whether the garment was placed on that body."""
        return self.garment_path(garment, body).is_file()

    def garment_bodies(self, garment) -> list:
        """The bodies the garment exists on, in the dataset's body order."""
        return [b for b in self.bodies if self.has_garment(garment, b)]

    def require_body(self, body):
        if body not in self.bodies:
            raise DatasetError(str(self.folder), f"has no body {body!r}; its bodies are: "
                                                 f"{', '.join(self.bodies)}")

    def require_garment(self, garment):
        if garment not in self.garments:
            raise DatasetError(str(self.folder), f"has no garment {garment!r}; its garments are: "
                                                 f"{', '.join(self.garments)}")

    def require_complete(self, garments, bodies):
        """Raise DatasetError naming the first missing ``garments/<g>/<body>.obj``."""
        for b in bodies:
            self.require_body(b)
        for g in garments:
            for b in bodies:
                if not self.has_garment(g, b):
                    have = self.garment_bodies(g)
                    raise DatasetError(
                        str(self.garment_path(g, b)),
                        f"missing: garment {g!r} is not on body {b!r} (it is on: "
                        f"{', '.join(have) if have else 'no body'}); every garment used for training "
                        "must exist on the source and on every target body")

    def body(self, name) -> Mesh:
        """The body mesh (read once, then kept)."""
        if name not in self._body_cache:
            self._body_cache[name] = _read(self.body_path(name))
        return self._body_cache[name]

    def garment(self, garment, body) -> Mesh:
        """The garment's mesh on a body (read on every call)."""
        path = self.garment_path(garment, body)
        if not path.is_file():
            self.require_complete([garment], [body])
        return _read(path)

    def garment_pair(self, garment, source, target):
        """The garment on the source body, and its vertices on the target body.

        Returns
        -------
        src : Mesh
            The garment on the source body; its triangles ``src.F`` are the ones to use for both shapes.
        target_V : (n,3) float64
            Vertex positions of the same garment on the target body.

        Raises
        ------
        DatasetError
            Naming the target file when its vertices or faces differ from the source file's.
        """
        src = self.garment(garment, source)
        tgt = self.garment(garment, target)
        try:
            require_same_topology(src, tgt)
        except TopologyMismatchError as exc:
            raise DatasetError(tgt.name, f"{exc.problem} (garment {garment!r}: every file of one "
                                         "garment must have the same vertices and faces)") from None
        return src, tgt.V


def _read(path) -> Mesh:
    try:
        return read_obj(path)
    except MeshError as exc:
        raise DatasetError(exc.name, exc.problem) from None


def load_dataset(folder) -> Dataset:
    """Open a dataset folder (no mesh is read yet).

    Parameters
    ----------
    folder : str or Path

    Raises
    ------
    DatasetError
        Naming the folder or file: no such folder, no ``bodies/``, no body or no garment at all, a
        manifest that is not valid JSON, or that lists a body or garment the folder lacks.
    """
    folder = Path(os.fspath(folder))
    if not folder.is_dir():
        raise DatasetError(str(folder), "dataset folder not found")
    manifest = {}
    mpath = folder / MANIFEST
    if mpath.is_file():
        try:
            manifest = json.loads(mpath.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise DatasetError(str(mpath), f"is not valid JSON ({exc})") from None
        if not isinstance(manifest, dict):
            raise DatasetError(str(mpath), "must hold a JSON object")
    bdir, gdir = folder / "bodies", folder / "garments"
    found_bodies = sorted(p.stem for p in bdir.glob("*.obj")) if bdir.is_dir() else []
    found_garments = sorted(p.name for p in gdir.iterdir() if p.is_dir()) if gdir.is_dir() else []
    bodies = _listed(manifest, "bodies", found_bodies, mpath, bdir, "{}.obj")
    garments = _listed(manifest, "garments", found_garments, mpath, gdir, "{}/")
    if not bodies:
        raise DatasetError(str(folder), "the dataset is empty: no bodies/<body>.obj")
    if not garments:
        raise DatasetError(str(folder), "the dataset is empty: no garments/<garment>/<body>.obj")
    units = manifest.get("units")
    up = manifest.get("up_axis")
    return Dataset(folder, bodies, garments, None if units is None else str(units),
                   None if up is None else str(up), manifest)


def dataset_inputs(folder):
    """What reading a dataset folder reads, named without reading it: for the outputs' check
    (``files.check_outputs``) before any work.

    Returns
    -------
    files : list of str
        ``<folder>/manifest.json``.
    folders : list of str
        ``<folder>/bodies`` and ``<folder>/garments``: every file in them may be read.
    """
    folder = os.fspath(folder)
    return ([os.path.join(folder, MANIFEST)],
            [os.path.join(folder, "bodies"), os.path.join(folder, "garments")])


def _listed(manifest, key, found, mpath, where, pattern):
    """The manifest's list for key (checked against the folder), else what the folder holds."""
    if key not in manifest:
        return found
    listed = manifest[key]
    if not isinstance(listed, list) or not all(isinstance(x, str) for x in listed):
        raise DatasetError(str(mpath), f"{key!r} must be a list of names")
    missing = [x for x in listed if x not in found]
    if missing:
        raise DatasetError(str(mpath), f"lists {key} that {where} lacks: "
                                       + ", ".join(pattern.format(x) for x in missing))
    return list(listed)


def garment_field(body_V, body_F, garment_V, garment_F, target_V, cover_distance=None):
    """One garment pair embedded on the source body (algorithm 1), with its coverage.

    Parameters
    ----------
    body_V : (nb,3) float
        Source body vertices.
    body_F : (M,3) int
        Source body triangles.
    garment_V : (n,3) float
        The garment on the source body.
    garment_F : (T,3) int
        Its triangles (those of the garment on the source body).
    target_V : (n,3) float
        The same garment on the target body.
    cover_distance : float, optional
        See ``embedding.body_to_cloth``.

    Returns
    -------
    B : (M,3,3) float64
        Deformation gradient of the nearest garment triangle, for every body triangle.
    covered : (M,) bool
        False where the garment is far from the body triangle, or its nearest garment triangle is
        degenerate (its gradient is undefined).
    """

    C, degenerate = deformation_gradients(garment_V, target_V, garment_F)
    index, covered = body_to_cloth(body_V, body_F, garment_V, garment_F, cover_distance)
    return embed(C, index), covered & ~degenerate[index]


@dataclass
class TrainingFields:
    """The training matrix: every garment's embedded deformation to every target body.

    Attributes
    ----------
    deviation : (G,K,M,9) float32
        ``Q - I`` of garment g towards target k on body triangle a (row-major 3x3); zero where the
        garment does not cover the triangle.
    raw_deviation : (G,K,M,9) float32 or None
        The same, with the paper's unmasked embedding (the nearest garment triangle's value even
        where it is far); kept only when asked for.
    covered : (G,M) bool
        Coverage of each garment (on the source body, so the same for every target).
    body_deviation : (K,M,9) float32
        ``Q - I`` of the source body's own triangles towards each target body.
    garments, targets : list of str
    source : str
    body : Mesh
        The source body.
    units, up_axis : str or None
        As the dataset's manifest states them.
    cover_distance : float or None
        The coverage distance used (None: ``embedding.default_cover_distance`` per garment).
    """

    deviation: np.ndarray
    covered: np.ndarray
    body_deviation: np.ndarray
    garments: list
    targets: list
    source: str
    body: Mesh
    raw_deviation: np.ndarray | None = None
    units: str | None = None
    up_axis: str | None = None
    cover_distance: float | None = None

    def select(self, garments) -> "TrainingFields":
        """The same fields restricted to some garments (in the given order)."""
        idx = [self.garments.index(g) for g in garments]
        raw = None if self.raw_deviation is None else self.raw_deviation[idx]
        return TrainingFields(self.deviation[idx], self.covered[idx], self.body_deviation,
                              list(garments), self.targets, self.source, self.body, raw,
                              self.units, self.up_axis, self.cover_distance)


def build_training_fields(dataset, source, targets, garments=None, cover_distance=None,
                          keep_raw=False, progress=None) -> TrainingFields:
    """Read a dataset and embed every garment's deformation to every target on the source body.

    Parameters
    ----------
    dataset : Dataset or str or Path
    source : str
        The source body's name.
    targets : list of str
        Target body names (not the source).
    garments : list of str, optional
        Default: every garment of the dataset.
    cover_distance : float, optional
        See ``embedding.body_to_cloth``.
    keep_raw : bool
        Also keep the unmasked embedding (for the paper's unmasked loss).
    progress : callable(fraction) -> bool, optional
        Called after each garment file pair; returning True cancels (raises Cancelled).

    Raises
    ------
    DatasetError
        Unknown body or garment, a garment missing on the source or a target, garment files of one
        garment with different topology, a target body of another topology than the source body.
    """

    ds = dataset if isinstance(dataset, Dataset) else load_dataset(dataset)
    targets = list(targets)
    garments = list(ds.garments if garments is None else garments)
    if not targets:
        raise DatasetError(str(ds.folder), "no target body given")
    if not garments:
        raise DatasetError(str(ds.folder), "no garment given to train on")
    for name in [source, *targets]:
        ds.require_body(name)
    for g in garments:
        ds.require_garment(g)
    if source in targets:
        raise DatasetError(str(ds.folder), f"the source body {source!r} cannot also be a target")
    if len(set(targets)) != len(targets) or len(set(garments)) != len(garments):
        raise DatasetError(str(ds.folder), "a target or garment is listed twice")
    ds.require_complete(garments, [source, *targets])

    body = ds.body(source)
    G, K, M = len(garments), len(targets), body.n_triangles
    body_dev = np.empty((K, M, 9), np.float32)
    for k, t in enumerate(targets):
        tb = ds.body(t)
        try:
            require_same_topology(body, tb)
        except TopologyMismatchError as exc:
            raise DatasetError(tb.name, f"{exc.problem} (all bodies of a dataset share one topology)") \
                from None
        Q, _ = deformation_gradients(body.V, tb.V, body.F)
        body_dev[k] = (Q - np.eye(3)).reshape(M, 9)

    dev = np.zeros((G, K, M, 9), np.float32)
    raw = np.zeros((G, K, M, 9), np.float32) if keep_raw else None
    covered = np.zeros((G, M), bool)
    done, total = 0, G * K
    for g, name in enumerate(garments):
        for k, t in enumerate(targets):
            src, tV = ds.garment_pair(name, source, t)
            B, cov = garment_field(body.V, body.F, src.V, src.F, tV, cover_distance)
            d = (B - np.eye(3)).reshape(M, 9)
            dev[g, k] = np.where(cov[:, None], d, 0.0)
            if keep_raw:
                raw[g, k] = d
            covered[g] = cov
            done += 1
            if progress is not None and progress(done / total):
                raise Cancelled("reading the dataset was cancelled")
        log.info("garment %s: %d of %d body triangles covered", name, int(covered[g].sum()), M)
    return TrainingFields(dev, covered, body_dev, garments, targets, source, body, raw,
                          ds.units, ds.up_axis, cover_distance)
