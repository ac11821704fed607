import numpy as np
import pytest
from meshes import grid

from garment_transfer.geometry.obj import read_obj, write_obj
from lab.garment_data import OFFSET_STEP, SOURCE_STEP, pack, read_packed

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


def test_in_between_bodies_are_packed_with_their_garments_and_unpacked_into_a_dataset(tmp_path):
    import json

    from meshes import icosphere

    from garment_transfer.geometry.mesh import mesh_from_triangles
    from garment_transfer.learning.dataset import load_dataset
    from lab.garment_data import unpack

    # A demo folder: a source body, a training body, one garment on both.
    demo = tmp_path / "demo"
    body = mesh_from_triangles(*icosphere(1), name="body")
    (demo / "bodies").mkdir(parents=True)
    write_obj(demo / "bodies" / "banana.obj", body)
    g = grid(5, 4)
    (demo / "garments" / "skirt").mkdir(parents=True)
    for b in ("banana", "pear"):
        write_obj(demo / "garments" / "skirt" / f"{b}.obj", g, g.V + [0.1, 0.2, 1.3])
    write_obj(demo / "bodies" / "pear.obj", body, body.V * 1.1)
    (demo / "manifest.json").write_text(json.dumps({"bodies": ["banana", "pear"], "garments": ["skirt"],
                                                    "source": "banana", "targets": ["pear"],
                                                    "train_garments": ["skirt"], "test_garments": []}))
    extra = tmp_path / "extra.npz"
    np.savez(extra, metadata=np.array(json.dumps({"source": "banana", "targets": ["pear"], "garments": [],
                                                   "source_step": SOURCE_STEP, "offset_step": OFFSET_STEP})))
    # The work folder of the in-between drape: its body and the garment on it.
    work = tmp_path / "work"
    (work / "bodies").mkdir(parents=True)
    write_obj(work / "bodies" / "pear_heavy.obj", body, body.V * 1.2)
    (work / "garments" / "skirt").mkdir(parents=True)
    write_obj(work / "garments" / "skirt" / "banana.obj", g, g.V + [0.1, 0.2, 1.3])
    write_obj(work / "garments" / "skirt" / "pear_heavy.obj", g, g.V + [0.1, 0.25, 1.3])
    (work / "log.txt").write_text("[ 1.0s] garment 1/1 skirt: 20 vertices, 24 triangles, 3.5s, vertices inside "
                                  "the body before/after the fix [0, 0]/[0, 0]\n")
    packed = tmp_path / "between.npz"
    meta = pack(work, packed, source="banana", targets=("pear_heavy",), with_bodies=True)
    assert meta["bodies"] == ["pear_heavy"]
    (work / "bodies" / "pear_heavy.obj").unlink()
    with pytest.raises(ValueError, match="pear_heavy.obj: body not found"):
        pack(work, tmp_path / "other.npz", source="banana", targets=("pear_heavy",), with_bodies=True)

    out = tmp_path / "dataset"
    unpack(out, packed=extra, demo=demo, between=packed)
    ds = load_dataset(out)
    assert "pear_heavy" in ds.bodies and ds.manifest["between_bodies"] == {"pear_heavy": ["pear", "heavy", 0.5]}
    np.testing.assert_allclose(ds.body("pear_heavy").V, body.V * 1.2, atol=SOURCE_STEP)
    np.testing.assert_array_equal(ds.body("pear_heavy").F, ds.body("banana").F)
    np.testing.assert_allclose(ds.garment("skirt", "pear_heavy").V, g.V + [0.1, 0.25, 1.3],
                               atol=SOURCE_STEP + OFFSET_STEP)
    # The demo's own files are not rewritten.
    np.testing.assert_array_equal(ds.garment("skirt", "pear").V, read_obj(demo / "garments" / "skirt" / "pear.obj").V)
