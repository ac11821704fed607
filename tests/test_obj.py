import numpy as np
import pytest

from garment_transfer.errors import GarmentTransferError, MeshError, TopologyMismatchError
from garment_transfer.geometry.mesh import mesh_from_polygons, require_same_topology
from garment_transfer.geometry.obj import obj_text, read_obj, write_obj

QUAD_OBJ = """# a quad and a pentagon with UVs and a group
o piece
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
v 2 0.5 0
v 1.5 1.5 0
vt 0 0
vt 1 0
vt 1 1
vt 0 1
g front
usemtl cotton
f 1/1 2/2 3/3 4/4
f 2/2 5/1 6/3 3/3
"""


def test_read_keeps_polygons_and_triangulates(tmp_path):
    p = tmp_path / "piece.obj"
    p.write_text(QUAD_OBJ)
    m = read_obj(p)
    assert m.n_vertices == 6 and m.n_faces == 2 and m.n_triangles == 2 + 2
    assert [list(f) for f in m.polygons()] == [[0, 1, 2, 3], [1, 4, 5, 2]]
    assert m.tri_to_face.tolist() == [0, 0, 1, 1]


def test_write_like_source_changes_only_vertex_lines(tmp_path):
    p = tmp_path / "piece.obj"
    p.write_text(QUAD_OBJ)
    m = read_obj(p)
    out = tmp_path / "moved.obj"
    write_obj(out, m, m.V + [0, 0, 1])
    text = out.read_text().splitlines()
    src = QUAD_OBJ.splitlines()
    assert [ln for ln in text if not ln.startswith("v ")] == [ln for ln in src if not ln.startswith("v ")]
    again = read_obj(out)
    np.testing.assert_allclose(again.V, m.V + [0, 0, 1])
    require_same_topology(m, again)


def test_in_memory_mesh_writes_its_own_polygons():
    m = mesh_from_polygons(np.eye(3).tolist() + [[1, 1, 1]], [[0, 1, 2], [0, 2, 3, 1]])
    text = obj_text(m)
    assert "f 1 2 3" in text and "f 1 3 4 2" in text


@pytest.mark.parametrize("content, problem", [
    ("", "no vertices"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\n", "no faces"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n", "vertex"),
    ("v 0 0 nan\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "NaN"),
    ("v 0 0 x\n", "not a number"),
    ("v 0 0 0\nv 1 0 0\nf 1 2\n", "at least 3"),
    ("v 0 0\n", "3 coordinates"),
])
def test_bad_files_name_the_file_and_problem(tmp_path, content, problem):
    p = tmp_path / "bad.obj"
    p.write_text(content)
    with pytest.raises(MeshError, match=problem) as exc:
        read_obj(p)
    assert str(p) in str(exc.value)


def test_missing_file_and_binary_file(tmp_path):
    with pytest.raises(MeshError, match="not found"):
        read_obj(tmp_path / "nope.obj")
    b = tmp_path / "blob.obj"
    b.write_bytes(b"\x00\x01\x02garbage")
    with pytest.raises(MeshError, match="binary"):
        read_obj(b)


def test_topology_mismatch_is_named():
    a = mesh_from_polygons(np.eye(3), [[0, 1, 2]], name="a.obj")
    b = mesh_from_polygons(np.vstack([np.eye(3), [[1, 1, 1]]]), [[0, 1, 2], [0, 2, 3]], name="b.obj")
    with pytest.raises(TopologyMismatchError, match="b.obj.*a.obj"):
        require_same_topology(a, b)


def test_write_is_atomic_on_failure(tmp_path):
    m = mesh_from_polygons(np.eye(3), [[0, 1, 2]])
    out = tmp_path / "out.obj"
    with pytest.raises(MeshError):
        write_obj(out, m, np.zeros((5, 3)))
    assert not out.exists() and list(tmp_path.iterdir()) == []


def test_failed_write_leaves_the_old_file_and_no_temporary(tmp_path, monkeypatch):
    import garment_transfer.geometry.obj as objmod

    m = mesh_from_polygons(np.eye(3), [[0, 1, 2]])
    out = tmp_path / "out.obj"
    out.write_text("previous result\n")

    def broken_replace(src, dst):
        raise OSError("disk full")

    monkeypatch.setattr(objmod.os, "replace", broken_replace)
    # The message names the user's file, not the temporary one.
    with pytest.raises(GarmentTransferError, match=r"out\.obj: cannot be written \(disk full\)"):
        write_obj(out, m)
    assert out.read_text() == "previous result\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.obj"]


