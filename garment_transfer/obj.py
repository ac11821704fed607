"""Wavefront OBJ reading and writing.

Reading keeps the file's own lines, so a result written "like" its source keeps the source's
faces, UVs, normals, groups and materials: only the ``v`` lines change. Writing is atomic: a
temporary file in the same folder, renamed over the target once complete.
"""

from __future__ import annotations

import os

import numpy as np

from .errors import MeshError
from .files import write_text_atomic
from .mesh import Mesh, mesh_from_polygons


def read_obj(path, name=None) -> Mesh:
    """Read an OBJ file into a Mesh (polygons triangulated, original faces kept).

    Raises
    ------
    MeshError
        Naming the file: missing, unreadable, malformed lines, bad indices, NaN/inf, no faces.
    """
    path = os.fspath(path)
    name = name or path
    try:
        with open(path, "r", encoding="utf-8", errors="replace") as fh:
            text = fh.read()
    except FileNotFoundError:
        raise MeshError(name, "file not found") from None
    except IsADirectoryError:
        raise MeshError(name, "is a folder, not an OBJ file") from None
    except OSError as exc:
        raise MeshError(name, f"cannot be read ({exc.strerror or exc})") from None
    if "\x00" in text[:4096]:
        raise MeshError(name, "is not a text OBJ file (binary content)")
    lines = text.splitlines()
    verts, polys = [], []
    for lineno, line in enumerate(lines, 1):
        if line.startswith("v "):
            parts = line.split()
            if len(parts) < 4:
                raise MeshError(name, f"line {lineno}: a vertex needs 3 coordinates: {line.strip()[:60]!r}")
            try:
                verts.append((float(parts[1]), float(parts[2]), float(parts[3])))
            except ValueError:
                raise MeshError(name, f"line {lineno}: not a number in {line.strip()[:60]!r}") from None
        elif line.startswith("f "):
            parts = line.split()[1:]
            try:
                idx = [int(p.split("/", 1)[0]) for p in parts]
            except ValueError:
                raise MeshError(name, f"line {lineno}: bad face {line.strip()[:60]!r}") from None
            n = len(verts)
            idx = [i - 1 if i > 0 else n + i for i in idx]
            if any(i < 0 for i in idx) or 0 in [int(p.split("/", 1)[0]) for p in parts]:
                raise MeshError(name, f"line {lineno}: face index out of range in {line.strip()[:60]!r}")
            if len(idx) < 3:
                raise MeshError(name, f"line {lineno}: a face needs at least 3 vertices")
            polys.append(idx)
    if not verts:
        raise MeshError(name, "has no vertices (is it an OBJ file?)")
    if not polys:
        raise MeshError(name, "has no faces (a point cloud or lines only)")
    V = np.asarray(verts, dtype=np.float64)
    if max(max(p) for p in polys) >= V.shape[0]:
        raise MeshError(name, f"a face refers to vertex beyond the {V.shape[0]} the file has")
    if all(len(p) == len(polys[0]) for p in polys):
        polys = np.asarray(polys, dtype=np.int64)
    return mesh_from_polygons(V, polys, name=name, obj_lines=lines)


def _format_vertices(V, digits=9):
    fmt = f"v %.{digits}g %.{digits}g %.{digits}g"
    return [fmt % tuple(v) for v in V]


def obj_text(mesh: Mesh, V=None, header=None, digits=9) -> str:
    """OBJ text of ``mesh`` with vertex positions ``V`` (default: the mesh's own).

    A mesh read from a file keeps every non-vertex line of that file; others get plain
    ``v``/``f`` lines with their original polygons. ``digits``: significant digits per coordinate.
    """
    V = mesh.V if V is None else np.asarray(V, dtype=np.float64)
    if V.shape != mesh.V.shape:
        raise MeshError(mesh.name, f"cannot write {V.shape[0]} vertices into a mesh of {mesh.n_vertices}")
    vlines = _format_vertices(V, digits)
    out = [f"# {header}"] if header else []
    if mesh.obj_lines is not None:
        it = iter(vlines)
        out += [next(it) if ln.startswith("v ") else ln for ln in mesh.obj_lines]
    else:
        out += vlines
        for p in mesh.polygons():
            out.append("f " + " ".join(str(int(i) + 1) for i in p))
    return "\n".join(out) + "\n"


def write_obj(path, mesh: Mesh, V=None, header=None, digits=9):
    """Write ``mesh`` (optionally with other vertex positions ``V``) to an OBJ file, atomically."""
    write_text_atomic(path, obj_text(mesh, V, header, digits))
