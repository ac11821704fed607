import numpy as np

from garment_transfer.obj import read_obj, write_obj
from lab.garment_data import OFFSET_STEP, SOURCE_STEP, pack, read_packed
from meshes import grid

BODIES = ("banana", "pear", "slim")


def draped(tmp_path, name, shift):
    g = grid(5, 4)
    folder = tmp_path / "garments" / name
    folder.mkdir(parents=True)
    for k, b in enumerate(BODIES):
        write_obj(folder / f"{b}.obj", g, g.V + [0.1, 0.2, 1.3] + k * shift)
    return g


def test_pack_keeps_shapes_to_the_step_and_leaves_out_unfinished_garments(tmp_path):
    g = draped(tmp_path, "skirt", np.array([0.0, 0.013, -0.21]))
    draped(tmp_path, "half_done", np.zeros(3))
    (tmp_path / "garments" / "half_done" / "slim.obj").unlink()
    (tmp_path / "log.txt").write_text(
        "[ 1.0s] garment 1/2 skirt: 20 vertices, 24 triangles, 12.5s, vertices inside the body before/after "
        "the fix [0, 3, 0]/[0, 0, 0]\n")
    out = tmp_path / "packed.npz"
    meta = pack(tmp_path, out, source="banana", targets=BODIES[1:])
    assert meta["garments"] == ["skirt"]
    assert meta["drape_log"]["skirt"]["seconds"] == 12.5
    assert meta["drape_log"]["skirt"]["inside_before_fix"] == [0, 3, 0]
    meta2, garments = read_packed(out)
    quads, shapes = garments["skirt"]
    np.testing.assert_array_equal(quads, np.array(g.polygons()))
    for b in BODIES:
        want = read_obj(tmp_path / "garments" / "skirt" / f"{b}.obj").V
        np.testing.assert_allclose(shapes[b], want, atol=0.5 * SOURCE_STEP + 0.5 * OFFSET_STEP + 1e-12)
    with np.load(out, allow_pickle=False) as npz:
        assert npz["skirt/offsets"].dtype == np.int16 and npz["skirt/source"].dtype == np.int32


def test_a_later_pack_keeps_the_garments_packed_before(tmp_path):
    first, second = tmp_path / "first", tmp_path / "second"
    for work, name, line in ((first, "skirt", 1), (second, "dress", 2)):
        draped(work, name, np.array([0.0, 0.01 * line, 0.0]))
        (work / "log.txt").write_text(
            f"[ 1.0s] garment {line}/2 {name}: 20 vertices, 24 triangles, {line}.5s, vertices inside the body "
            "before/after the fix [0, 0, 0]/[0, 0, 0]\n")
    out = tmp_path / "packed.npz"
    pack(first, out, source="banana", targets=BODIES[1:])
    before = read_packed(out)[1]["skirt"]
    meta = pack(second, out, source="banana", targets=BODIES[1:])
    assert meta["garments"] == ["dress", "skirt"]
    assert meta["drape_log"]["skirt"]["seconds"] == 1.5 and meta["drape_log"]["dress"]["seconds"] == 2.5
    after = read_packed(out)[1]
    np.testing.assert_array_equal(after["skirt"][0], before[0])
    for b in BODIES:
        np.testing.assert_array_equal(after["skirt"][1][b], before[1][b])