READINGS_CASES = [
    "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 2 .5 0\nf 1 2 3 4\nf 2 5 3\n",
    "v +.5 1. -0\r\nv 1e-3 0 0\r\nv 0 1E+2 0\r\nv 1 1 1\r\nf 1/1/1 2//2 3/3\r\nf 1/ 3 4\r\n",
    "# tabs\nv\t0\t0\t0\nv 1  0 0\t\nv 0 1 0\nvt 0 0\nvn 0 0 1\ns off\ng g\nf 1 2 3\n",
    "v 0 0 0 1 0 0\nv 1 0 0 0 1 0\nv 0 1 0 0 0 1\nf 1 2 3\n",       # vertex colours
    "v 0 0 0\nv 1 0 0\nv 0 1 0\nf -3 -2 -1\n",                       # relative indices
    "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nv 2 2 2\nv 3 3 3\nf 1 2 3\nf 2 4 3\n",   # loose vertices (cut off)
    "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n",                          # vertex 0
    "v 0 0 1e\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",                         # not a number
    "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3/4/5/6\n",
    "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 /2 3\n",
    "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2/3/ 3\n",
    "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3 v\n",
    "v 0 0 0\nv 1 0 0\nv 0 1 0\nl 1 2\nf 1 2 3\n",
    "v 0 0 0\nv 1 0 0\nv 0 1 0\nfoo 1 2\nf 1 2 3\n",                  # not an OBJ statement
    "v 0 0 0 v 1 0\nv 0 1 0\nf 1 2 3\n",
]


@pytest.mark.parametrize("content", READINGS_CASES)
def test_whole_file_reading_equals_line_by_line_reading(tmp_path, content, monkeypatch):
    """Plain files are read a block at a time (``plain_arrays``); the result, or the error, is the line-by-line
    reading's."""
    from garment_transfer.geometry import obj

    p = tmp_path / "case.obj"
    p.write_bytes(content.encode())

    def read():
        try:
            return read_obj(p)
        except MeshError as exc:
            return str(exc)

    fast = read()
    monkeypatch.setattr(obj, "plain_arrays", lambda raw_lines: None)
    slow = read()
    if isinstance(slow, str):
        assert fast == slow
    else:
        for key in ("V", "F", "face_vertices", "face_start", "tri_to_face"):
            assert np.array_equal(getattr(fast, key), getattr(slow, key))
        assert fast.obj_lines == slow.obj_lines


def test_a_plain_file_is_read_a_block_at_a_time():
    from garment_transfer.geometry import obj

    lines = QUAD_OBJ.encode().split(b"\n")
    V, face_vertices, face_start = obj.plain_arrays(lines)
    assert V.shape == (6, 3) and face_vertices.tolist() == [0, 1, 2, 3, 1, 4, 5, 2]
    assert face_start.tolist() == [0, 4, 8]


