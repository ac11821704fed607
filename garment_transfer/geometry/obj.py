"""Wavefront OBJ reading and writing.

Reading keeps the file's own text, so a result written "like" its source is the source byte for
byte except for the three coordinates of each ``v`` line, and of each ``vn`` normal whose faces turned
(``mesh.turned_normals``): faces, UVs, groups, materials, vertex colours (``v x y z r g b``), comments in any
encoding, line endings and a byte-order mark all stay. Bytes that are not UTF-8 are carried through
unchanged (``surrogateescape``).

What is read (the OBJ format allows any run of spaces and tabs between fields):

- ``v x y z [w | r g b]``: numbers only; ``f`` with 1-based or negative (relative) indices, with or
  without ``/vt/vn``; comments after ``#``; the other OBJ statements are kept and not used.
- A line that is none of the OBJ statements (for example a damaged keyword), a number that is not
  one, a face with fewer than 3 vertices or an index out of range is an error naming the line.
- A file cut off is refused where that can be seen: the last line is a ``v`` or ``f`` (or other
  data) record without its line break, or the faces stop early, leaving vertices (two or more, and
  more than ``CUT_OFF_SHARE`` of them) used by no face or other element. A file cut exactly at a
  line break inside the faces, where every vertex is still used, is a valid OBJ file and cannot be
  told apart.

Writing is atomic and never replaces an input (see ``files.write_atomic``).
"""

from __future__ import annotations

import os
import re

import numpy as np

from ..errors import MeshError
from ..files import write_text_atomic
from .mesh import Mesh, mesh_from_polygon_arrays, turned_normals

#: More than this share of the vertices used by no face means the faces stop early: a file cut off.
#: (MakeHuman fixtures and demo files: none.)
CUT_OFF_SHARE = 0.01

_WS = "[ \t\r\f\v]"
_NUMBER = re.compile(r"[+-]?(?:\d+\.?\d*(?:[eE][+-]?\d+)?|\.\d+(?:[eE][+-]?\d+)?|nan|inf|infinity)\Z",
                     re.ASCII | re.IGNORECASE)
_INDEX = re.compile(r"([+-]?\d+)(?:/[+-]?\d*(?:/[+-]?\d*)?)?\Z", re.ASCII)
# A v line split so that only the three coordinates are replaced when writing: the prefix (any BOM,
# indentation, the keyword and the blank after it), x, blank, y, blank, z, and everything after z.
_V_LINE = re.compile(rf"(\ufeff*{_WS}*v{_WS}+)(\S+)({_WS}+)(\S+)({_WS}+)([^ \t\r\f\v#]+)(.*)\Z", re.DOTALL)
# A vn line split the same way: its three numbers are replaced when the faces that use it turn.
_VN_LINE = re.compile(rf"(\ufeff*{_WS}*vn{_WS}+)(\S+)({_WS}+)(\S+)({_WS}+)([^ \t\r\f\v#]+)(.*)\Z", re.DOTALL)
# Whether a text has an mtllib line; an mtllib line split: the keyword (and what is before it), the library names,
# and the blanks and any comment after them.
_ANY_MTLLIB = re.compile(rf"^\ufeff*{_WS}*mtllib{_WS}", re.MULTILINE)
_MTLLIB_LINE = re.compile(rf"(\ufeff*{_WS}*mtllib{_WS}+)([^#]*?)({_WS}*(?:#.*)?)\Z", re.DOTALL)
# Whether a text has a vn line at all.
_ANY_VN = re.compile(rf"^\ufeff*{_WS}*vn{_WS}", re.MULTILINE)
# A face corner's vertex index and, when it names one, its normal's.
_CORNER = re.compile(r"([+-]?\d+)(?:/[+-]?\d*(?:/([+-]?\d*))?)?")
#: A normal that turns by less than this (radians) keeps its line as it was.
NORMAL_KEPT = 1e-9
_FAST_NUMBER = rb"[+-]?(?:\d+\.?\d*(?:[eE][+-]?\d+)?|\.\d+(?:[eE][+-]?\d+)?)"
_FAST_V = re.compile(rb"v(?:[ \t]+" + _FAST_NUMBER + rb"){3,}[ \t\r]*")
_FAST_F = re.compile(rb"f(?:[ \t]+[1-9]\d*(?:/\d*(?:/\d*)?)?){3,}[ \t\r]*")
# What a plain v line or f line may hold, and the /vt/vn of a face corner.
_V_BYTES = b"v0123456789.eE+- \t\r\n"
_F_BYTES = b"f0123456789/ \t\r\n"
_SLASHES = re.compile(rb"(?<=\d)/\d*(?:/\d*)?(?=[ \t\r\n]|\Z)")
_KEYWORDS = frozenset("""v vt vn vp f l p g o s usemtl mtllib cstype deg bmat step curv curv2 surf parm
trim hole scrv sp end con mg bevel c_interp d_interp lod usemap maplib shadow_obj trace_obj ctech stech
call csh""".split())
_DATA = frozenset("v vt vn vp f l p".split())


