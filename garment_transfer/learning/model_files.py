"""Model files of every kind behind one loader: what ``transfer --model`` and the Blender panel read.

Three kinds of file are read:

- the paper's shared deformation model (``model.py``, format ``garment_transfer.shared_deformation_model``);
- a garment fit model alone (``garment_model.py``, format ``garment_transfer.garment_fit_model``);
- a **garment fit bundle** (format ``garment_transfer.garment_fit_bundle``, written by
  ``python -m garment_transfer train --kind garment``): the garment fit model and, optionally, the
  learned placement (``placement.py``) in one file, so that one file is passed around.

A bundle is an ``.npz`` of plain arrays, the field model's prefixed ``field.`` and the placement's
``placement.``, and one JSON string ``metadata``::

    {"format": "garment_transfer.garment_fit_bundle", "format_version": 1,
     "field": <the garment fit model's metadata>, "placement": <the placement model's metadata> or null,
     "dataset": {"folder", "units", "up_axis"}, "source": {...}, "targets": [...]}

A learned placement of several members (``placement.PlacementEnsemble``: networks trained alike with
other seeds, their predictions averaged) is written as format version 2: ``"placement_members": N`` and
``"placement"`` the list of the N members' metadata, member i's arrays prefixed ``placement.<i>.``. A
single placement model is written as version 1 (as before), and both versions are read.

It is read with ``allow_pickle=False`` only; its parts are checked as the single-model files are
(their own formats and versions), and must have been trained on the same source body.

A bundle may also hold the nearest garments' placement (``placement.NearestGarments``: the training
garments' own placements, no network), mixed with the networks' (``placement.MixedPlacement``): format
version 3, its arrays prefixed ``library.``, its metadata ``"library"`` and the share ``"library_share"``;
the placement networks are then listed as in version 2 (``placement_members`` >= 1). Versions 1 and 2 are
read as before; a reader of those versions refuses a version 3 file rather than leave its part out.

A placement model alone is refused: it is meant to go with the field it was measured with.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field, replace

import numpy as np

from ..errors import ModelError
from . import garment_model, placement
from .model import FORMAT as SHARED_FORMAT
from .model import FORMAT_VERSION as SHARED_VERSION
from .model import SharedDeformationModel, need_format_version, read_model_arrays, save_npz_atomic
from .placement import LIBRARY_SHARE, MixedPlacement

BUNDLE_FORMAT = "garment_transfer.garment_fit_bundle"
#: The version written with a single placement model (or none); ``ENSEMBLE_BUNDLE_VERSION`` with several.
BUNDLE_VERSION = 1
ENSEMBLE_BUNDLE_VERSION = 2
#: The version written with the nearest garments' placement (``placement.NearestGarments``).
LIBRARY_BUNDLE_VERSION = 3
#: Placement members a bundle may hold (a damaged count is refused before anything is built).
MAX_PLACEMENT_MEMBERS = 64
#: The share of the garment fit model's field used by default (``GarmentFitModel.with_field_share``):
#: with the learned placement, half the field kept MDC at 0.93x direct transfer's with 0.63x its vertex
#: error on the demo's unseen test garments on pear (0.96x and 0.57x on heavy), where the whole field
#: gave 1.29x MDC at 0.59x (lab/notes/garment-model-study.md). Chosen again among 0, 0.25, 0.5, 0.75 and 1 on
#: held-out training garments: the lowest drape error with MDC at most 1.1x direct's.
DEFAULT_FIELD_SHARE = 0.5
#: What ``ModelFile.kind`` says.
KINDS = ("shared", "garment")


@dataclass
class ModelFile:
    """A model file as ``transfer_garment`` uses it.

    Attributes
    ----------
    path : str
    kind : {"shared", "garment"}
        The paper's shared deformation model, or the garment fit model.
    model : SharedDeformationModel or GarmentFitModel
        ``transfer_garment``'s ``model`` (the garment fit model with ``field_share`` applied).
    placement : placement.BlendedPlacement or None
        ``transfer_garment``'s ``placement``: the file's learned placement (a ``PlacementModel`` or a
        ``PlacementEnsemble``, or either mixed with the nearest garments' in a ``MixedPlacement``; blended
        over its training bodies for a body it was not trained on), unless left out.
    field_share : float or None
        The share of the garment fit model's field (None for the shared model).
    has_placement : bool
        Whether the file holds a placement (used or not).
    metadata : dict
        ``dataset`` (the training data's units and up axis) and ``targets``.
    """

    path: str
    kind: str
    model: object
    placement: object = None
    field_share: float | None = None
    has_placement: bool = False
    metadata: dict = field(default_factory=dict)

    @property
    def name(self):
        return self.path

    @property
    def targets(self) -> list:
        """The training targets' labels."""
        return list(self.model.targets)

    def transfer_arguments(self) -> dict:
        """``transfer_garment``'s ``model`` and ``placement`` (also ``transfer_outfit``'s)."""
        return {"model": self.model, "placement": self.placement}

    def with_field_share(self, share):
        """The same file with another share of the garment fit model's field (a ModelError for the shared
        model, which has none)."""
        if self.kind != "garment":
            raise ModelError(self.path, "holds the paper's shared deformation model, which has no field share "
                                        "(that is for a garment fit model)")
        share = float(share)
        return replace(self, model=self.model.with_field_share(share), field_share=share)

    def check_source_body(self, mesh):
        """Raise ModelError unless the model serves garments dressed on ``mesh``."""
        self.model.check_source_body(mesh)

    def summary(self) -> dict:
        """JSON-ready: ``model`` (file), ``model_kind``, ``field_share``, ``placement``, ``nearest_garments`` (the
        share of the nearest garments' placement in it, or None), ``targets``."""
        share = getattr(getattr(self.placement, "model", None), "share", None)
        return {"model": self.path, "model_kind": self.kind, "field_share": self.field_share,
                "placement": self.placement is not None, "nearest_garments": share, "targets": self.targets}

    def describe(self) -> str:
        """One line: which model, which share of its field, with or without the placement."""
        base = os.path.basename(self.path)
        if self.kind == "shared":
            return f"shared deformation model ({base})"
        text = f"garment fit model ({base}), field share {self.field_share:g}"
        if self.placement is not None:
            share = self.summary()["nearest_garments"]
            return text + (", learned placement" if share is None else
                           f", learned placement mixed with the nearest garments' at share {share:g}")
        return text + (", placement left out" if self.has_placement else ", no placement in the file")


def save_garment_fit_bundle(path, field_model, placement_model=None, dataset=None, inputs=(), library=None,
                            library_share=None):
    """Write a garment fit model and its learned placement to one ``.npz`` file, atomically.

    Parameters
    ----------
    path : str or Path
    field_model : garment_model.GarmentFitModel
    placement_model : placement.PlacementModel or placement.PlacementEnsemble, optional
        Trained on the same source body.
    library : placement.NearestGarments, optional
        The nearest garments' placement, mixed with ``placement_model``'s (needs one) at ``library_share``
        (default ``placement.LIBRARY_SHARE``).
    dataset : dict, optional
        ``folder``, ``units``, ``up_axis`` of the training data (the Blender layer reads the up axis).
    inputs : iterable of paths
        Files the model file must not be (``files.check_output``).
    """

    if placement_model is not None and not _same_source(field_model, placement_model):
        raise ModelError(os.fspath(path), "the field and placement models were trained on different source bodies")
    arrays = {f"field.{k}": np.asarray(v) for k, v in field_model.arrays.items()}
    members = getattr(placement_model, "members", None)
    if library is not None:

        if placement_model is None:
            raise ModelError(os.fspath(path), "the nearest garments' placement goes with the placement networks; "
                                              "none was given")
        library_share = LIBRARY_SHARE if library_share is None else float(library_share)
        MixedPlacement(placement_model, library, library_share)  # checks that the two fit together
    if members is not None and len(members) > MAX_PLACEMENT_MEMBERS:
        raise ModelError(os.fspath(path), f"the placement has {len(members)} members; a model file holds at most "
                                          f"{MAX_PLACEMENT_MEMBERS}")
    version, placement_md = BUNDLE_VERSION, None
    if members is not None and len(members) > 1:
        for i, m in enumerate(members):
            arrays.update({f"placement.{i}.{k}": np.asarray(v) for k, v in m.arrays.items()})
        version, placement_md = ENSEMBLE_BUNDLE_VERSION, [m.metadata for m in members]
    elif placement_model is not None:
        single = placement_model if members is None else members[0]
        arrays.update({f"placement.{k}": np.asarray(v) for k, v in single.arrays.items()})
        placement_md = single.metadata
    metadata = {"format": BUNDLE_FORMAT, "format_version": version,
                "field": field_model.metadata, "placement": placement_md,
                "dataset": dataset or field_model.metadata.get("dataset"),
                "source": field_model.metadata["source"], "targets": list(field_model.targets)}
    if version == ENSEMBLE_BUNDLE_VERSION:
        metadata["placement_members"] = len(members)
    if library is not None:
        if version == BUNDLE_VERSION:
            arrays = {(f"placement.0.{k[len('placement.'):]}" if k.startswith("placement.") else k): v
                      for k, v in arrays.items()}
            metadata["placement"] = [placement_md]
        metadata.update(format_version=LIBRARY_BUNDLE_VERSION, placement_members=len(metadata["placement"]),
                        library=library.metadata, library_share=library_share)
        arrays.update({f"library.{k}": np.asarray(v) for k, v in library.arrays.items()})
    save_npz_atomic(path, arrays, metadata, inputs=inputs)


def read_model_file(path, field_share=None, use_placement=True) -> ModelFile:
    """Read a model file of any kind (plain arrays only, ``allow_pickle=False``).

    Parameters
    ----------
    path : str or Path
    field_share : float, optional
        For a garment fit model: the share of its field, in [0, 1] (default ``DEFAULT_FIELD_SHARE``).
        Refused for the shared model, which has no such setting.
    use_placement : bool
        False leaves a bundle's placement out (the garment fit model's field alone).

    Raises
    ------
    ModelError
        Naming the file: missing, unreadable, pickled objects, a format or version this code does not
        read, arrays that do not fit together, parts trained on different bodies, a placement alone.
    """

    path = os.fspath(path)
    arrays, metadata = read_model_arrays(path)
    fmt = metadata.get("format")
    if fmt == SHARED_FORMAT:
        if field_share is not None:
            raise ModelError(path, "holds the paper's shared deformation model, which has no field share "
                                   "(that is for a garment fit model)")
        need_format_version(path, metadata, SHARED_VERSION)
        model = _build(path, SharedDeformationModel, arrays, metadata)
        return ModelFile(path, "shared", model, metadata={"dataset": metadata.get("dataset"),
                                                          "targets": model.targets})
    share = DEFAULT_FIELD_SHARE if field_share is None else float(field_share)
    if not 0.0 <= share <= 1.0:
        raise ValueError(f"the field share must be between 0 and 1, got {share}")
    if fmt == garment_model.FORMAT:
        need_format_version(path, metadata, garment_model.FORMAT_VERSION)
        model = _build(path, garment_model.GarmentFitModel, arrays, metadata)
        return ModelFile(path, "garment", model.with_field_share(share), field_share=share,
                         metadata={"dataset": metadata.get("dataset"), "targets": model.targets})
    if fmt == placement.FORMAT:
        raise ModelError(path, "holds a placement model alone; train with `train --kind garment`, which writes "
                               "the garment fit model and its placement in one file")
    if fmt != BUNDLE_FORMAT:
        raise ModelError(path, f"is not a garment transfer model (metadata 'format' is {fmt!r})")
    need_format_version(path, metadata, (BUNDLE_VERSION, ENSEMBLE_BUNDLE_VERSION, LIBRARY_BUNDLE_VERSION))
    members = _placement_members(path, metadata, metadata["format_version"])
    # (prefix of the arrays, metadata, module, what): the field model and each placement member.
    specs = [("field", metadata.get("field"), garment_model, "field")]
    if members is None:
        specs.append(("placement", metadata.get("placement"), placement, "placement"))
    else:
        specs += [(f"placement.{i}", md, placement, f"placement member {i}")
                  for i, md in enumerate(metadata["placement"])]
    parts = {}
    for prefix, md, module, what in specs:
        own = {k[len(prefix) + 1:]: v for k, v in arrays.items() if k.startswith(prefix + ".")}
        if md is None and prefix in ("field", "placement"):
            if prefix == "field":
                raise ModelError(path, "has no garment fit model ('field' metadata)")
            if own:
                raise ModelError(path, "has placement arrays but no placement metadata")
            continue
        if not isinstance(md, dict):
            raise ModelError(path, f"its {what!r} metadata is not a table")
        kind = "field" if prefix == "field" else "placement"
        if md.get("format") != module.FORMAT:
            raise ModelError(path, f"its {what!r} part is not a {kind} model (format {md.get('format')!r})")
        need_format_version(path, md, getattr(module, "FORMAT_VERSIONS", module.FORMAT_VERSION), f"its {what} model")
        if kind == "placement" and "smoothing_share" not in md:
            raise ModelError(path, f"its {what} metadata lacks 'smoothing_share'")
        parts[prefix] = (own, md)
    library = None
    if metadata["format_version"] == LIBRARY_BUNDLE_VERSION:
        library = _library(path, metadata, arrays)
    prefixes = [*parts, *(["library"] if library is not None else [])]
    strays = sorted(k for k in arrays if not any(k.startswith(p + ".") for p in prefixes))
    if strays:
        raise ModelError(path, f"has arrays of no part: {', '.join(strays[:5])}")
    model = _build(path, garment_model.GarmentFitModel, *parts.pop("field"))
    placed = None
    if parts:
        built = [_build(path, placement.PlacementModel, own, md) for own, md in parts.values()]
        if not all(_same_source(model, m) for m in built):
            raise ModelError(path, "its field and placement models were trained on different source bodies")
        # One member: the model itself (the same prediction as an ensemble of one).
        placed = built[0] if members is None or len(built) == 1 else placement.PlacementEnsemble(built, path)
    if library is not None:
        if placed is None:
            raise ModelError(path, "has the nearest garments' placement but no placement networks to mix it with")
        if not _same_source(model, library):
            raise ModelError(path, "its field model and nearest garments' placement were made on different source "
                                   "bodies")
        mix = metadata.get("library_share")
        if isinstance(mix, bool) or not isinstance(mix, (int, float)) or not 0.0 <= mix <= 1.0:
            raise ModelError(path, f"has a bad 'library_share' ({mix!r}): a number between 0 and 1")
        placed = placement.MixedPlacement(placed, library, float(mix))
    # A body the placement was not trained on gets the blend of its training bodies' placements (on the
    # demo's hourglass held out: 1.23x the error of a training body against 1.48x for the network's own
    # prediction at the mixed label); a training body gets the network's own.
    used = placement.BlendedPlacement(placed) if placed is not None and use_placement else None
    return ModelFile(path, "garment", model.with_field_share(share), used,
                     field_share=share, has_placement=placed is not None,
                     metadata={"dataset": metadata.get("dataset"), "targets": model.targets})


def _placement_members(path, metadata, version):
    """How many placement members a bundle holds: None for version 1 (one placement model or none); for
    versions 2 and 3 the checked ``placement_members``, which its ``placement`` metadata list must match."""
    count = metadata.get("placement_members")
    if version == BUNDLE_VERSION:
        if count is not None:
            raise ModelError(path, f"has 'placement_members' ({count!r}), which format version {BUNDLE_VERSION} "
                                   "does not have")
        return None
    least = 2 if version == ENSEMBLE_BUNDLE_VERSION else 1
    if isinstance(count, bool) or not isinstance(count, int) or not least <= count <= MAX_PLACEMENT_MEMBERS:
        raise ModelError(path, f"has a bad 'placement_members' ({count!r}): a format version "
                               f"{version} file holds {least} to {MAX_PLACEMENT_MEMBERS} placement "
                               "members")
    listed = metadata.get("placement")
    if not isinstance(listed, list) or len(listed) != count:
        have = f"{len(listed)} entries" if isinstance(listed, list) else type(listed).__name__
        raise ModelError(path, f"says it holds {count} placement members, but its 'placement' metadata has "
                               f"{have}")
    return count


def _library(path, metadata, arrays):
    """The nearest garments' placement of a version 3 bundle, checked (a ModelError naming the file)."""

    md = metadata.get("library")
    if not isinstance(md, dict):
        raise ModelError(path, "has no nearest garments' placement ('library' metadata), which format version "
                               f"{LIBRARY_BUNDLE_VERSION} has")
    if md.get("format") != placement.LIBRARY_FORMAT:
        raise ModelError(path, f"its 'library' part is not a nearest garments' placement (format {md.get('format')!r})")
    need_format_version(path, md, placement.LIBRARY_FORMAT_VERSION, "its nearest garments' placement")
    own = {k[len("library."):]: v for k, v in arrays.items() if k.startswith("library.")}
    return _build(path, placement.NearestGarments, own, md)


def _same_source(field_model, placement_model):
    """Whether the two models were trained on the same source body mesh (its faces' hash)."""
    return placement_model.metadata["source"].get("faces_hash") == field_model.metadata["source"].get("faces_hash")


def _build(path, cls, arrays, metadata):
    """``cls(arrays, metadata, path)``; metadata of the wrong shape is a ModelError naming the file."""
    try:
        return cls(arrays, metadata, path)
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise ModelError(path, f"its metadata is damaged ({type(exc).__name__}: {exc})") from None