def random_obj_text(rng, vertices):
    """An OBJ text of mostly plain lines in any order, now and then a word or a line that is not."""
    numbers = ["0", "1", "-1", "+1", "1.", ".5", "-.5", "1e3", "1E-3", "2.5e+2"]
    odd_numbers = ["1e", "e1", ".", "-", "1.2.3", "nan", "inf", "0x1", "1_0", "v", "f", "1/2"]
    indices = ["1", "2", "3", "4", "1/1", "2//2", "3/3/3", "4/"]
    odd_indices = ["0", "-1", "1/2/3/4", "/2", "01", "x", "9"]
    others = ["# comment", "", "vt 0 0", "vn 0 0 1", "g a", "s off", "usemtl m", "o x", "vt\t0 0"]

    def word(plain, odd):
        return str(rng.choice(plain if rng.random() < 0.99 else odd))

    def line():
        k, blank = rng.random(), str(rng.choice([" ", "  ", "\t"]))
        if k < 0.45:
            n = 3 if rng.random() < 0.9 else int(rng.choice([2, 4, 6]))
            return "v" + blank + blank.join(word(numbers, odd_numbers) for _ in range(n)) + \
                str(rng.choice([""] * 20 + [" ", "\r", " # c"]))
        if k < 0.85:
            n = int(rng.choice([3, 3, 4, 5] * 10 + [2]))
            return "f" + blank + blank.join(word(indices, odd_indices) for _ in range(n))
        return str(rng.choice(others * 5 + ["l 1 2", "p 1", "bogus 1", "vp 1", " v 1 2 3"]))

    lines = [f"v {x:.3f} {y:.3f} {z:.3f}" for x, y, z in rng.random((vertices, 3))]
    lines += [line() for _ in range(int(rng.integers(1, 10)))]
    return "\n".join(str(s) for s in rng.permutation(lines)) + str(rng.choice(["\n", "", "\r\n"]))


def test_whole_file_reading_equals_line_by_line_reading_on_random_files(tmp_path, monkeypatch):
    from garment_transfer.geometry import obj

    rng = np.random.default_rng(7)
    p = tmp_path / "random.obj"

    def read():
        try:
            return read_obj(p)
        except MeshError as exc:
            return str(exc)

    whole = 0
    for _ in range(400):
        p.write_text(random_obj_text(rng, int(rng.integers(3, 8))))
        whole += obj.plain_arrays(p.read_bytes().split(b"\n")) is not None
        fast = read()
        with monkeypatch.context() as m:
            m.setattr(obj, "plain_arrays", lambda raw_lines: None)
            slow = read()
        if isinstance(fast, str) or isinstance(slow, str):
            assert fast == slow
        else:
            for key in ("V", "F", "face_vertices", "face_start"):
                assert np.array_equal(getattr(fast, key), getattr(slow, key))
    assert whole >= 25                      # the whole-file reading was taken on many of them


def sheet_with_normals(rng):
    """A 4x3 quad sheet in the xy plane, curved along y: smooth normals per vertex (as Blender makes them), one face
    shaded flat (its own normal, named by its four corners), one vertex's normal tilted by the artist."""
    x, y = np.meshgrid(np.linspace(0, 1, 5), np.linspace(0, 0.8, 4) + 0.01 * rng.random(4))
    V = np.stack([x, y, 0.2 * np.sin(3 * y)], -1).reshape(-1, 3)
    idx = np.arange(20).reshape(4, 5)
    quads = np.stack([idx[:-1, :-1], idx[:-1, 1:], idx[1:, 1:], idx[1:, :-1]], -1).reshape(-1, 4)
    m = mesh_from_polygons(V, quads)
    smooth = np.zeros((20, 3))
    for q in quads:
        n = np.cross(V[q[1]] - V[q[0]], V[q[2]] - V[q[0]]) + np.cross(V[q[2]] - V[q[0]], V[q[3]] - V[q[0]])
        for c in range(4):
            e1, e2 = V[q[c - 1]] - V[q[c]], V[q[(c + 1) % 4]] - V[q[c]]
            angle = np.arccos(e1 @ e2 / np.linalg.norm(e1) / np.linalg.norm(e2))
            smooth[q[c]] += angle * n / np.linalg.norm(n)
    smooth /= np.linalg.norm(smooth, axis=1, keepdims=True)
    flat = np.cross(V[quads[5, 2]] - V[quads[5, 0]], V[quads[5, 3]] - V[quads[5, 1]])
    tilted = smooth[7] + [0.3, 0.0, 0.0]
    normals = np.vstack([smooth, flat / np.linalg.norm(flat), tilted / np.linalg.norm(tilted)])
    lines = [f"v {a:.17g} {b:.17g} {c:.17g}" for a, b, c in V]
    lines += [f"vn {a:.17g} {b:.17g} {c:.17g}" for a, b, c in normals]
    for k, q in enumerate(quads):
        named = [21] * 4 if k == 5 else [22 if i == 7 else i + 1 for i in q]
        lines.append("f " + " ".join(f"{i + 1}//{j}" for i, j in zip(q, named)))
    return m, normals, "\n".join(lines) + "\n"