def _decode(data: bytes, name) -> str:
    sample = data[:4096]
    if data.startswith((b"\xff\xfe", b"\xfe\xff")) or sample.count(0) > len(sample) // 4:
        raise MeshError(name, "is UTF-16 (or UTF-32) text; OBJ files are ASCII or UTF-8: save it "
                              "as UTF-8")
    if b"\x00" in sample:
        raise MeshError(name, "is not a text OBJ file (binary content)")
    return data.decode("utf-8", errors="surrogateescape")


def _statement(line):
    """The keyword and fields of a line (no comment), or (None, []) for a blank or comment line."""
    body = line.lstrip("\ufeff").split("#", 1)[0]
    parts = re.split(f"{_WS}+", body.strip(" \t\r\f\v"))
    if parts == [""]:
        return None, []
    return parts[0], parts[1:]


def _show(line):
    return repr(line.strip()[:60].encode("utf-8", "surrogateescape").decode("utf-8", "replace"))


def read_obj(path, name=None) -> Mesh:
    """Read an OBJ file into a Mesh (polygons triangulated, original faces and text kept).

    Raises
    ------
    MeshError
        Naming the file (and the line): missing, unreadable, not text, malformed lines, bad
        indices, NaN/inf, no faces, cut off.
    """
    path = os.fspath(path)
    name = name or path
    try:
        with open(path, "rb") as fh:
            data = fh.read()
    except FileNotFoundError:
        raise MeshError(name, "file not found") from None
    except IsADirectoryError:
        raise MeshError(name, "is a folder, not an OBJ file") from None
    except OSError as exc:
        raise MeshError(name, f"cannot be read ({exc.strerror or exc})") from None
    lines = _decode(data, name).split("\n")
    # First: a record cut in two is usually malformed too, but "cut off" is what the user must hear.
    if _statement(lines[-1])[0] in _DATA:
        raise MeshError(name, f"line {len(lines)}: the file ends in the middle of a record "
                              f"({_show(lines[-1])} has no line break): it looks cut off. If it is "
                              "complete, end it with a line break")
    raw_lines = data.split(b"\n")
    plain = plain_arrays(raw_lines)
    if plain is not None:
        return _in_folder(_mesh_read(*plain, [], name, lines), path)
    verts, polys, others = [], [], []
    for lineno, (line, raw) in enumerate(zip(lines, raw_lines), 1):
        # Plain v and f lines (nearly all of a file) take a fast path; the rest is read in full.
        if raw[:2] == b"v " and _FAST_V.fullmatch(raw):
            x, y, z = raw.split()[1:4]
            verts.append((float(x), float(y), float(z)))
            continue
        if raw[:2] == b"f " and _FAST_F.fullmatch(raw):
            polys.append([int(t.split(b"/", 1)[0]) - 1 for t in raw.split()[1:]])
            continue
        key, fields = _statement(line)
        if key is None:
            continue
        if key == "v":
            verts.append(_vertex(fields, line, lineno, name))
        elif key == "f":
            polys.append(_face(fields, len(verts), line, lineno, name))
        elif key in ("l", "p"):
            # Not used, but their vertices are not loose: they count for the cut-off check.
            others.extend(_element(fields, len(verts)))
        elif key not in _KEYWORDS:
            raise MeshError(name, f"line {lineno}: not an OBJ statement: {_show(line)}; "
                                  "is the file damaged?")
    if not verts:
        raise MeshError(name, "has no vertices (is it an OBJ file?)")
    if not polys:
        raise MeshError(name, "has no faces (a point cloud or lines only)")
    sizes = np.fromiter((len(p) for p in polys), dtype=np.int64, count=len(polys))
    return _in_folder(_mesh_read(np.asarray(verts, dtype=np.float64), np.concatenate(polys).astype(np.int64),
                                 np.concatenate([[0], np.cumsum(sizes)]), others, name, lines), path)


