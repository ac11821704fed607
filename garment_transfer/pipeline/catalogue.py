"""A catalogue: which garments, dressed on which source body, go to which target bodies, and how.

A catalogue is a JSON or TOML file (the keys: ``catalogue_from_dict``; the user's guide: docs/batch.md) or a
dataset folder (``bodies/<body>.obj``, ``garments/<garment>/<body>.obj``; see ``learning.dataset``). Reading one
checks it whole before any work: every problem is a ``CatalogueError`` naming the file and the entry. What a
catalogue becomes is plain data (``Catalogue``, ``GarmentJob``, ``Target``, ``Settings``, ``RigFiles``), which
``batch.run_batch`` runs.
"""

from __future__ import annotations

import json
import math
import os
import re
from dataclasses import dataclass, replace
from pathlib import Path

from ..errors import DatasetError
from ..learning.dataset import dataset_inputs, load_dataset

METHODS = ("direct", "model", "surface")
SETTING_KEYS = ("method", "model", "offset", "fix_penetration", "interpolate", "stiffness", "field_share",
                "placement", "untangle")
ENTRY_KEYS = ("name", "file", "source", "targets", "labels", "references", *SETTING_KEYS)
TOP_KEYS = ("format", "settings", "bodies", "garments", "source", "targets", "labels", "rig")
RIG_KEYS = ("skeleton", "weights", "joints")
_NAME = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.+-]*$")


class CatalogueError(DatasetError):
    """A catalogue that cannot be run as written: names the file and the entry."""


@dataclass(frozen=True)
class Settings:
    """How every pair of a garment is transferred (see ``transfer.transfer_garment``)."""

    method: str = "direct"
    model: str | None = None
    offset: float | None = None
    fix_penetration: bool = True
    interpolate: bool = True
    stiffness: float | None = None
    #: For a garment fit model file: the share of its field (None: ``model_files.DEFAULT_FIELD_SHARE``).
    field_share: float | None = None
    #: For a garment fit model file: whether its learned placement is used (where the file holds one).
    placement: bool = True
    #: A target in another rest pose: undo where posing the source folds the cloth through itself
    #: (``rest_pose.transfer_across_rest_poses``).
    untangle: bool = False


@dataclass(frozen=True)
class Target:
    """One target body of a garment: its name (the result's file name), file, model label, reference."""

    name: str
    body: str
    label: str | None = None
    reference: str | None = None
    #: The skeleton's joints on this body (a joints file), where the catalogue has a ``rig``.
    joints: str | None = None


@dataclass(frozen=True)
class RigFiles:
    """The catalogue's ``rig``, as one garment's source body has it: the skeleton, the source body's weights and
    its joints (files); each target with joints of its own that stands in another pose is posed into
    (``rest_pose.transfer_across_rest_poses``)."""

    skeleton: str
    weights: str
    source_joints: str


@dataclass(frozen=True)
class GarmentJob:
    """One garment and all its targets: the unit of work.

    Attributes
    ----------
    name : str
        The garment's name: its results go to ``<out>/<name>/``.
    file : str
        The garment on the source body (OBJ).
    source : str
        The source body's name.
    source_file : str
        The source body (OBJ).
    targets : tuple of Target
    settings : Settings
    entry : str
        Where the catalogue defines it (for messages).
    """

    name: str
    file: str
    source: str
    source_file: str
    targets: tuple
    settings: Settings
    entry: str = ""
    rig: RigFiles | None = None


@dataclass
class Catalogue:
    """Garments to transfer, in order.

    Attributes
    ----------
    origin : str
        The catalogue file or dataset folder.
    jobs : list of GarmentJob
    """

    origin: str
    jobs: list

    @property
    def n_pairs(self) -> int:
        return sum(len(j.targets) for j in self.jobs)

    def pairs(self):
        """``(garment, target)`` names of every pair, in catalogue order."""
        return [(j.name, t.name) for j in self.jobs for t in j.targets]

    def inputs(self):
        """Everything a run of the catalogue reads: ``(files, folders)``.

        The catalogue file and every file it names (garments, bodies, references, models); for a
        dataset folder, what reading it reads (``dataset.dataset_inputs``) and the files.
        """
        files, folders = ([], []) if not os.path.isdir(self.origin) else dataset_inputs(self.origin)
        if not folders:
            files.append(self.origin)
        for j in self.jobs:
            files += [j.file, j.source_file, j.settings.model]
            files += [p for t in j.targets for p in (t.body, t.reference, t.joints)]
            if j.rig is not None:
                files += [j.rig.skeleton, j.rig.weights, j.rig.source_joints]
        return list(dict.fromkeys(p for p in files if p is not None)), folders


