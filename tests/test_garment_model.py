import json

import numpy as np
import pytest
from meshes import grid, icosphere
from test_dataset import make_tiny_dataset

from garment_transfer.errors import ModelError
from garment_transfer.geometry.embedding import body_scale
from garment_transfer.geometry.gradients import deformation_gradients
from garment_transfer.geometry.mesh import mesh_from_triangles
from garment_transfer.geometry.poisson import PoissonSolver
from garment_transfer.learning.dataset import load_dataset
from garment_transfer.learning.garment_model import (
    GARMENT_FEATURES,
    garment_features,
    label_weights,
    load_garment_model,
    target_features,
)
from garment_transfer.pipeline.transfer import anchor_weights, prepare_garment, transfer_garment

TARGETS = ["similar", "pear"]


def test_garment_features_of_a_lifted_copy():
    # The garment is the body sheet lifted along its normal: every triangle is covered, the offset
    # points along the body normal and the garment faces the same way.
    body = grid(6, 5)
    lift = 0.01
    X, covered = garment_features(body.V, body.F, body.V + [0, 0, lift], body.F)
    assert X.shape == (body.F.shape[0], len(GARMENT_FEATURES)) and covered.all()
    scale = body_scale(body.V)
    np.testing.assert_allclose(X[:, 1], lift / scale, rtol=1e-12)
    np.testing.assert_allclose(X[:, 2], lift / scale * np.sign(X[:, 5]), rtol=1e-12)
    np.testing.assert_allclose(np.abs(X[:, 3:6]), np.tile([0, 0, 1.0], (len(X), 1)), atol=1e-12)
    np.testing.assert_allclose(X[:, 6:9], np.tile([0, 0, 1.0], (len(X), 1)) * np.sign(X[:, 5:6]), atol=1e-12)


def test_garment_features_zero_where_uncovered():
    body = grid(8, 8)
    piece = grid(2, 2)
    X, covered = garment_features(body.V, body.F, piece.V * 0.1 + [0, 0, 0.001], piece.F, cover_distance=0.2)
    assert covered.any() and not covered.all()
    assert np.all(X[~covered, :9] == 0)
    assert np.all(X[covered, 0] == 1)


@pytest.mark.parametrize("share", [0.02, 0.11, 0.5])
def test_neighbourhood_mean_equals_every_pair_within_the_radius(share):
    # The blocked computation against the definition: every pair of centroids, its distance, the
    # weighted mean over those within the radius (the triangle itself included). Points on a body-like
    # cloud with clusters (dense hands, sparse torso) and blocks smaller than the cloud.
    from garment_transfer.learning.garment_model import neighbourhood_mean

    rng = np.random.default_rng(3)
    P = np.concatenate([rng.normal(size=(600, 3)) * [0.2, 0.1, 0.8], 0.02 * rng.normal(size=(300, 3)) + [0.5, 0, 0.3]])
    values = rng.normal(size=(P.shape[0], 4))
    weights = rng.uniform(0.1, 2.0, size=P.shape[0])
    radius = share * np.ptp(P, axis=0).max()
    within = np.linalg.norm(P[:, None] - P[None], axis=2) <= radius
    expected = (within * weights) @ values / (within @ weights)[:, None]
    np.testing.assert_allclose(neighbourhood_mean(P, values, radius, weights, chunk=64), expected,
                               rtol=0, atol=1e-12)
    # Some rows only: theirs the same, the others NaN.
    rows = rng.uniform(size=P.shape[0]) < 0.3
    some = neighbourhood_mean(P, values, radius, weights, chunk=64, rows=rows)
    np.testing.assert_allclose(some[rows], expected[rows], rtol=0, atol=1e-12)
    assert np.isnan(some[~rows]).all()