def _in_folder(mesh, path):
    mesh.obj_folder = os.path.dirname(os.path.abspath(path))
    return mesh


def _mesh_read(V, face_vertices, face_start, others, name, lines):
    """The Mesh of what a file gave (vertices, its polygons flat, the vertices of its ``l`` and ``p`` elements), once
    every face's vertex is known to be in the file and the faces do not stop early (a file cut off)."""
    top = int(face_vertices.max())
    if top >= V.shape[0]:
        raise MeshError(name, f"a face refers to vertex {top + 1} but the file has {V.shape[0]}")
    used = np.zeros(V.shape[0], bool)
    used[face_vertices] = True
    used[others] = True
    loose = int(V.shape[0] - used.sum())
    if loose >= 2 and loose > CUT_OFF_SHARE * V.shape[0]:
        raise MeshError(name, f"{loose} of its {V.shape[0]} vertices are used by no face: the faces stop early, as "
                              f"in a file cut off ({face_start.shape[0] - 1} faces read). Export it again (or delete "
                              "the loose vertices)")
    return mesh_from_polygon_arrays(V, face_vertices, face_start, name=name, obj_lines=lines)


def plain_arrays(raw_lines):
    """``(V, face_vertices, face_start)`` of a file whose every ``v`` and ``f`` line is plain (numbers only; positive
    indices, with or without ``/vt/vn``) and whose other lines are blank, comments or statements other than
    ``v``, ``f``, ``l`` and ``p``: nearly every file. The v lines and the f lines are each checked and converted
    as a whole: only the characters of numbers, indices and ``/``, one keyword a line, four words a v line, every
    word a number (a 50K-triangle body in 0.07 s against 0.3 s line by line). None for any other file, which is
    read line by line (and its errors named by line)."""
    v, f = [], []
    for raw in raw_lines:
        head = raw[:2]
        if head == b"v ":
            v.append(raw)
        elif head == b"f ":
            f.append(raw)
        elif head in (b"vt", b"vn") and raw[2:3] in (b" ", b"\t"):
            continue
        elif head[:1] != b"#":
            key, _ = _statement(raw.decode("utf-8", errors="surrogateescape"))
            if key is not None and (key in _DATA or key not in _KEYWORDS):
                return None
    if not v or not f:
        return None
    vertices, faces = b"\n".join(v), b"\n".join(f)
    if vertices.translate(None, _V_BYTES) or faces.translate(None, _F_BYTES):
        return None
    # Each line holds one keyword, its first word (as many keywords as lines), a v line 4 words: v x y z.
    tokens = vertices.split()
    if len(tokens) != 4 * len(v) or tokens.count(b"v") != len(v):
        return None
    vertex_words = np.array(tokens, dtype=np.bytes_).reshape(-1, 4)
    faces = _SLASHES.sub(b"", faces) if b"/" in faces else faces
    tokens = faces.split()
    if tokens.count(b"f") != len(f) or not (vertex_words[:, 0] == b"v").all():
        return None
    face_words = np.array(tokens, dtype=np.bytes_)
    keyword = face_words == b"f"
    sizes = np.diff(np.append(np.flatnonzero(keyword), face_words.shape[0])) - 1
    if not keyword[0] or sizes.min() < 3:
        return None
    try:
        V = vertex_words[:, 1:].astype(np.float64)
        face_vertices = face_words[~keyword].astype(np.int64) - 1
    except ValueError:                      # a word that is not a number ("1e", "1.2.3", "v"): read line by line
        return None
    if face_vertices.min() < 0:             # a vertex 0 (or 00): named by the line-by-line reading
        return None
    return V, face_vertices, np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)


def _vertex(fields, line, lineno, name):
    if len(fields) < 3:
        raise MeshError(name, f"line {lineno}: a vertex needs 3 coordinates: {_show(line)}")
    bad = [f for f in fields if not _NUMBER.match(f)]
    if bad:
        raise MeshError(name, f"line {lineno}: not a number ({_show(bad[0])}) in {_show(line)}")
    return float(fields[0]), float(fields[1]), float(fields[2])


