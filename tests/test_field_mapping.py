"""A model serving garments dressed on another body mesh: its field carried through a registration."""

import numpy as np
import pytest

pytest.importorskip("torch")

from meshes import random_rotation, require_makehuman  # noqa: E402

from garment_transfer.errors import ModelError  # noqa: E402
from garment_transfer.fitting.registration import register  # noqa: E402
from garment_transfer.geometry.obj import read_obj  # noqa: E402
from garment_transfer.learning.dataset import build_training_fields, load_dataset  # noqa: E402
from garment_transfer.learning.model import load_model  # noqa: E402
from garment_transfer.learning.training import train_model  # noqa: E402
from garment_transfer.pipeline.field_mapping import map_field, model_field  # noqa: E402
from garment_transfer.pipeline.metrics import mdc  # noqa: E402
from garment_transfer.pipeline.transfer import transfer_garment  # noqa: E402
from lab.paths import DEMO_DATA  # noqa: E402


@pytest.fixture(autouse=True)
def own_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("GARMENT_TRANSFER_CACHE", str(tmp_path / "cache"))


@pytest.fixture(scope="module")
def mannequin_model(tmp_path_factory):
    """A small shared model trained on the demo mannequins (metres, Z up), saved and loaded."""
    fields = build_training_fields(load_dataset(DEMO_DATA), "banana", ["pear"],
                                   garments=["straight_skirt", "aline_skirt", "tank_top"])
    model, _ = train_model(fields, latent=4, epochs=60, seed=1, threads=1)
    path = tmp_path_factory.mktemp("model") / "mannequins.npz"
    model.save(path)
    return load_model(path)


def test_a_field_carried_onto_the_same_body_moved_scaled_and_turned(mannequin_model):
    # The model's own body in decimetres, turned: every triangle must take its own triangle's value,
    # conjugated by the turn (a linear map A of the model's frame is R0 A R0^T in the turned one).
    body = mannequin_model.source_body
    rng = np.random.default_rng(4)
    R0 = random_rotation(rng)
    moved = body.with_vertices(10.0 * body.V @ R0.T + [3.0, -2.0, 1.0], name="turned")
    reg = register(body, moved, cache=False)
    A = np.eye(3) + 0.2 * rng.normal(size=(3, 3))
    Q = np.repeat(A[None], body.n_triangles, axis=0) * (1 + 0.1 * rng.random(body.n_triangles))[:, None, None]
    Q_to, tri = map_field(Q, reg, body, moved)
    assert np.mean(tri == np.arange(body.n_triangles)) > 0.99
    own = tri == np.arange(body.n_triangles)
    expected = np.einsum("ij,mjk,lk->mil", R0, Q[own], R0)
    # The alignment is found by ICP, to about 1e-5 in its rotation.
    np.testing.assert_allclose(Q_to[own], expected, atol=1e-4)
    assert np.abs(Q_to[own] - np.einsum("ji,mjk,kl->mil", R0, Q[own], R0)).max() > 1e-2


def test_model_of_the_mannequins_serves_a_makehuman_garment(mannequin_model):
    root = require_makehuman()
    source = read_obj(root / "bodies" / "female_average.obj")
    target = read_obj(root / "bodies" / "female_pear.obj")
    garment = read_obj(root / "garments" / "female_casualsuit01" / "female_average.obj")
    assert not mannequin_model.same_body(source)
    field = model_field(mannequin_model, "pear", source)
    assert field.shape == (source.n_triangles, 3, 3) and np.isfinite(field).all()
    r = transfer_garment(source, target, garment, method="model", model=mannequin_model, target="pear")
    direct = transfer_garment(source, target, garment)
    assert r.penetrating_vertices == 0
    # The carried field is turned into MakeHuman's frame (Y up): a field left in the mannequins'
    # frame (Z up) would wreck the folds, many times direct transfer's design change.
    assert mdc(garment.V, r.V, garment.F) < 2.0 * mdc(garment.V, direct.V, garment.F)
    turned_wrong = np.einsum("ij,mjk->mik", np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]]), field)
    from garment_transfer.pipeline.transfer import prepare_garment

    # Without the crossing pass: it cannot mend a garment that wrecked, and its rounds would only cost time.
    prepared = prepare_garment(source, garment)
    wrong = transfer_garment(source, target, garment, prepared=prepared, method="model",
                             model=_Fixed(mannequin_model, turned_wrong), target="pear", resolve_crossings=False)
    assert mdc(garment.V, wrong.V, garment.F) > 2.0 * mdc(garment.V, r.V, garment.F)


class _Fixed:
    """A model answering one given field (to show what a field in the wrong frame does)."""

    def __init__(self, model, field):
        self.name, self.targets, self._field = model.name, model.targets, field

    def check_source_body(self, mesh):
        pass

    def same_body(self, mesh):
        return True

    def body_field(self, target):
        return self._field


def test_a_model_without_its_body_is_refused_on_another_body(mannequin_model, tmp_path):
    from garment_transfer.learning.model import SharedDeformationModel

    arrays = {k: v for k, v in mannequin_model.arrays.items() if not k.startswith("source_")}
    old = SharedDeformationModel(arrays, mannequin_model.metadata, name="old.npz")
    assert old.source_body is None
    other = mannequin_model.source_body.with_vertices(mannequin_model.source_body.V)
    other.F = other.F[::-1].copy()
    other.face_vertices = other.face_vertices[::-1].copy()
    with pytest.raises(ModelError, match="old.npz.*trained on source body"):
        model_field(old, "pear", other)
    # A model holding part of its body, or another body than its hash says, is refused on loading.
    with pytest.raises(ModelError, match="part of its source body"):
        SharedDeformationModel(dict(arrays, source_V=mannequin_model.arrays["source_V"]),
                               mannequin_model.metadata, name="half.npz")
    damaged = dict(mannequin_model.arrays)
    damaged["source_face_vertices"] = damaged["source_face_vertices"][::-1].copy()
    with pytest.raises(ModelError, match="faces hash"):
        SharedDeformationModel(damaged, mannequin_model.metadata, name="bad.npz").source_body
