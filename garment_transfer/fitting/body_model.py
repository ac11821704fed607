"""A body model's shape space as a shape basis of the source body: MakeHuman's targets.

MakeHuman's bodies are its base mesh (hm08) plus a weighted sum of its *targets*: sparse vertex deltas
("measure-hips-circ-incr", "universal-female-young-averagemuscle-maxweight", ...), CC0. A source body
that is an hm08 body (a MakeHuman or MPFB export without helper geometry: 13,380 vertices) can use
them as its shape basis (``registration.register(..., shape_basis=, shape_bounds=,
body_model=True)``): the registration then fits the source as the body model would make the
target, and the model carries the correspondence along the limbs and around the torso.

The targets are read from MakeHuman's compiled archive ``makehuman/data/targets.npz`` (in the
``makehuman`` wheel on PyPI; ``pip download --no-deps makehuman==1.3.2``): for each target
``targets/<group>/<name>.index.npy`` (vertex indices into the hm08 mesh) and ``.vector.npy`` (int16
deltas in thousandths of a decimetre, Y up, +Z forward). Members are read with
``allow_pickle=False``; nothing is downloaded here.

The columns of the basis are one per *slider*: a ``-decr`` / ``-incr`` (``-down`` / ``-up``,
``-in`` / ``-out``, ``-backward`` / ``-forward``) pair whose two deltas point opposite ways is one
signed column, and the gender is one column (the male less the female ethnic targets, averaged over
the three ethnic groups) beside the ethnic targets themselves. Only the young adult targets are kept;
the hands', fingers' and feet's own targets are left out (registration fits the hands and feet as
wholes). Every weight is bounded by -1 and 1.
"""

from __future__ import annotations

import io
import re
import zipfile
from dataclasses import dataclass

import numpy as np

from ..errors import MeshError, TopologyMismatchError
from ..geometry.mesh import Mesh
from .alignment import units_scale

#: Vertices of the hm08 base mesh's body (the rest of the mesh is helper geometry that OBJ exports omit).
HM08_BODY_VERTICES = 13380
#: Target groups used by default: the whole body, not the face.
DEFAULT_GROUPS = ("macrodetails", "measure", "hip", "buttocks", "torso", "stomach", "pelvis", "armslegs",
                  "neck", "breast", "bodyshapes")
#: The targets' deltas are int16 in thousandths of a decimetre (MakeHuman's unit).
TARGET_UNIT = 1e-3
#: A -decr / -incr pair is one signed column when the cosine between one delta and the other's
#: opposite is at least this.
OPPOSITE_COS = 0.9
_PAIRS = (("-decr", "-incr"), ("-down", "-up"), ("-in", "-out"), ("-backward", "-forward"))
_LEFT_OUT = re.compile(r"(baby|child|old)")
_HAND_FOOT = re.compile(r"(finger|hand-|foot-)")
#: Heights a MakeHuman body may have, in decimetres (for the units check of the source).
_HEIGHT_DM = (12.0, 24.0)


@dataclass
class BodyModelBasis:
    """A shape basis from a body model, in the source body's units and axes.

    Attributes
    ----------
    names : list of str
        One per column: the target (``group/name``), ``group/name(+-)`` for a signed pair (positive
        towards the second of the pair), or ``macrodetails/gender``.
    basis : (k, n, 3) float64
        Deltas of the source body, in its units and axes.
    bounds : (k, 2) float64
        Bounds of each weight.
    path : str
        The archive read.
    units : float
        Source units per decimetre (1 for MakeHuman's OBJ files, 0.1 for metres).
    up : str
        The source's up axis: ``"Y"`` (MakeHuman's own) or ``"Z"`` (Blender's; its forward axis is -Y).
    """

    names: list
    basis: np.ndarray
    bounds: np.ndarray
    path: str
    units: float
    up: str


def _read_member(zf, name, path):
    from numpy.lib import format as npformat

    try:
        with zf.open(name) as fh:
            return npformat.read_array(io.BytesIO(fh.read()), allow_pickle=False)
    except (ValueError, OSError, zipfile.BadZipFile, KeyError) as exc:
        raise MeshError(str(path), f"member {name} is not a plain numpy array ({exc})") from None


def read_makehuman_targets(path, groups=DEFAULT_GROUPS):
    """MakeHuman's targets of the given groups as dense deltas of the hm08 body vertices.

    Parameters
    ----------
    path : str or Path
        MakeHuman's ``targets.npz``.
    groups : sequence of str
        Target groups (the folder under ``targets/``).

    Returns
    -------
    names : list of str
        ``group/name`` of each target kept (young adults; not the hands', fingers' or feet's own).
    deltas : (k, 13380, 3) float64
        In decimetres, MakeHuman's axes (Y up, +Z forward). Targets that do not move a body vertex
        are left out.
    """
    path = str(path)
    try:
        zf = zipfile.ZipFile(path)
    except FileNotFoundError:
        raise MeshError(path, "file not found (MakeHuman's targets.npz: pip download --no-deps "
                              "makehuman==1.3.2, then unzip makehuman/data/targets.npz)") from None
    except (zipfile.BadZipFile, OSError) as exc:
        raise MeshError(path, f"not a MakeHuman targets archive (.npz): {exc}") from None
    groups = set(groups)
    with zf:
        members = set(zf.namelist())
        stems = sorted(m[:-len(".index.npy")] for m in members
                       if m.startswith("targets/") and m.endswith(".index.npy"))
        if not stems:
            raise MeshError(path, "holds no targets/<group>/<name>.index.npy members: not MakeHuman's "
                                  "targets.npz")
        names, deltas = [], []
        for stem in stems:
            parts = stem.split("/")
            group, base = parts[1], parts[-1]
            if group not in groups or _LEFT_OUT.search(base):
                continue
            if group == "armslegs" and _HAND_FOOT.search(base):
                continue
            if stem + ".vector.npy" not in members:
                raise MeshError(path, f"target {stem} has indices but no {stem}.vector.npy")
            index = _read_member(zf, stem + ".index.npy", path)
            vector = _read_member(zf, stem + ".vector.npy", path)
            if (index.ndim != 1 or not np.issubdtype(index.dtype, np.integer) or vector.ndim != 2
                    or vector.shape != (index.shape[0], 3) or not np.issubdtype(vector.dtype, np.number)):
                raise MeshError(path, f"target {stem}: indices {index.shape} {index.dtype} and deltas "
                                      f"{vector.shape} {vector.dtype} do not match (n indices, n x 3 deltas)")
            index = index.astype(np.int64)
            if index.size and index.min() < 0:
                raise MeshError(path, f"target {stem} has a negative vertex index")
            body = index < HM08_BODY_VERTICES
            if not body.any():
                continue
            d = np.zeros((HM08_BODY_VERTICES, 3))
            d[index[body]] = vector[body].astype(np.float64) * TARGET_UNIT
            if not np.isfinite(d).all():
                raise MeshError(path, f"target {stem} has non-finite deltas")
            if np.abs(d).max() == 0.0:
                continue
            names.append("/".join(parts[1:]))
            deltas.append(d)
    if not names:
        raise MeshError(path, f"holds no body targets in the groups {sorted(groups)}")
    return names, np.stack(deltas)