def _face(fields, n, line, lineno, name):
    if len(fields) < 3:
        raise MeshError(name, f"line {lineno}: a face needs at least 3 vertices: {_show(line)}")
    idx = []
    for f in fields:
        m = _INDEX.match(f)
        if not m:
            raise MeshError(name, f"line {lineno}: bad face {_show(line)}")
        i = int(m.group(1))
        i = i - 1 if i > 0 else n + i
        if i < 0 or m.group(1).lstrip("+-").strip("0") == "":
            raise MeshError(name, f"line {lineno}: face index out of range in {_show(line)}")
        idx.append(i)
    return idx


def _element(fields, n):
    """Vertex indices of an ``l`` or ``p`` element that can be read (the others are ignored)."""
    out = []
    for f in fields:
        m = _INDEX.match(f)
        if m:
            i = int(m.group(1))
            i = i - 1 if i > 0 else n + i
            if 0 <= i < n:
                out.append(i)
    return out


def _normal_uses(lines):
    """The file's normals and the face corners that use them, from its text.

    Returns
    -------
    rows : (k,) int
        The line of each ``vn`` record (in order: normal j is ``rows[j]``).
    split : list
        Each vn line split by ``_VN_LINE`` (None where it does not split so).
    N : (k,3) float
        The normals as written; NaN where a vn line holds no three numbers.
    corners : (c,) int, start : (p+1,) int
        The ``f`` lines' vertices (0-based, relative indices resolved): polygon i is ``corners[start[i]:start[i+1]]``.
    uses : (u,2) int
        (corner, normal) of every face corner that names a normal there is (``f v/vt/vn``, ``f v//vn``).
    """
    rows, split, N, faces, at_v, at_vn = [], [], [], [], [], []
    n_v = 0
    for i, line in enumerate(lines):
        head = line[:2]
        if head == "v ":
            n_v += 1
            continue
        if head == "vt":
            continue
        if head == "f " and "#" not in line:
            key, fields = "f", line[2:]
        elif head == "vn" and line[2:3] == " ":
            key, fields = "vn", None
        else:
            key, fields = _statement(line)
            fields = " ".join(fields or ())
        if key == "v":
            n_v += 1
        elif key == "vn":
            rows.append(i)
            m = _VN_LINE.match(line)
            split.append(m)
            try:
                N.append([float(m.group(2)), float(m.group(4)), float(m.group(6))] if m else [np.nan] * 3)
            except ValueError:
                N.append([np.nan] * 3)
        elif key == "f":
            faces.append(fields)
            at_v.append(n_v)
            at_vn.append(len(rows))
    sizes = np.fromiter((len(f.split()) for f in faces), dtype=np.int64, count=len(faces))
    # Each corner's vertex and normal (``v``, ``v/vt``, ``v//vn``, ``v/vt/vn``; no normal: 0, never an index).
    words = _CORNER.findall(" ".join(faces))
    if len(words) != int(sizes.sum()):     # a corner read otherwise than the faces were: no normal is turned
        return (np.asarray(rows, dtype=np.int64), split, np.asarray(N, dtype=np.float64).reshape(-1, 3),
                np.zeros(0, np.int64), np.zeros(1, np.int64), np.zeros((0, 2), np.int64))
    corners = np.array([w[0] for w in words], dtype=np.int64).reshape(-1)
    named = np.array([w[1] or "0" for w in words], dtype=np.int64).reshape(-1)
    corners = np.where(corners > 0, corners - 1, np.repeat(np.asarray(at_v, dtype=np.int64), sizes) + corners)
    k = len(rows)
    normal = np.where(named > 0, named - 1, np.repeat(np.asarray(at_vn, dtype=np.int64), sizes) + named)
    use = (named != 0) & (normal >= 0) & (normal < k)
    return (np.asarray(rows, dtype=np.int64), split, np.asarray(N, dtype=np.float64).reshape(-1, 3), corners,
            np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64),
            np.stack([np.flatnonzero(use), normal[use]], axis=1))