def read_catalogue(path, *, source=None, targets=None, garments=None, settings=None) -> Catalogue:
    """Read and check a catalogue: a ``.json`` or ``.toml`` file, or a dataset folder.

    Parameters
    ----------
    path : str or Path
    source : str, optional
        For a dataset folder: the source body's name (else the manifest's ``"source"``).
    targets : list of str, optional
        For a dataset folder: target bodies (default: every other body).
    garments : list of str, optional
        For a dataset folder: garments (default: every garment dressed on the source body).
    settings : dict, optional
        Settings (``SETTING_KEYS``) over the catalogue's own defaults, for every garment that does
        not set them itself.

    Raises
    ------
    CatalogueError
        Naming the file and the entry: unreadable or malformed file, unknown key, body or method,
        bad value, a garment listed twice, a model method without a model.
    """
    # Absolute: workers on other machines, or in another folder, read the same paths.
    path = Path(os.fspath(path)).absolute()
    if path.is_dir():
        return catalogue_from_dataset(path, source=source, targets=targets, garments=garments,
                                      settings=settings)
    if not path.is_file():
        raise CatalogueError(str(path), "catalogue not found (a .json or .toml file, or a dataset folder)")
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise CatalogueError(str(path), f"cannot be read ({exc.strerror or exc})") from None
    suffix = path.suffix.lower()
    try:
        if suffix == ".json":
            data = json.loads(raw.decode("utf-8"))
        elif suffix == ".toml":
            import tomllib

            data = tomllib.loads(raw.decode("utf-8"))
        else:
            raise CatalogueError(str(path), "a catalogue file must end in .json or .toml")
    except UnicodeDecodeError:
        raise CatalogueError(str(path), "is not UTF-8 text") from None
    except ValueError as exc:
        if isinstance(exc, CatalogueError):
            raise
        raise CatalogueError(str(path), f"is not valid {suffix[1:].upper()} ({exc})") from None
    if not isinstance(data, dict):
        raise CatalogueError(str(path), "must hold an object (a table) at the top")
    if settings:
        data = dict(data, settings={**(data.get("settings") or {}), **settings})
    if source is not None:
        data = dict(data, source=source)
    if targets is not None:
        data = dict(data, targets=list(targets))
    cat = catalogue_from_dict(data, base=path.parent, origin=str(path))
    if garments is not None:
        cat = _select(cat, garments)
    return cat


def _select(cat, garments):
    known = {j.name: j for j in cat.jobs}
    unknown = [g for g in garments if g not in known]
    if unknown:
        raise CatalogueError(cat.origin, f"has no garment {', '.join(map(repr, unknown))}")
    return Catalogue(cat.origin, [known[g] for g in garments])