def written_normals(path):
    return np.array([[float(t) for t in ln.split()[1:]] for ln in path.read_text().splitlines()
                     if ln.startswith("vn ")])


def test_the_normals_written_turn_with_the_faces(tmp_path):
    """A file's normals shade the shape they were written for: written for another shape, each turns with its
    faces (the smallest rotation of the angle-weighted mean of their normals), a tilted one keeps its tilt."""
    rng = np.random.default_rng(3)
    _, normals, text = sheet_with_normals(rng)
    p = tmp_path / "sheet.obj"
    p.write_text(text)
    m = read_obj(p)
    # Turned about the x axis, square to every normal of the sheet (the smallest rotation of each is this one).
    t = 0.7
    R = np.array([[1, 0, 0], [0, np.cos(t), -np.sin(t)], [0, np.sin(t), np.cos(t)]])
    out = tmp_path / "turned.obj"
    write_obj(out, m, m.V @ R.T + [0.2, -1.0, 3.0], digits=17)
    turned = written_normals(out)
    used = np.arange(22) != 7      # vertex 7's corners name the tilted normal: no face uses its smooth one
    np.testing.assert_allclose(turned[used], normals[used] @ R.T, atol=1e-12)
    np.testing.assert_array_equal(turned[7], normals[7])
    # The rest of the file as it was; the same positions leave every line as it was.
    assert [ln for ln in out.read_text().splitlines() if ln[:2] not in ("v ", "vn")] == \
        [ln for ln in text.splitlines() if ln[:2] not in ("v ", "vn")]
    assert obj_text(m, m.V.copy(), digits=17) == text


def test_only_the_normals_of_the_faces_that_turned_change(tmp_path):
    rng = np.random.default_rng(4)
    _, normals, text = sheet_with_normals(rng)
    p = tmp_path / "sheet.obj"
    p.write_text(text)
    m = read_obj(p)
    V = m.V.copy()
    V[:, 2] += np.where(V[:, 0] > 0.6, 0.5 * (V[:, 0] - 0.6), 0.0)   # the last column of faces bent up
    out = tmp_path / "bent.obj"
    write_obj(out, m, V, digits=17)
    before = [ln for ln in text.splitlines() if ln.startswith("vn ")]
    after = [ln for ln in out.read_text().splitlines() if ln.startswith("vn ")]
    # Vertices 0-3 of each row (x <= 0.75) touch only faces left of x = 0.75, all unbent but those at x in
    # 0.5..0.75 (their corners at x = 0.75 moved): the normals of x < 0.5 and the flat face 5 stay byte for byte.
    x = m.V[:, 0]
    for i in range(20):
        if x[i] < 0.4 and i != 7:
            assert after[i] == before[i], i
        if x[i] > 0.9:
            assert after[i] != before[i], i
    assert after[20] == before[20]
    assert np.allclose(np.linalg.norm(written_normals(out), axis=1), 1.0)


