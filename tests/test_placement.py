import json

import numpy as np
import pytest
from meshes import icosphere
from test_dataset import make_tiny_dataset

from garment_transfer.errors import ModelError
from garment_transfer.geometry.binding import bind, carry
from garment_transfer.geometry.gradients import orthonormal_frames
from garment_transfer.learning.dataset import load_dataset
from garment_transfer.learning.garment_model import load_garment_model
from garment_transfer.learning.placement import (
    placement_displacements,
    smooth_on_body,
    triangle_laplacian,
    true_offsets,
    unrotate,
)
from garment_transfer.pipeline.transfer import transfer_garment

TARGETS = ["similar", "pear"]


def rotation(axis, degrees):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    a = np.radians(degrees)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(a) * K + (1 - np.cos(a)) * K @ K


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    return make_tiny_dataset(tmp_path_factory.mktemp("tiny") / "ds")


@pytest.fixture(scope="module")
def moved(tiny):
    """The tiny source body, the same body turned and shifted, and a garment on it."""
    ds = load_dataset(tiny)
    src, g = ds.body("src"), ds.garment("top", "src")
    R = rotation([1.0, 2.0, 0.5], 40)
    t = np.array([0.3, -0.1, 0.2])
    return src, src.with_vertices(src.V @ R.T + t, name="moved"), g, R


def test_triangle_laplacian_of_a_closed_surface():
    V, F = icosphere(1)
    L = triangle_laplacian(F)
    # Every triangle of a closed surface has three edge neighbours.
    np.testing.assert_array_equal(L.diagonal(), 3.0)
    np.testing.assert_allclose(L @ np.ones(F.shape[0]), 0.0, atol=1e-12)
    assert (L - L.T).nnz == 0