def catalogue_from_dict(data: dict, base=".", origin="catalogue") -> Catalogue:
    """A catalogue from its JSON/TOML content.

    Keys (``?`` optional)::

        format?    1
        settings?  {method?, model?, offset?, fix_penetration?, interpolate?, stiffness?, untangle?}
                   defaults for every garment (method "direct"; model: a .npz file, for "model")
        bodies     {name: "path/to/body.obj", ...}  every body, source and targets, one topology
        source?    default source body name
        targets?   default target body names
        labels?    {body: model label} for method "model" (default: the body's name)
        rig?       {skeleton, weights, joints: {body: joints file}}: MakeHuman's layouts (``rigging``); a
                   target whose joints stand in another pose than its garment's source body's gets the
                   source and the garment posed into it first
        garments   [{name, file, source?, targets?, labels?, references?, <any setting>?}, ...]
                   targets: body names, or {body, label?, reference?};
                   references: {body: "garment simulated or fitted on that body.obj"} (metrics)

    Relative paths are relative to ``base`` (the catalogue's folder).

    Raises
    ------
    CatalogueError
        Naming ``origin`` and the entry (``garments[3] 'shirt'``).
    """
    base = Path(os.fspath(base))

    def fail(where, problem):
        raise CatalogueError(f"{origin}: {where}" if where else origin, problem)

    _unknown_keys(data, TOP_KEYS, "", fail)
    if data.get("format", 1) != 1:
        fail("format", f"format {data.get('format')!r} is not known to this version (1)")
    defaults = _settings(data.get("settings") or {}, Settings(), base, "settings", fail)
    bodies_raw = data.get("bodies")
    if not isinstance(bodies_raw, dict) or not bodies_raw:
        fail("bodies", "a table of body name = OBJ path is needed (every body: source and targets)")
    bodies = {}
    for name, p in bodies_raw.items():
        if name in ("source", "targets", "labels") and not (isinstance(p, str) and p.lower().endswith(".obj")):
            # TOML: a key written after [bodies] belongs to that table.
            fail(f"bodies.{name}", f"{name!r} is a top-level key: in TOML, write source, targets and labels "
                                   "above the first [table]; after [bodies] they belong to it")
        _check_name(name, f"bodies.{name}", fail)
        bodies[name] = _path(p, base, f"bodies.{name}", fail)
    top_labels = _labels(data.get("labels"), bodies, "labels", fail)
    rig, joints = _rig(data.get("rig"), bodies, base, fail)
    entries = data.get("garments")
    if not isinstance(entries, list) or not entries:
        fail("garments", "a list of garments is needed (each with name and file)")
    jobs, seen = [], {}
    for i, entry in enumerate(entries):
        where = f"garments[{i}]"
        if not isinstance(entry, dict):
            fail(where, "must be a table with name and file")
        name = entry.get("name")
        if name is not None:
            where = f"garments[{i}] {name!r}"
        _unknown_keys(entry, ENTRY_KEYS, where, fail)
        _check_name(name, where + " name", fail)
        if name in seen:
            fail(where, f"the name is already used by garments[{seen[name]}]; results would collide")
        seen[name] = i
        if "file" not in entry:
            fail(where, "has no file (the garment on its source body, OBJ)")
        gfile = _path(entry["file"], base, where + " file", fail)
        settings = _settings(entry, defaults, base, where, fail)
        source = entry.get("source", data.get("source"))
        if source is None:
            fail(where, "has no source body (set source here or at the top)")
        source_name, source_file = _body(source, bodies, base, where + " source", fail)
        raw_targets = entry.get("targets", data.get("targets"))
        if not isinstance(raw_targets, list) or not raw_targets:
            fail(where, "has no targets (a list of body names, here or at the top)")
        labels = {**top_labels, **_labels(entry.get("labels"), bodies, where + " labels", fail)}
        refs = entry.get("references") or {}
        if not isinstance(refs, dict):
            fail(where + " references", "must be a table of body name = OBJ path")
        targets, names = [], set()
        for k, t in enumerate(raw_targets):
            twhere = f"{where} targets[{k}]"
            label, ref = None, None
            if isinstance(t, dict):
                _unknown_keys(t, ("body", "label", "reference"), twhere, fail)
                label, ref, t = t.get("label"), t.get("reference"), t.get("body")
            tname, tfile = _body(t, bodies, base, twhere, fail)
            if tname in names:
                fail(twhere, f"{tname!r} is listed twice")
            if tname == source_name:
                fail(twhere, f"{tname!r} is the source body")
            names.add(tname)
            label = label if label is not None else labels.get(tname)
            if label is not None and not isinstance(label, str):
                fail(twhere, "label must be a string")
            ref = ref if ref is not None else refs.get(tname)
            ref = None if ref is None else _path(ref, base, twhere + " reference", fail)
            if settings.method == "model" and label is None:
                label = tname
            targets.append(Target(tname, tfile, label, ref, joints.get(tname)))
        for body in refs:
            if body not in names:
                fail(where + " references", f"{body!r} is not one of its targets")
        job_rig = None if rig is None or source_name not in joints else RigFiles(*rig, joints[source_name])
        jobs.append(GarmentJob(name, gfile, source_name, source_file, tuple(targets), settings, where, job_rig))
    return Catalogue(origin, jobs)


def _rig(raw, bodies, base, fail):
    """The catalogue's ``rig`` table: ((skeleton, weights) paths, {body: joints path}), or (None, {})."""
    if raw is None:
        return None, {}
    if not isinstance(raw, dict):
        fail("rig", "must be a table with skeleton, weights and joints")
    _unknown_keys(raw, RIG_KEYS, "rig", fail)
    missing = [k for k in RIG_KEYS if k not in raw]
    if missing:
        fail("rig", f"needs {', '.join(missing)} (skeleton and weights files, and a table of body = joints file)")
    if not isinstance(raw["joints"], dict) or not raw["joints"]:
        fail("rig.joints", "must be a table of body name = joints file")
    joints = {}
    for body, p in raw["joints"].items():
        if body not in bodies:
            fail(f"rig.joints.{body}", f"{body!r} is not a body of the catalogue; its bodies are: "
                                       f"{', '.join(sorted(bodies))}")
        joints[body] = _path(p, base, f"rig.joints.{body}", fail)
    return (_path(raw["skeleton"], base, "rig.skeleton", fail), _path(raw["weights"], base, "rig.weights", fail)), \
        joints


