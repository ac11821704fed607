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