def obj_text(mesh: Mesh, V=None, header=None, digits=9, path=None) -> str:
    """OBJ text of ``mesh`` with vertex positions ``V`` (default: the mesh's own).

    A mesh read from a file gets that file's text back with only the three coordinates of each
    ``v`` line replaced, and those of each ``vn`` line whose faces turned (``turned_normals``: a normal
    written for the source's shape would shade the new one wrongly in any reader that uses the file's
    normals, as Blender's importer does); ``header`` is not added. Given ``path``, where the text is written,
    its ``mtllib`` lines name the material libraries the file had from the folder of ``path``
    (``relinked_libraries``: a reader looks for them beside the file it reads). Nothing else changes. Others
    get ``# header`` and plain ``v``/``f`` lines with their original polygons. ``digits``: significant digits per
    coordinate.
    """
    fmt = f"%.{digits}g"
    V = mesh.V if V is None else np.asarray(V, dtype=np.float64)
    if V.shape != mesh.V.shape:
        raise MeshError(mesh.name, f"cannot write {V.shape[0]} vertices into a mesh of {mesh.n_vertices}")
    if mesh.obj_lines is not None:
        out, k = [], 0
        for line in mesh.obj_lines:
            # Exactly the lines read as vertices: a v keyword, blanks, then at least three fields.
            m = _V_LINE.match(line)
            if m:
                x, y, z = V[k]
                k += 1
                line = m.group(1) + fmt % x + m.group(3) + fmt % y + m.group(5) + fmt % z + m.group(7)
            out.append(line)
        if k != len(V):
            raise MeshError(mesh.name, f"its text has {k} vertex lines for {len(V)} vertices; read it again")
        text = "\n".join(out)
        if not np.array_equal(V, mesh.V) and _ANY_VN.search(text):
            _turn_normal_lines(out, mesh.obj_lines, mesh.V, V, fmt)
            text = "\n".join(out)
        if path is not None and mesh.obj_folder is not None and _ANY_MTLLIB.search(text):
            here = os.path.dirname(os.path.abspath(path))
            lines = [relinked_libraries(line, mesh.obj_folder, here) for line in text.split("\n")]
            text = "\n".join(lines)
        return text
    out = [f"# {header}"] if header else []
    out += ["v " + " ".join(fmt % c for c in v) for v in V]
    for p in mesh.polygons():
        out.append("f " + " ".join(str(int(i) + 1) for i in p))
    return "\n".join(out) + "\n"


def relinked_libraries(line, folder, here):
    """An ``mtllib`` line of a file in ``folder`` written into the folder ``here``: each material library that is
    a file, relative to ``folder``, named from ``here`` (relative, with ``/``; absolute where no relative path
    exists, as across Windows drives). Any other line, a library named by an absolute path or one not found, and
    a file written into its own folder are left as they were.

    A name with blanks (the rest of the line, when that is a file) is one library; otherwise the blanks separate
    several, as the OBJ format has it."""
    m = _MTLLIB_LINE.match(line)
    # Real paths: a reader resolves "../" from the folder the file really is in.
    here = os.path.realpath(here)
    if m is None or os.path.normcase(os.path.realpath(folder)) == os.path.normcase(here):
        return line
    whole = m.group(2)
    names = [whole] if os.path.isfile(os.path.join(folder, whole)) else whole.split()
    moved = []
    for name in names:
        target = os.path.join(folder, name)
        if os.path.isabs(name) or not os.path.isfile(target):
            moved.append(name)
            continue
        target = os.path.realpath(target)
        try:
            moved.append(os.path.relpath(target, here).replace(os.sep, "/"))
        except ValueError:
            moved.append(target.replace(os.sep, "/"))
    if moved == names:
        return line
    return m.group(1) + " ".join(moved) + m.group(3)


def _turn_normal_lines(out, lines, V_from, V_to, fmt):
    """Replace, in ``out`` (the text's lines), the numbers of each vn line whose normal turned with its faces."""
    rows, split, N, corners, start, uses = _normal_uses(lines)
    if corners.size and (corners.min() < 0 or corners.max() >= V_from.shape[0]):
        return
    turned = turned_normals(N, V_from, V_to, corners, start, uses)
    length = np.linalg.norm(N, axis=1)
    unit = N / np.where(length > 0, length, 1.0)[:, None]
    # The angle between the normal as written and as turned (its chord for small angles).
    moved = np.isfinite(turned).all(axis=1) & ~(np.linalg.norm(turned - unit, axis=1) < NORMAL_KEPT)
    for j in np.flatnonzero(moved):
        m = split[j]
        x, y, z = turned[j]
        out[rows[j]] = m.group(1) + fmt % x + m.group(3) + fmt % y + m.group(5) + fmt % z + m.group(7)


def write_obj(path, mesh: Mesh, V=None, header=None, inputs=(), digits=9):
    """Write ``mesh`` (optionally with other vertex positions ``V``) to an OBJ file, atomically.

    ``inputs``: files the output must not be; the mesh's own file (its name) is always one.
    """
    write_text_atomic(path, obj_text(mesh, V, header, digits, path=path), inputs=(mesh.name, *inputs))