def test_material_libraries_are_named_from_where_the_result_is_written(tmp_path):
    """A reader looks for an OBJ's material libraries beside the file it reads: a result written into another
    folder names the source's libraries from there (its textures stay where the library names them)."""
    src = tmp_path / "garments" / "suit"
    src.mkdir(parents=True)
    (src / "cloth.mtl").write_text("newmtl cotton\nKd 0.8 0.1 0.1\n")
    (src / "trim and lining.mtl").write_text("newmtl lining\n")
    (src / "extra.mtl").write_text("newmtl extra\n")
    text = QUAD_OBJ.replace("o piece\n", "mtllib cloth.mtl\nmtllib trim and lining.mtl\nmtllib cloth.mtl extra.mtl "
                                         "# two\nmtllib missing.mtl\nmtllib /nowhere/abs.mtl\r\n")
    (src / "suit.obj").write_text(text)
    m = read_obj(src / "suit.obj")
    out = tmp_path / "results" / "pear"
    out.mkdir(parents=True)
    write_obj(out / "suit_on_pear.obj", m, m.V + 1.0)
    lines = (out / "suit_on_pear.obj").read_bytes().decode().split("\n")
    assert lines[1:6] == ["mtllib ../../garments/suit/cloth.mtl", "mtllib ../../garments/suit/trim and lining.mtl",
                         "mtllib ../../garments/suit/cloth.mtl ../../garments/suit/extra.mtl # two",
                         "mtllib missing.mtl", "mtllib /nowhere/abs.mtl\r"]
    assert (out / "../../garments/suit/trim and lining.mtl").is_file()
    assert [ln for ln in lines if not ln.startswith(("mtllib", "v "))] == \
        [ln for ln in text.split("\n") if not ln.startswith(("mtllib", "v "))]
    # Into a folder through a link to it: named from where the file really is, as a reader opens "../".
    elsewhere = tmp_path / "deep" / "down" / "real"
    elsewhere.mkdir(parents=True)
    (tmp_path / "link").symlink_to(elsewhere, target_is_directory=True)
    write_obj(tmp_path / "link" / "linked.obj", m, m.V + 1.0)
    library = (elsewhere / "linked.obj").read_text().split("\n")[1].removeprefix("mtllib ")
    assert (elsewhere / library).resolve() == (src / "cloth.mtl").resolve()
    # Written beside its source, nothing is renamed.
    write_obj(src / "moved.obj", m, m.V + 1.0)
    assert [ln for ln in (src / "moved.obj").read_bytes().decode().split("\n") if ln.startswith("mtllib")] == \
        [ln for ln in text.split("\n") if ln.startswith("mtllib")]


def test_any_file_with_normals_is_written_moved_with_only_its_vertices_and_normals_changed(tmp_path):
    """Normals named every way a face corner can (v//vn, v/vt/vn, relative, out of range, none), in files of odd
    lines: written with moved positions, nothing fails, only v and vn lines change, and a changed normal is unit."""
    rng = np.random.default_rng(11)
    forms = ["{v}//{n}", "{v}/1/{n}", "{v}", "{v}/1", "{v}//-1", "-1//{n}", "{v}//9", "{v}//{n} # c"]
    turn = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    written = changed = 0
    for k in range(400):
        n = int(rng.integers(3, 8))
        text = random_obj_text(rng, n) if rng.random() < 0.3 else "\n".join(
            f"v {a:.3f} {b:.3f} {c:.3f}" for a, b, c in rng.random((n, 3))) + "\ns 1\n# x"
        extra = [f"vn {a:.3f} {b:.3f} {c:.3f}" for a, b, c in rng.normal(size=(3, 3))]
        extra += ["f " + " ".join(str(rng.choice(forms)).format(v=int(rng.integers(1, 4)), n=int(rng.integers(1, 4)))
                                  for _ in range(3)) for _ in range(3)]
        lines = text.split("\n") + ["f " + " ".join(str(i + 1) for i in range(n))]     # every vertex used
        at = int(rng.integers(0, len(lines) + 1))
        lines[at:at] = extra
        p = tmp_path / f"case{k}.obj"
        lines.append("")
        p.write_text("\n".join(lines))
        try:
            m = read_obj(p)
        except MeshError:
            continue
        out = obj_text(m, m.V @ turn.T + 1.0).split("\n")
        written += 1
        assert len(out) == len(lines)
        for old, new in zip(lines, out):
            if old.lstrip().startswith("vn") and new != old:
                changed += 1
                assert abs(np.linalg.norm([float(x) for x in new.split()[1:4]]) - 1.0) < 1e-8
            elif not old.lstrip().startswith("v"):
                assert new == old
    assert written > 100 and changed > 40
