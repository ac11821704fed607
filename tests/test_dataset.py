import json
from pathlib import Path

import numpy as np
import pytest
from meshes import MAKEHUMAN, icosphere

from garment_transfer.errors import DatasetError
from garment_transfer.geometry.gradients import deformation_gradients
from garment_transfer.geometry.mesh import mesh_from_triangles
from garment_transfer.geometry.obj import write_obj
from garment_transfer.learning.dataset import build_training_fields, garment_field, load_dataset

SCALE = 1.2


def similar(V):
    """Uniform scale: every triangle's deformation gradient is exactly SCALE * I."""
    return V * SCALE


def pear(V):
    """A smooth, non-affine change of shape: wider at the bottom."""
    return V * (1.0 + 0.25 * np.clip(-V[:, 2:3], 0.0, None)) * np.array([1.0, 1.1, 1.0])


TARGETS = {"similar": similar, "pear": pear}


def piece(V, F, keep):
    """The triangles ``keep`` of (V, F) as a mesh of their own (own vertex numbering)."""
    F = F[keep]
    used, inv = np.unique(F.reshape(-1), return_inverse=True)
    return V[used], inv.reshape(-1, 3)


def tiny_garments():
    """Three garments of different topology around a unit sphere."""
    V, F = icosphere(3, radius=1.06)
    z = V[F].mean(axis=1)[:, 2]
    return {"skirt": piece(V, F, z < -0.2), "top": piece(V, F, z > 0.15),
            "band": piece(V, F, np.abs(z) < 0.4)}


def make_tiny_dataset(folder, garments=None, manifest=True):
    """A dataset folder: an icosphere body ``src``, targets ``similar`` and ``pear``, small garments.

    Returns the folder (a Path).
    """
    folder = Path(folder)
    (folder / "bodies").mkdir(parents=True)
    BV, BF = icosphere(2)
    body = mesh_from_triangles(BV, BF, name="src")
    write_obj(folder / "bodies" / "src.obj", body)
    for name, f in TARGETS.items():
        write_obj(folder / "bodies" / f"{name}.obj", body, f(BV))
    for g, (V, F) in (tiny_garments() if garments is None else garments).items():
        (folder / "garments" / g).mkdir(parents=True)
        m = mesh_from_triangles(V, F, name=g)
        write_obj(folder / "garments" / g / "src.obj", m)
        for name, f in TARGETS.items():
            write_obj(folder / "garments" / g / f"{name}.obj", m, f(V))
    if manifest:
        (folder / "manifest.json").write_text(json.dumps({"units": "metres", "up_axis": "Z"}))
    return folder


@pytest.fixture
def tiny(tmp_path):
    return make_tiny_dataset(tmp_path / "tiny")


def test_load_lists_bodies_garments_and_manifest_without_reading_meshes(tiny):
    ds = load_dataset(tiny)
    assert ds.bodies == ["pear", "similar", "src"]
    assert ds.garments == ["band", "skirt", "top"]
    assert (ds.units, ds.up_axis) == ("metres", "Z")
    assert ds._body_cache == {}
    assert ds.garment_bodies("top") == ["pear", "similar", "src"]
    assert ds.body("src").n_triangles == 320
    assert ds.body("src") is ds.body("src")


def test_manifest_order_wins_and_no_manifest_means_unknown_units(tmp_path):
    ds = load_dataset(make_tiny_dataset(tmp_path / "a", manifest=False))
    assert ds.units is None and ds.up_axis is None
    folder = make_tiny_dataset(tmp_path / "b")
    (folder / "manifest.json").write_text(json.dumps({"bodies": ["src", "pear", "similar"]}))
    assert load_dataset(folder).bodies == ["src", "pear", "similar"]


def test_field_of_a_similarity_is_exact_where_covered(tiny):
    tf = build_training_fields(tiny, "src", ["similar", "pear"])
    G, K, M = len(tf.garments), 2, 320
    assert tf.deviation.shape == (G, K, M, 9) and tf.deviation.dtype == np.float32
    assert tf.covered.shape == (G, M)
    want = (SCALE - 1.0) * np.eye(3).reshape(9)
    for g in range(G):
        cov = tf.covered[g]
        assert 0 < cov.sum() < M
        np.testing.assert_allclose(tf.deviation[g, 0, cov], np.broadcast_to(want, (cov.sum(), 9)), atol=1e-5)
        assert np.all(tf.deviation[g, :, ~cov] == 0.0)
    np.testing.assert_allclose(tf.body_deviation[0], np.broadcast_to(want, (M, 9)), atol=1e-5)