def _unknown_keys(d, allowed, where, fail):
    unknown = [k for k in d if k not in allowed]
    if unknown:
        fail(where, f"unknown key {', '.join(map(repr, unknown))}; known keys: {', '.join(allowed)}")


def _check_name(name, where, fail):
    if not isinstance(name, str) or not _NAME.match(name):
        fail(where, f"{name!r} is not a usable name: letters, digits, _ . + - (it names result files)")


def _path(p, base, where, fail) -> str:
    if not isinstance(p, str) or not p:
        fail(where, "must be a file path (a string)")
    if re.match(r"^[a-zA-Z][a-zA-Z0-9+.-]*://", p):
        fail(where, f"{p!r}: URLs are not read; give a path every worker sees (a shared filesystem, "
                    "or the object store mounted as one: see docs/batch.md)")
    return str(base / os.path.expanduser(p))


def _body(ref, bodies, base, where, fail):
    """A body given by name (``bodies`` table) or as an OBJ path (named by its file name)."""
    if isinstance(ref, str) and ref in bodies:
        return ref, bodies[ref]
    if isinstance(ref, str) and ref.lower().endswith(".obj"):
        name = Path(ref).stem
        _check_name(name, where, fail)
        return name, _path(ref, base, where, fail)
    fail(where, f"{ref!r} is not a body of the catalogue; its bodies are: {', '.join(bodies)}")


def _labels(raw, bodies, where, fail):
    if raw is None:
        return {}
    if not isinstance(raw, dict) or not all(isinstance(v, str) for v in raw.values()):
        fail(where, "must be a table of body name = model label")
    return dict(raw)


def _settings(d, defaults: Settings, base, where, fail) -> Settings:
    if where == "settings":
        _unknown_keys(d, SETTING_KEYS, where, fail)
    values = {}
    for key in SETTING_KEYS:
        if key not in d:
            continue
        v = d[key]
        if key == "method":
            if v not in METHODS:
                fail(where, f"method {v!r} is unknown; choose one of {', '.join(METHODS)}")
        elif key == "model":
            v = None if v is None else _path(v, base, f"{where} model", fail)
        elif key in ("offset", "stiffness"):
            if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float))
                                  or not math.isfinite(v) or v < 0 or (key == "stiffness" and v == 0)):
                fail(where, f"{key} must be a {'non-negative' if key == 'offset' else 'positive'} "
                            f"number in the files' units, not {v!r}")
            v = None if v is None else float(v)
        elif key == "field_share":
            if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float))
                                  or not 0.0 <= v <= 1.0):
                fail(where, f"field_share must be a number from 0 to 1, not {v!r}")
            v = None if v is None else float(v)
        elif not isinstance(v, bool):
            fail(where, f"{key} must be true or false, not {v!r}")
        values[key] = v
    s = replace(defaults, **values)
    if s.method == "model" and not s.model:
        fail(where, "method 'model' needs a model file (settings.model)")
    return s


def catalogue_from_dataset(folder, *, source=None, targets=None, garments=None, settings=None) -> Catalogue:
    """A catalogue from a dataset folder: its garments on ``source``, to every other body (or ``targets``).

    A garment file on a target body, where there is one, is the pair's reference for the metrics.

    Raises
    ------
    CatalogueError
        No source body given, an unknown body or garment, a garment not dressed on the source body.
    """

    try:
        ds = load_dataset(Path(os.fspath(folder)).absolute())
    except DatasetError as exc:
        raise CatalogueError(exc.name, exc.problem) from None
    origin = str(ds.folder)
    source = source or ds.manifest.get("source")
    if not source:
        raise CatalogueError(origin, f"say which body the garments are dressed on (--source); "
                                     f"its bodies are: {', '.join(ds.bodies)}")
    targets = [b for b in ds.bodies if b != source] if targets is None else list(targets)
    try:
        for b in [source, *targets]:
            ds.require_body(b)
        for g in garments or []:
            ds.require_garment(g)
    except DatasetError as exc:
        raise CatalogueError(exc.name, exc.problem) from None
    if garments is None:
        garments = [g for g in ds.garments if ds.has_garment(g, source)]
        if not garments:
            raise CatalogueError(origin, f"no garment is dressed on the source body {source!r}")
    entries = []
    for g in garments:
        refs = {t: os.fspath(ds.garment_path(g, t)) for t in targets if ds.has_garment(g, t)}
        entries.append({"name": g, "file": os.fspath(ds.garment_path(g, source)), "references": refs})
    data = {"bodies": {b: os.fspath(ds.folder / "bodies" / f"{b}.obj") for b in ds.bodies},
            "source": source, "targets": targets, "garments": entries, "settings": settings or {}}
    return catalogue_from_dict(data, base=ds.folder, origin=origin)