def slider_columns(names, deltas):
    """One column per slider: opposite pairs merged into one signed column, and a gender column.

    Returns
    -------
    names : list of str
    columns : (k, n, 3) float64
    """
    index = {n: i for i, n in enumerate(names)}
    out_names, cols, done = [], [], set()
    for name in names:
        if name in done:
            continue
        d = deltas[index[name]]
        merged = False
        for a, b in _PAIRS:
            if name.endswith(a) and name[:-len(a)] + b in index:
                other = name[:-len(a)] + b
                e = deltas[index[other]]
                cos = -float((d * e).sum()) / max(float(np.linalg.norm(d) * np.linalg.norm(e)), 1e-300)
                if cos >= OPPOSITE_COS:
                    out_names.append(other + "(+-)")
                    cols.append(0.5 * (e - d))
                    done.update((name, other))
                    merged = True
                break
        if not merged:
            done.add(name)
            out_names.append(name)
            cols.append(d)
    male = [n for n in names if re.fullmatch(r"macrodetails/(african|asian|caucasian)-male-young", n)]
    pairs = [(m, m.replace("-male-", "-female-")) for m in male if m.replace("-male-", "-female-") in index]
    if pairs:
        out_names.append("macrodetails/gender")
        cols.append(np.mean([deltas[index[m]] - deltas[index[f]] for m, f in pairs], axis=0))
    return out_names, np.stack(cols)


def _units_and_up(source: Mesh):
    """Source units per decimetre and its up axis, from its extents (an upright person)."""

    used = np.unique(source.face_vertices) if source.face_vertices.size else np.arange(source.n_vertices)
    ext = np.ptp(np.asarray(source.V)[used], axis=0)
    up_index = int(np.argmax(ext))
    if up_index not in (1, 2):
        raise MeshError(source.name, f"is longest along X ({ext.round(4).tolist()}): a MakeHuman body stands "
                                     f"along Y (MakeHuman's files) or Z (Blender)")
    height = float(ext[up_index])
    units = units_scale(height / 17.0)[0]
    if not (_HEIGHT_DM[0] <= height / units <= _HEIGHT_DM[1]):
        raise MeshError(source.name, f"is {height:.4g} units tall, which is no known unit of a person's "
                                     f"height (MakeHuman's files are in decimetres)")
    return units, "YZ"[up_index - 1]


def makehuman_shape_basis(source: Mesh, path, groups=DEFAULT_GROUPS, exclude_groups=()) -> BodyModelBasis:
    """A shape basis of an hm08 source body from MakeHuman's targets archive.

    Parameters
    ----------
    source : Mesh
        The source body: MakeHuman's hm08 body (13,380 vertices, its vertex order), upright along Y
        (MakeHuman's files) or Z (Blender), in any known unit.
    path : str or Path
        MakeHuman's ``targets.npz``.
    groups : sequence of str
        Target groups to use (``DEFAULT_GROUPS``).
    exclude_groups : sequence of str
        Groups left out of ``groups``.

    Returns
    -------
    BodyModelBasis

    Raises
    ------
    TopologyMismatchError
        The source is not an hm08 body (the message names the archive and the vertex counts).
    MeshError
        An archive that is not MakeHuman's targets, or a source that is not upright or not of a
        person's height in a known unit.
    """
    if source.n_vertices != HM08_BODY_VERTICES:
        raise TopologyMismatchError(
            source.name, f"has {source.n_vertices} vertices, but the targets of {path} are for MakeHuman's "
                         f"hm08 body ({HM08_BODY_VERTICES} vertices, exported without helper geometry): "
                         f"a body model basis needs a source body of that mesh")
    units, up = _units_and_up(source)
    keep = [g for g in groups if g not in set(exclude_groups)]
    names, deltas = read_makehuman_targets(path, keep)
    names, cols = slider_columns(names, deltas)
    cols = cols * units
    if up == "Z":
        # MakeHuman (x, y, z) with Y up and +Z forward is Blender's (x, -z, y).
        cols = np.stack([cols[..., 0], -cols[..., 2], cols[..., 1]], axis=-1)
    bounds = np.tile([-1.0, 1.0], (len(names), 1))
    return BodyModelBasis(names=names, basis=np.ascontiguousarray(cols), bounds=bounds, path=str(path),
                          units=float(units), up=up)