def test_target_features_of_an_unchanged_and_a_scaled_body():
    V, F = icosphere(2)
    X, dev = target_features(V, V, F)
    np.testing.assert_allclose(X, 0.0, atol=1e-12)
    X, dev = target_features(V, 1.5 * V, F)
    # A uniform scale is the same gradient everywhere: its local and neighbourhood means agree.
    expect = (0.5 * np.eye(3)).reshape(9)
    np.testing.assert_allclose(dev, np.tile(expect, (F.shape[0], 1)), atol=1e-12)
    np.testing.assert_allclose(X, np.tile(expect, (F.shape[0], X.shape[1] // 9)), atol=1e-12)


def test_label_weights_one_hot_and_between_two_bodies():
    V, _ = icosphere(1)
    bodies = np.stack([V, V * [1.3, 1.0, 1.0], V * [1.0, 1.0, 0.7]])
    for k in range(3):
        np.testing.assert_allclose(label_weights(bodies[k], bodies), np.eye(3)[k], atol=1e-6)
    np.testing.assert_allclose(label_weights(0.5 * (bodies[0] + bodies[2]), bodies), [0.5, 0, 0.5], atol=1e-6)


def test_poisson_per_vertex_weights_equal_to_a_scalar_give_the_same_solution():
    m = grid(7, 6)
    rng = np.random.default_rng(0)
    Q = np.eye(3) + 0.1 * rng.normal(size=(m.F.shape[0], 3, 3))
    anchors = m.V + rng.normal(size=m.V.shape) * 0.01
    a = PoissonSolver(m.V, m.F, 1e-2).solve(Q, anchors)
    b = PoissonSolver(m.V, m.F, np.full(m.V.shape[0], 1e-2)).solve(Q, anchors)
    np.testing.assert_allclose(a, b, atol=1e-12)
    with pytest.raises(ValueError, match="anchor_weight"):
        PoissonSolver(m.V, m.F, np.ones(3))
    with pytest.raises(ValueError, match="anchor_weight"):
        PoissonSolver(m.V, m.F, np.r_[0.0, np.ones(m.V.shape[0] - 1)])


def test_contact_anchoring_ties_only_what_rests_on_the_body():
    m = grid(5, 5)
    d = np.linspace(0.0, 0.1, m.V.shape[0])
    w = anchor_weights(m, d, scale=1.0, stiffness=0.04, anchoring="contact", contact=0.02)
    lam = anchor_weights(m, d, scale=1.0, stiffness=0.04)
    assert np.isscalar(lam) or np.ndim(lam) == 0
    np.testing.assert_allclose(w[d <= 0.02], lam)
    assert np.all(w[d >= 0.04] < 0.01 * lam) and np.all(w > 0)
    assert np.all(np.diff(w) <= 1e-15)
    with pytest.raises(ValueError, match="anchoring"):
        anchor_weights(m, d, 1.0, 0.04, anchoring="somewhere")


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    return make_tiny_dataset(tmp_path_factory.mktemp("tiny") / "ds")


torch = pytest.importorskip("torch")


@pytest.fixture(scope="module")
def trained(tiny):
    from garment_transfer.learning.garment_training import train_garment_model, training_tables

    tables = training_tables(tiny, "src", TARGETS, ["band", "skirt"])
    model, info = train_garment_model(tables, TARGETS, hidden=(16,), epochs=30, batch=256, seed=1, threads=1)
    return model, info, tables


def test_training_lowers_the_loss(trained):
    _, info, _ = trained
    assert info["samples"] > 0
    assert info["losses"][-1] < 0.85 * info["losses"][0]


def test_numpy_inference_equals_torch(trained):
    model, _, tables = trained
    X = np.random.default_rng(0).normal(size=(50, model.arrays["input_mean"].shape[0]))
    layers = []
    n = model.metadata["layers"]
    for i in range(n):
        lin = torch.nn.Linear(*model.arrays[f"W{i}"].shape[::-1]).double()
        lin.weight.data = torch.from_numpy(model.arrays[f"W{i}"].astype(np.float64))
        lin.bias.data = torch.from_numpy(model.arrays[f"b{i}"])
        layers += [lin] + ([torch.nn.Tanh()] if i < n - 1 else [])
    x = torch.from_numpy((X - model.arrays["input_mean"]) / model.arrays["input_std"])
    np.testing.assert_allclose(model.forward(X), torch.nn.Sequential(*layers)(x).detach().numpy(), atol=1e-10)


def test_field_is_the_body_s_own_where_the_garment_is_absent_and_learned_where_it_is(trained, tiny):
    model, _, _ = trained
    ds = load_dataset(tiny)
    src, tgt, g = ds.body("src"), ds.body("pear"), ds.garment("top", "src")
    Q = model.body_field("pear", garment=g, source_body=src, target_body=tgt)
    body_Q = deformation_gradients(src.V, tgt.V, src.F)[0]
    _, covered = garment_features(src.V, src.F, g.V, g.F)
    np.testing.assert_allclose(Q[~covered], body_Q[~covered], atol=1e-12)
    assert np.abs(Q[covered] - body_Q[covered]).max() > 1e-4


def test_field_share_goes_from_the_body_s_field_to_the_model_s(trained, tiny):
    model, _, _ = trained
    ds = load_dataset(tiny)
    src, tgt, g = ds.body("src"), ds.body("pear"), ds.garment("top", "src")
    Q = model.body_field("pear", g, src, tgt)
    body_Q = deformation_gradients(src.V, tgt.V, src.F)[0]
    np.testing.assert_allclose(model.with_field_share(0.0).body_field("pear", g, src, tgt), body_Q, atol=1e-12)
    np.testing.assert_allclose(model.with_field_share(0.5).body_field("pear", g, src, tgt), 0.5 * (Q + body_Q),
                               atol=1e-12)
    assert model.field_share == 1.0
    with pytest.raises(ValueError, match="field share"):
        model.with_field_share(1.5)


def test_a_field_ensemble_is_the_mean_of_its_members_fields_at_the_same_share(trained, tiny):
    from garment_transfer.learning.garment_training import train_garment_model
    from lab.experiment import FieldEnsemble

    model, _, tables = trained
    other, _ = train_garment_model(tables, TARGETS, hidden=(16,), epochs=30, batch=256, seed=2, threads=1)
    ds = load_dataset(tiny)
    src, tgt, g = ds.body("src"), ds.body("pear"), ds.garment("top", "src")
    ensemble = FieldEnsemble([model, other])
    a, b = model.body_field("pear", g, src, tgt), other.body_field("pear", g, src, tgt)
    assert np.abs(a - b).max() > 1e-4
    np.testing.assert_allclose(ensemble.body_field("pear", g, src, tgt), 0.5 * (a + b), atol=1e-12)
    half = ensemble.with_field_share(0.25)
    np.testing.assert_allclose(half.body_field("pear", g, src, tgt),
                               0.5 * (model.with_field_share(0.25).body_field("pear", g, src, tgt)
                                      + other.with_field_share(0.25).body_field("pear", g, src, tgt)), atol=1e-12)
    assert ensemble.targets == model.targets and ensemble.field_share == 1.0 and half.field_share == 0.25


def test_saved_model_loads_without_pickle_and_transfers(trained, tiny, tmp_path):
    model, _, _ = trained
    path = tmp_path / "g.npz"
    model.save(path)
    loaded = load_garment_model(path)
    ds = load_dataset(tiny)
    src, tgt, g = ds.body("src"), ds.body("pear"), ds.garment("top", "src")
    np.testing.assert_array_equal(loaded.body_field("pear", g, src, tgt), model.body_field("pear", g, src, tgt))
    r = transfer_garment(src, tgt, g, method="model", model=loaded, target="pear", anchoring="contact")
    assert r.V.shape == g.V.shape and np.isfinite(r.V).all()
    assert r.info["anchoring"] == "contact"
    # An unknown body: label weights from its shape, halfway between the two training targets.
    mid = src.with_vertices(0.5 * (ds.body("similar").V + tgt.V))
    np.testing.assert_allclose(loaded.label_weights_for(mid), [0.5, 0.5], atol=1e-3)
    assert np.isfinite(loaded.body_field(None, g, src, mid)).all()


def test_broken_model_files_are_refused(trained, tmp_path):
    model, _, _ = trained
    bad = tmp_path / "pickled.npz"
    np.savez(bad, metadata=np.array(json.dumps(model.metadata)), W0=np.array([object()], dtype=object))
    with pytest.raises(ModelError, match="pickled.npz"):
        load_garment_model(bad)
    other = tmp_path / "other.npz"
    np.savez(other, metadata=np.array(json.dumps({**model.metadata, "format": "x"})), **model.arrays)
    with pytest.raises(ModelError, match="format"):
        load_garment_model(other)
    short = dict(model.arrays)
    del short["W0"]
    cut = tmp_path / "cut.npz"
    np.savez(cut, metadata=np.array(json.dumps(model.metadata)), **short)
    with pytest.raises(ModelError, match="W0"):
        load_garment_model(cut)
    with pytest.raises(ModelError, match="not found"):
        load_garment_model(tmp_path / "none.npz")


def test_model_refuses_another_source_body(trained):
    model, _, _ = trained
    V, F = icosphere(1)
    other = mesh_from_triangles(V, F, name="other")
    with pytest.raises(ModelError, match="other"):
        model.body_field("pear", other, other, other)


def test_prepare_garment_contact_anchoring_is_kept(tiny):
    ds = load_dataset(tiny)
    p = prepare_garment(ds.body("src"), ds.garment("skirt", "src"), anchoring="contact")
    assert p.anchoring == "contact"
    assert np.ndim(p.solver.anchor_weight) == 1
    with pytest.raises(ValueError, match="anchoring"):
        prepare_garment(ds.body("src"), ds.garment("skirt", "src"), anchoring="nowhere")


def test_makehuman_folds_never_train_on_the_held_out_garment_or_its_looser_cut():
    from lab.garment_model import makehuman_folds

    garments = ["suit_a", "suit_b", "suit_c", "suit_a_loose", "suit_b_loose", "trousers", "tshirt"]
    manifest = {"procedural_garments": ["trousers", "tshirt"],
                "variants": {"suit_a_loose": "suit_a", "suit_b_loose": "suit_b"}}
    held, folds = makehuman_folds(garments, manifest)
    assert held == ["suit_a", "suit_b", "suit_c"]                  # catalogue garments and cuts never held out
    assert folds[0] == (["suit_b", "suit_c", "suit_b_loose", "trousers", "tshirt"], ["suit_a"])
    assert folds[2] == (["suit_a", "suit_b", "suit_a_loose", "suit_b_loose", "trousers", "tshirt"], ["suit_c"])
    assert makehuman_folds(garments, manifest, ["suit_b"])[1] == [
        (["suit_a", "suit_c", "suit_a_loose", "trousers", "tshirt"], ["suit_b"])]
    # A plain fixture folder: every garment held out in turn, trained on the others.
    assert makehuman_folds(["a", "b"], {})[1] == [(["b"], ["a"]), (["a"], ["b"])]
    # A garment whose drape failed is neither trained on nor tested, named or not.
    failed = {"suit_b": {"male_average": 0.085}}
    held, folds = makehuman_folds(garments, manifest, failed=failed)
    assert held == ["suit_a", "suit_c"] and folds[0] == (["suit_c", "suit_b_loose", "trousers", "tshirt"], ["suit_a"])
    assert makehuman_folds(garments, manifest, ["suit_b", "suit_c"], failed)[0] == ["suit_c"]


def test_a_validation_fold_holds_out_styles_with_their_variants():
    from lab.garment_model import validation_fold

    garments = ["suit_a", "trousers", "trousers_loose", "trousers_tight", "tshirt", "sweater", "sweater_tight"]
    assert validation_fold(garments, ["trousers", "sweater"]) == (["suit_a", "tshirt"], ["trousers", "sweater"])
    with pytest.raises(SystemExit, match="skirt not among the training garments"):
        validation_fold(garments, ["skirt"])
    # An outfit with a held-out piece (or its variant) is held out of training too.
    outfits = {"outfit_a": ["tshirt", "trousers_loose"], "outfit_b": ["tshirt", "shorts"]}
    assert validation_fold(garments + list(outfits), ["trousers", "sweater"], outfits) == \
        (["suit_a", "tshirt", "outfit_b"], ["trousers", "sweater"])