def test_coverage_follows_the_garment(tiny):
    tf = build_training_fields(tiny, "src", ["pear"])
    ds = load_dataset(tiny)
    z = ds.body("src").V[ds.body("src").F].mean(axis=1)[:, 2]
    top = tf.garments.index("top")
    assert tf.covered[top, z > 0.5].all()
    assert not tf.covered[top, z < -0.6].any()


def test_unmasked_embedding_keeps_the_nearest_value_everywhere(tiny):
    tf = build_training_fields(tiny, "src", ["similar"], keep_raw=True)
    want = (SCALE - 1.0) * np.eye(3).reshape(9)
    np.testing.assert_allclose(tf.raw_deviation[0, 0], np.broadcast_to(want, (320, 9)), atol=1e-5)


def test_garment_field_uses_the_source_triangles_for_both_shapes():
    BV, BF = icosphere(2)
    V, F = tiny_garments()["band"]
    A = np.array([[1.1, 0.2, 0.0], [0.0, 0.9, 0.1], [0.0, 0.0, 1.05]])
    B, covered = garment_field(BV, BF, V, F, V @ A.T)
    C, _ = deformation_gradients(V, V @ A.T, F)
    assert covered.any()
    for b in B[covered][:5]:
        assert any(np.allclose(b, c) for c in C)


def test_errors_name_what_is_wrong(tmp_path, tiny):
    with pytest.raises(DatasetError, match="not found"):
        load_dataset(tmp_path / "nowhere")
    (tmp_path / "empty" / "bodies").mkdir(parents=True)
    with pytest.raises(DatasetError, match="empty"):
        load_dataset(tmp_path / "empty")
    with pytest.raises(DatasetError, match="has no body 'nobody'.*pear, similar, src"):
        build_training_fields(tiny, "nobody", ["pear"])
    with pytest.raises(DatasetError, match="has no garment 'coat'"):
        build_training_fields(tiny, "src", ["pear"], garments=["coat"])
    with pytest.raises(DatasetError, match="cannot also be a target"):
        build_training_fields(tiny, "src", ["src"])


def test_empty_garments_folder(tmp_path):
    folder = make_tiny_dataset(tmp_path / "d", garments={}, manifest=False)
    with pytest.raises(DatasetError, match="empty: no garments"):
        load_dataset(folder)


def test_garment_missing_on_a_body_names_the_file(tiny):
    (tiny / "garments" / "skirt" / "pear.obj").unlink()
    with pytest.raises(DatasetError, match=r"skirt[/\\]pear\.obj: missing.*is on: similar, src"):
        build_training_fields(tiny, "src", ["similar", "pear"])
    build_training_fields(tiny, "src", ["similar"])


def test_garment_files_of_other_topology_name_the_file(tiny):
    V, F = tiny_garments()["band"]
    write_obj(tiny / "garments" / "band" / "pear.obj", mesh_from_triangles(V, F[::-1], name="x"))
    with pytest.raises(DatasetError, match=r"band[/\\]pear\.obj: has other faces"):
        build_training_fields(tiny, "src", ["pear"])
    write_obj(tiny / "garments" / "band" / "pear.obj", mesh_from_triangles(V[:-1], F[F.max(1) < len(V) - 1]))
    with pytest.raises(DatasetError, match=r"band[/\\]pear\.obj: has \d+ vertices"):
        build_training_fields(tiny, "src", ["pear"])


def test_bad_manifest(tiny):
    (tiny / "manifest.json").write_text("{not json")
    with pytest.raises(DatasetError, match="manifest.json: is not valid JSON"):
        load_dataset(tiny)
    (tiny / "manifest.json").write_text(json.dumps({"bodies": ["src", "giant"]}))
    with pytest.raises(DatasetError, match="lists bodies that .* lacks: giant.obj"):
        load_dataset(tiny)


def test_unreadable_garment_file_is_a_dataset_error(tiny):
    (tiny / "garments" / "top" / "pear.obj").write_text("v 0 0 0\n")
    with pytest.raises(DatasetError, match=r"top[/\\]pear\.obj"):
        build_training_fields(tiny, "src", ["pear"])


def test_makehuman_layout_and_one_field():
    if not (MAKEHUMAN / "bodies").is_dir():
        pytest.skip(f"MakeHuman fixtures not found at {MAKEHUMAN}")
    ds = load_dataset(MAKEHUMAN)
    assert (ds.units, ds.up_axis) == ("decimetres", "Y")
    assert len(ds.bodies) == 5 and len(ds.garments) == 8
    tf = build_training_fields(ds, "female_average", ["female_pear"], garments=["female_casualsuit02"])
    assert tf.deviation.shape == (1, 1, 26756, 9)
    share = tf.covered.mean()
    assert 0.1 < share < 0.6
    assert np.isfinite(tf.deviation).all()