def test_smoothing_keeps_a_constant_and_fills_empty_triangles():
    V, F = icosphere(2)
    M = F.shape[0]
    w = np.zeros(M)
    w[: M // 3] = 2.0
    values = np.where(w[:, None] > 0, [[1.0, -2.0, 0.5]], 7.0)
    X = smooth_on_body(values, w, V, F, 0.3)
    np.testing.assert_allclose(X, np.tile([1.0, -2.0, 0.5], (M, 1)), atol=1e-6)
    np.testing.assert_array_equal(smooth_on_body(values, w, V, F, 0.0), values)
    noisy = np.random.default_rng(0).normal(size=(M, 3))
    assert smooth_on_body(noisy, np.ones(M), V, F, 0.3).std() < 0.5 * noisy.std()


def test_zero_placement_leaves_the_transfer_unchanged(tiny):
    ds = load_dataset(tiny)
    src, tgt, g = ds.body("src"), ds.body("pear"), ds.garment("top", "src")
    for anchoring in ("everywhere", "contact"):
        a = transfer_garment(src, tgt, g, anchoring=anchoring)
        b = transfer_garment(src, tgt, g, anchoring=anchoring, placement=np.zeros((src.F.shape[0], 3)))
        np.testing.assert_allclose(b.V, a.V, atol=1e-12, rtol=0)
        assert b.info["placement"] and not a.info["placement"]


def test_constant_offset_in_every_frame_of_a_rigidly_moved_body(moved):
    src, tgt, g, R = moved
    binding = bind(g.V, src.V, src.F)
    S = orthonormal_frames(src.V, src.F)
    M = src.F.shape[0]
    # A lift along every triangle's normal: each anchor moves along its triangle's normal on the target.
    D = placement_displacements(binding, tgt.V, src.F, np.tile([0.0, 0.0, 0.02], (M, 1)))
    np.testing.assert_allclose(D, 0.02 * (S[binding.triangle, 2] @ R.T), atol=1e-12)
    # Any constant offset in the frames: the source frame's vector, turned with the body.
    c = np.array([0.01, -0.03, 0.005])
    D = placement_displacements(binding, tgt.V, src.F, np.tile(c, (M, 1)))
    np.testing.assert_allclose(D, np.einsum("pji,j->pi", S[binding.triangle], c) @ R.T, atol=1e-12)
    # The triangles' own turn is the body's.
    np.testing.assert_allclose(unrotate(src.V, tgt.V, src.F), np.broadcast_to(R.T, (M, 3, 3)), atol=1e-12)


def test_a_placement_that_is_one_vector_unrotated_moves_the_whole_transfer_by_it_turned(moved):
    # A rigid motion: the direct field is the rotation everywhere, so a uniform shift of the anchors
    # shifts the rebuilt garment by exactly as much.
    src, tgt, g, R = moved
    v = np.array([0.02, 0.01, -0.015])
    C = orthonormal_frames(src.V, src.F) @ v
    a = transfer_garment(src, tgt, g, fix_penetration=False)
    b = transfer_garment(src, tgt, g, fix_penetration=False, placement=C)
    np.testing.assert_allclose(b.V - a.V, np.tile(R @ v, (g.n_vertices, 1)), atol=1e-9)


def test_true_offsets_give_back_a_known_placement(moved):
    src, tgt, g, R = moved
    binding = bind(g.V, src.V, src.F)
    v = np.array([0.01, 0.0, -0.02])
    on_target = carry(binding, tgt.V, src.F) + R @ v
    C, y, w = true_offsets(binding, src, tgt, on_target)
    assert w.sum() == g.n_vertices
    np.testing.assert_allclose(y, np.tile(v, (src.F.shape[0], 1)), atol=1e-6)
    np.testing.assert_allclose(placement_displacements(binding, tgt.V, src.F, C), np.tile(R @ v, (g.n_vertices, 1)),
                               atol=1e-6)


def test_a_placement_of_the_wrong_size_is_refused(tiny):
    ds = load_dataset(tiny)
    src, tgt, g = ds.body("src"), ds.body("pear"), ds.garment("top", "src")
    with pytest.raises(ValueError, match="one offset per body triangle"):
        transfer_garment(src, tgt, g, placement=np.zeros((3, 3)))
    with pytest.raises(ValueError, match="not finite"):
        transfer_garment(src, tgt, g, placement=np.full((src.F.shape[0], 3), np.nan))


torch = pytest.importorskip("torch")


@pytest.fixture(scope="module")
def trained(tiny):
    from garment_transfer.learning.garment_training import placement_tables, train_placement_model, training_tables

    tables = training_tables(tiny, "src", TARGETS, ["band", "skirt"])
    placement_tables(tiny, "src", TARGETS, ["band", "skirt"], tables)
    model, info = train_placement_model(tables, TARGETS, hidden=(16,), epochs=30, batch=256, seed=1, threads=1)
    return model, info, tables


def test_placement_training_lowers_the_loss(trained):
    model, info, tables = trained
    assert info["samples"] == int((tables["bound"] > 0).sum()) * len(TARGETS)
    assert info["losses"][-1] < 0.85 * info["losses"][0]
    assert model.metadata["format"] == "garment_transfer.garment_placement_model"


def test_placement_model_round_trip_and_transfer(trained, tiny, tmp_path):
    model, _, _ = trained
    path = tmp_path / "placement.npz"
    model.save(path)
    with np.load(path, allow_pickle=False) as npz:
        assert all(npz[k].dtype != object for k in npz.files)
    from garment_transfer.learning.placement import load_placement_model

    loaded = load_placement_model(path)
    ds = load_dataset(tiny)
    src, tgt, g = ds.body("src"), ds.body("pear"), ds.garment("top", "src")
    binding = bind(g.V, src.V, src.F)
    C = model.frame_offsets(binding, src, tgt, g, "pear")
    np.testing.assert_array_equal(loaded.frame_offsets(binding, src, tgt, g, "pear"), C)
    assert np.isfinite(C).all() and np.abs(C).max() > 0
    r = transfer_garment(src, tgt, g, placement=loaded, target="pear")
    expect = transfer_garment(src, tgt, g, placement=C)
    np.testing.assert_allclose(r.V, expect.V, atol=1e-12)
    # A body between the training targets: label weights from its shape.
    mid = src.with_vertices(0.5 * (ds.body("similar").V + tgt.V))
    assert np.isfinite(loaded.frame_offsets(binding, src, mid, g)).all()


def test_placement_model_files_of_another_version_or_kind_are_refused(trained, tmp_path):
    from garment_transfer.learning.placement import load_placement_model

    model, _, _ = trained
    newer = tmp_path / "newer.npz"
    np.savez(newer, metadata=np.array(json.dumps({**model.metadata, "format_version": 99})), **model.arrays)
    with pytest.raises(ModelError, match=r"newer.npz: has format version 99; this version reads versions 1 and 2"):
        load_placement_model(newer)
    with pytest.raises(ModelError, match="is not a garment fit model"):
        load_garment_model(newer)
    pickled = tmp_path / "pickled.npz"
    np.savez(pickled, metadata=np.array(json.dumps(model.metadata)), W0=np.array([object()], dtype=object))
    with pytest.raises(ModelError, match="only plain arrays"):
        load_placement_model(pickled)
    with pytest.raises(ModelError, match="placement model, not a field model"):
        model.body_field("pear")


def test_body_offset_features_of_a_shifted_and_an_inflated_sphere():
    from garment_transfer.learning.placement import body_offset_features

    V, F = icosphere(2)
    X = body_offset_features(V, V + np.array([0.4, -0.2, 0.1]), F, shares=(0.3,))
    assert X.shape == (F.shape[0], 6)
    np.testing.assert_allclose(X, 0.0, atol=1e-12)
    # Grown by 10% about its centre: every triangle moved outward along its normal, not along the surface.
    X = body_offset_features(V, 1.1 * V, F, shares=())
    centroids = V[F].mean(axis=1)
    from garment_transfer.geometry.embedding import body_scale

    n = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    np.testing.assert_allclose(X[:, 2], 0.1 * np.einsum("ij,ij->i", centroids, n) / body_scale(V), rtol=1e-9)
    assert (X[:, 2] > 0).all()
    assert np.abs(X[:, :2]).max() < 0.1 * X[:, 2].min()


def test_placement_model_with_the_body_offset(trained, tiny, tmp_path):
    from garment_transfer.learning.garment_training import train_placement_model
    from garment_transfer.learning.placement import BODY_OFFSET_SHARES, load_placement_model

    _, _, tables = trained
    model, info = train_placement_model(tables, TARGETS, hidden=(16,), epochs=30, batch=256, seed=1, threads=1,
                                        body_offset=True)
    assert model.metadata["body_offset_shares"] == list(BODY_OFFSET_SHARES)
    assert model.arrays["input_mean"].shape == (model.n_inputs(model.metadata),)
    assert info["losses"][-1] < 0.85 * info["losses"][0]
    path = tmp_path / "offset.npz"
    model.save(path)
    loaded = load_placement_model(path)
    ds = load_dataset(tiny)
    src, tgt, g = ds.body("src"), ds.body("pear"), ds.garment("top", "src")
    binding = bind(g.V, src.V, src.F)
    C = loaded.frame_offsets(binding, src, tgt, g, "pear")
    np.testing.assert_array_equal(C, model.frame_offsets(binding, src, tgt, g, "pear"))
    assert np.isfinite(C).all() and np.abs(C).max() > 0


def test_blended_placement_of_a_body_between_two_training_bodies(trained, tiny):
    from garment_transfer.learning.placement import BlendedPlacement

    model, _, _ = trained
    blend = BlendedPlacement(model)
    ds = load_dataset(tiny)
    src, g = ds.body("src"), ds.garment("top", "src")
    binding = bind(g.V, src.V, src.F)
    bodies = [src.with_vertices(np.asarray(model.arrays["label_bodies"][k], dtype=np.float64)) for k in range(2)]
    own = [model.frame_offsets(binding, src, b, g, t) for b, t in zip(bodies, TARGETS)]
    # A training body by label, or by shape alone: the model's own prediction.
    np.testing.assert_array_equal(blend.frame_offsets(binding, src, bodies[1], g, TARGETS[1]), own[1])
    np.testing.assert_allclose(blend.frame_offsets(binding, src, bodies[1], g), own[1], atol=1e-9)
    # Halfway between them: halfway between their placements (not the network at a mixed label).
    mid = src.with_vertices(0.5 * (bodies[0].V + bodies[1].V))
    np.testing.assert_allclose(blend.frame_offsets(binding, src, mid, g), 0.5 * (own[0] + own[1]), atol=1e-9)
    assert np.abs(own[0] - own[1]).max() > 1e-4
    r = transfer_garment(src, mid, g, placement=blend)
    np.testing.assert_allclose(r.V, transfer_garment(src, mid, g, placement=0.5 * (own[0] + own[1])).V, atol=1e-9)


def test_an_ensemble_of_identical_members_is_the_single_model(trained, tiny):
    from garment_transfer.learning.placement import BlendedPlacement, PlacementEnsemble, PlacementModel

    model, _, _ = trained
    same = PlacementEnsemble([model, PlacementModel(model.arrays, model.metadata, "copy"), model])
    assert same.targets == model.targets and same.name == model.name
    ds = load_dataset(tiny)
    src, tgt, g = ds.body("src"), ds.body("pear"), ds.garment("top", "src")
    binding = bind(g.V, src.V, src.F)
    mid = src.with_vertices(0.5 * (ds.body("similar").V + tgt.V))
    for body, label in ((tgt, "pear"), (mid, None)):
        C = model.frame_offsets(binding, src, body, g, label)
        assert np.abs(C).max() > 1e-4
        np.testing.assert_allclose(same.frame_offsets(binding, src, body, g, label), C, rtol=0, atol=1e-12)
        np.testing.assert_allclose(BlendedPlacement(same).frame_offsets(binding, src, body, g, label),
                                   BlendedPlacement(model).frame_offsets(binding, src, body, g, label),
                                   rtol=0, atol=1e-12)
    np.testing.assert_allclose(transfer_garment(src, tgt, g, placement=same, target="pear").V,
                               transfer_garment(src, tgt, g, placement=model, target="pear").V, rtol=0, atol=1e-12)


def test_an_ensemble_predicts_the_mean_of_its_members_trained_with_successive_seeds(trained, tiny):
    from garment_transfer.learning.garment_training import train_placement_ensemble
    from garment_transfer.learning.placement import BlendedPlacement, PlacementEnsemble, PlacementModel

    model, _, tables = trained
    ensemble, info = train_placement_ensemble(tables, TARGETS, 2, seed=1, hidden=(16,), epochs=30, batch=256,
                                              threads=1)
    assert isinstance(ensemble, PlacementEnsemble) and len(ensemble.members) == 2 and info["members"] == 2
    assert len(info["losses"]) == 30 and info["samples"] == int((tables["bound"] > 0).sum()) * len(TARGETS)
    first, second = ensemble.members
    # The first member is the single model of the same seed; the second another network.
    assert all(np.array_equal(first.arrays[k], model.arrays[k]) for k in model.arrays)
    assert first.metadata["training"]["seed"] == 1 and second.metadata["training"]["seed"] == 2
    ds = load_dataset(tiny)
    src, tgt, g = ds.body("src"), ds.body("pear"), ds.garment("top", "src")
    binding = bind(g.V, src.V, src.F)
    mid = src.with_vertices(0.5 * (ds.body("similar").V + tgt.V))
    for body, label in ((tgt, "pear"), (mid, None)):
        own = [m.frame_offsets(binding, src, body, g, label) for m in (first, second)]
        assert np.abs(own[0] - own[1]).max() > 1e-4
        np.testing.assert_allclose(ensemble.frame_offsets(binding, src, body, g, label), 0.5 * (own[0] + own[1]),
                                   rtol=0, atol=1e-12)
    blended = [BlendedPlacement(m).frame_offsets(binding, src, mid, g) for m in (first, second)]
    np.testing.assert_allclose(BlendedPlacement(ensemble).frame_offsets(binding, src, mid, g),
                               0.5 * (blended[0] + blended[1]), rtol=0, atol=1e-12)
    single, single_info = train_placement_ensemble(tables, TARGETS, 1, seed=1, hidden=(16,), epochs=30, batch=256,
                                                   threads=1)
    assert isinstance(single, PlacementModel) and single_info["members"] == 1
    assert all(np.array_equal(single.arrays[k], model.arrays[k]) for k in model.arrays)
    # Members must agree on their inputs and smoothing, and at least one is needed.
    other = PlacementModel(second.arrays, {**second.metadata, "smoothing_share": 0.5}, "other.npz")
    with pytest.raises(ModelError, match=r"other.npz: placement member 1 differs from member 0 \(placement model\) "
                                         r"in 'smoothing_share'"):
        PlacementEnsemble([first, other])
    with pytest.raises(ValueError, match="at least one member"):
        PlacementEnsemble([])
    with pytest.raises(ValueError, match="whole number >= 1 of members, got 0"):
        train_placement_ensemble(tables, TARGETS, 0)
    with pytest.raises(ValueError, match="whole number >= 1 of members, got 1.5"):
        train_placement_ensemble(tables, TARGETS, 1.5)


def test_mean_offsets_weighs_garments_by_their_bound_points():
    from garment_transfer.learning.placement import mean_offsets

    offset = np.zeros((2, 2, 3, 3))
    offset[0, :, :, 0] = 1.0          # garment 0: +1 along x on every triangle and target
    offset[1, 1, :, 1] = 4.0          # garment 1: +4 along y on target 1
    bound = np.array([[1.0, 3.0, 0.0], [3.0, 1.0, 0.0]])
    base = mean_offsets(offset, bound)
    assert base.shape == (2, 3, 3)
    np.testing.assert_allclose(base[:, 0, 0], 0.25)
    np.testing.assert_allclose(base[:, 1, 0], 0.75)
    np.testing.assert_allclose(base[1, :2, 1], [3.0, 1.0])
    np.testing.assert_allclose(base[0, :, 1], 0.0)
    # A triangle no garment is bound to: no offset.
    np.testing.assert_array_equal(base[:, 2], 0.0)
    with pytest.raises(ValueError, match="do not fit"):
        mean_offsets(offset, bound[:, :2])


def test_a_residual_placement_adds_the_training_garments_mean_offset(trained, tiny, tmp_path):
    from garment_transfer.geometry.embedding import body_scale
    from garment_transfer.learning.garment_training import train_placement_model
    from garment_transfer.learning.placement import PlacementModel, load_placement_model, mean_offsets, smooth_on_body

    model, _, tables = trained
    res, info = train_placement_model(tables, TARGETS, hidden=(16,), epochs=30, batch=256, seed=1, threads=1,
                                      residual=True)
    assert res.metadata["format_version"] == 2 and res.metadata["training"]["residual"] is True
    assert model.metadata["format_version"] == 1 and "offset_base" not in model.arrays
    base = mean_offsets(tables["offset"], tables["bound"])
    np.testing.assert_allclose(res.arrays["offset_base"], base, rtol=1e-6, atol=1e-9)
    assert np.abs(base).max() > 1e-3
    assert info["losses"][-1] < 0.85 * info["losses"][0]
    ds = load_dataset(tiny)
    src, g = ds.body("src"), ds.garment("top", "src")
    binding = bind(g.V, src.V, src.F)
    w = np.bincount(binding.triangle, minlength=src.F.shape[0]).astype(float)
    length = res.metadata["smoothing_share"] * body_scale(src.V)
    # Its prediction is the network's plus the base of the target's label (blended for a body between).
    network_only = PlacementModel({**res.arrays, "offset_base": np.zeros_like(res.arrays["offset_base"])},
                                  res.metadata, "zero base")
    tgt = ds.body("pear")
    mid = src.with_vertices(0.5 * (ds.body("similar").V + tgt.V))
    for body, label in ((tgt, "pear"), (mid, None)):
        lw = res.label_weights_for(body, label)
        bound_base = np.where((w > 0)[:, None], np.einsum("k,kmc->mc", lw, base), 0.0)
        np.testing.assert_allclose(res.unrotated_offsets(binding, src, body, g, label),
                                   network_only.unrotated_offsets(binding, src, body, g, label)
                                   + smooth_on_body(bound_base, w, src.V, src.F, length), rtol=0, atol=1e-6)
    # Written as format version 2, read back the same; a version 1 file of the same network as before.
    path = tmp_path / "residual.npz"
    res.save(path)
    loaded = load_placement_model(path)
    assert loaded.metadata["format_version"] == 2
    np.testing.assert_array_equal(loaded.frame_offsets(binding, src, tgt, g, "pear"),
                                  res.frame_offsets(binding, src, tgt, g, "pear"))
    old = tmp_path / "old.npz"
    model.save(old)
    np.testing.assert_array_equal(load_placement_model(old).frame_offsets(binding, src, tgt, g, "pear"),
                                  model.frame_offsets(binding, src, tgt, g, "pear"))
    # The base and the version go together; a base of the wrong shape or not finite is refused.
    arrays = {k: v for k, v in res.arrays.items() if k != "offset_base"}
    cases = {"no_base.npz": (arrays, res.metadata, "needs the array 'offset_base'"),
             "v1_base.npz": (res.arrays, {**res.metadata, "format_version": 1}, "which format version 1 does not have"),
             "short_base.npz": ({**arrays, "offset_base": res.arrays["offset_base"][:1]}, res.metadata,
                                r"offset_base' of shape \(2, "),
             "nan_base.npz": ({**arrays, "offset_base": np.full_like(res.arrays["offset_base"], np.nan)},
                              res.metadata, "not finite")}
    for name, (a, md, message) in cases.items():
        bad = tmp_path / name
        np.savez(bad, metadata=np.array(json.dumps(md)), **a)
        with pytest.raises(ModelError, match=f"{name}: .*{message}"):
            load_placement_model(bad)


def test_placement_training_options(trained):
    from garment_transfer.learning.garment_training import train_placement_model

    model, _, tables = trained
    kw = dict(hidden=(16,), epochs=30, batch=256, seed=1, threads=1)
    # Weighted by bound points that are the same everywhere: the same network as unweighted.
    even = {**tables, "bound": np.where(tables["bound"] > 0, 2.0, 0.0).astype(np.float32)}
    same, _ = train_placement_model(even, TARGETS, weighted=True, **kw)
    assert all(np.array_equal(same.arrays[k], model.arrays[k]) for k in model.arrays)
    weighted, _ = train_placement_model(tables, TARGETS, weighted=True, **kw)
    assert len(np.unique(tables["bound"][tables["bound"] > 0])) > 1
    assert not np.array_equal(weighted.arrays["W0"], model.arrays["W0"])
    assert weighted.metadata["training"]["weighted"] is True and model.metadata["training"]["weighted"] is False
    cosine, info = train_placement_model(tables, TARGETS, schedule="cosine", **kw)
    assert cosine.metadata["training"]["schedule"] == "cosine" and model.metadata["training"]["schedule"] == "exp"
    assert info["losses"][-1] < 0.85 * info["losses"][0]
    assert not np.array_equal(cosine.arrays["W0"], model.arrays["W0"])
    # Decoupled weight decay shrinks the weights.
    decayed, _ = train_placement_model(tables, TARGETS, weight_decay=5.0, **kw)
    assert decayed.metadata["training"]["weight_decay"] == 5.0
    norm = [sum(float(np.sum(m.arrays[f"W{i}"] ** 2)) for i in range(2)) for m in (model, decayed)]
    assert norm[1] < 0.8 * norm[0]
    with pytest.raises(ValueError, match="unknown learning rate schedule 'linear'"):
        train_placement_model(tables, TARGETS, schedule="linear", **kw)
