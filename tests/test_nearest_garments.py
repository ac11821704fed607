"""The nearest garments' placement: the training garments' own placements, weighted by likeness."""

import json

import numpy as np
import pytest
from meshes import icosphere
from test_dataset import make_tiny_dataset

from garment_transfer.errors import ModelError
from garment_transfer.geometry.binding import bind
from garment_transfer.geometry.gradients import orthonormal_frames
from garment_transfer.learning.dataset import load_dataset
from garment_transfer.learning.garment_training import nearest_garments, placement_tables, training_tables
from garment_transfer.learning.placement import (
    LIBRARY_FORMAT,
    BlendedPlacement,
    MixedPlacement,
    NearestGarments,
    bound_counts,
)
from garment_transfer.pipeline.transfer import transfer_garment

TARGETS = ["similar", "pear"]
TRAINING = ["band", "skirt"]


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    folder = make_tiny_dataset(tmp_path_factory.mktemp("nearest") / "ds")
    tables = training_tables(folder, "src", TARGETS, TRAINING)
    placement_tables(folder, "src", TARGETS, TRAINING, tables)
    return folder, tables


def test_the_library_keeps_each_garment_s_placement_on_its_bound_triangles(tiny):
    _, tables = tiny
    lib = nearest_garments(tables, TARGETS, TRAINING)
    a = lib.arrays
    assert lib.metadata["format"] == LIBRARY_FORMAT and lib.metadata["garments"] == TRAINING
    assert a["triangles"].shape[0] == int((tables["bound"] > 0).sum())
    for g in range(2):
        mine = a["garment"] == g
        idx = np.nonzero(tables["bound"][g] > 0)[0]
        np.testing.assert_array_equal(a["triangles"][mine], idx)
        np.testing.assert_array_equal(a["offsets"][:, mine], tables["offset"][g][:, idx])
        np.testing.assert_array_equal(a["weights"][mine], tables["bound"][g][idx])
    assert a["features"].shape[1] == 3 * len(tables["context_shares"]) + 2


def test_a_training_garment_gets_its_own_placement_back(tiny):
    folder, tables = tiny
    ds = load_dataset(folder)
    src = ds.body("src")
    lib = nearest_garments(tables, TARGETS, TRAINING, width=1e-6)
    for g, name in enumerate(TRAINING):
        garment = ds.garment(name, "src")
        w = bound_counts(bind(garment.V, src.V, src.F), src.n_triangles)
        feats = lib.similarity_features(src, garment)
        for k in range(2):
            y = lib.raw_offsets(w, feats, np.eye(2)[k])
            bound = w > 0
            np.testing.assert_allclose(y[bound], tables["offset"][g, k][bound], rtol=0, atol=1e-7)
            assert not y[~bound].any()
    # The two garments overlap, so the comparison above chose between them.
    assert ((tables["bound"][0] > 0) & (tables["bound"][1] > 0)).any()


def synthetic_library(M=4, K=2, width=0.5):
    """Two garments on a 4-triangle body: garment 0 on triangles 0 and 1, garment 1 on 0 and 2."""
    V, F = icosphere(0)
    F = F[:M]
    nb = V.shape[0]
    rng = np.random.default_rng(3)
    arrays = {"triangles": np.array([0, 1, 0, 2], np.int32), "garment": np.array([0, 0, 1, 1], np.int32),
              "features": rng.normal(size=(4, 5)).astype(np.float32),
              "offsets": rng.normal(size=(K, 4, 3)).astype(np.float32),
              "weights": np.array([2.0, 1.0, 3.0, 1.0], np.float32),
              "feature_scale": np.array([1.0, 2.0, 0.5, 1.0, 4.0], np.float32),
              "label_bodies": np.stack([V + k for k in range(K)]).astype(np.float32)}
    md = {"format": LIBRARY_FORMAT, "format_version": 1, "targets": [f"t{k}" for k in range(K)],
          "source": {"name": "body", "n_vertices": nb, "n_faces": M, "n_triangles": M, "faces_hash": "synthetic"},
          "cover_distance": None, "context_shares": [0.1], "smoothing_share": 0.01, "similarity_width": width,
          "garments": ["a", "b"]}
    return arrays, md


def test_the_prediction_is_the_mean_weighted_by_bound_points_and_likeness():
    arrays, md = synthetic_library()
    lib = NearestGarments(arrays, md, "lib.npz")
    q = np.random.default_rng(5).normal(size=(4, 5))
    bound = np.array([1.0, 1.0, 0.0, 1.0])
    lw = np.array([0.25, 0.75])
    y = lib.raw_offsets(bound, q, lw)
    f = arrays["features"].astype(np.float64)
    s = arrays["feature_scale"].astype(np.float64)
    off = np.einsum("k,knc->nc", lw, arrays["offsets"].astype(np.float64))

    def weight(e, qt):
        return arrays["weights"][e] * np.exp(-(((f[e] - qt) / s) ** 2).sum() / (2 * 0.5 ** 2))

    w0, w2 = weight(0, q[0]), weight(2, q[0])
    np.testing.assert_allclose(y[0], (w0 * off[0] + w2 * off[2]) / (w0 + w2), rtol=1e-12)
    np.testing.assert_allclose(y[1], off[1], rtol=1e-12)      # one garment there: its own
    assert not y[2].any()                                     # the new garment is not bound there
    assert not y[3].any()                                     # no training garment lies there
    # Both garments very far in features: the nearer one's placement, not 0 / 0 (each triangle's weights are
    # taken relative to its nearest entry).
    far = q.copy()
    far[0] = f[0] + 1e4 * s
    assert weight(0, far[0]) == weight(2, far[0]) == 0.0
    nearer = 0 if (((f[0] - far[0]) / s) ** 2).sum() < (((f[2] - far[0]) / s) ** 2).sum() else 2
    np.testing.assert_allclose(lib.raw_offsets(bound, far, lw)[0], off[nearer], rtol=1e-12)


def test_damaged_libraries_are_refused_naming_the_file():
    arrays, md = synthetic_library()
    cases = {
        "nan": ({**arrays, "offsets": np.full_like(arrays["offsets"], np.nan)}, md, "'offsets' that are not finite"),
        "short": ({**arrays, "weights": arrays["weights"][:3]}, md, "'weights' of shape (3,)"),
        "missing": ({k: v for k, v in arrays.items() if k != "features"}, md, "lacks the arrays features"),
        "outside": ({**arrays, "triangles": np.array([0, 1, 0, 9], np.int32)}, md, "triangle indices outside"),
        "zero": ({**arrays, "weights": np.zeros(4, np.float32)}, md, "not positive"),
        "features": (arrays, {**md, "context_shares": [0.1, 0.2]}, "has 5 features; its context shares give 8"),
    }
    for name, (a, m, message) in cases.items():
        with pytest.raises(ModelError) as exc:
            NearestGarments(a, m, f"{name}.npz")
        assert str(exc.value).startswith(f"{name}.npz") and message in str(exc.value), (name, str(exc.value))


def test_a_constant_placement_is_predicted_wherever_a_training_garment_lies(tiny):
    folder, tables = tiny
    ds = load_dataset(folder)
    src, tgt = ds.body("src"), ds.body("pear")
    c = np.array([0.01, -0.02, 0.005])
    lib = nearest_garments({**tables, "offset": np.broadcast_to(c, tables["offset"].shape).astype(np.float32)},
                           TARGETS, TRAINING)
    lib_bound = np.zeros(src.n_triangles, bool)
    lib_bound[lib.arrays["triangles"]] = True
    mid = src.with_vertices(0.5 * (ds.body("similar").V + tgt.V))
    # A new garment: the constant where a training garment lies, zero where none does (before smoothing).
    top = ds.garment("top", "src")
    w = bound_counts(bind(top.V, src.V, src.F), src.n_triangles)
    y = lib.raw_offsets(w, lib.similarity_features(src, top), np.array([0.3, 0.7]))
    both = (w > 0) & lib_bound
    assert both.any() and ((w > 0) & ~lib_bound).any()
    np.testing.assert_allclose(y[both], np.broadcast_to(c, y[both].shape), rtol=1e-6)
    assert not y[~both].any()
    # A garment bound only where training garments lie: the constant everywhere it is bound, after smoothing.
    band = ds.garment("band", "src")
    binding = bind(band.V, src.V, src.F)
    bound = bound_counts(binding, src.n_triangles) > 0
    for body, label in ((tgt, "pear"), (mid, None)):
        y = lib.unrotated_offsets(binding, src, body, band, label)
        np.testing.assert_allclose(y[bound], np.broadcast_to(c, y[bound].shape), rtol=0, atol=1e-9)
        C = lib.frame_offsets(binding, src, body, band, label)
        np.testing.assert_allclose(C, np.einsum("mij,mj->mi", orthonormal_frames(src.V, src.F), y), atol=1e-15)


torch = pytest.importorskip("torch")


@pytest.fixture(scope="module")
def network(tiny):
    from garment_transfer.learning.garment_training import train_placement_model

    _, tables = tiny
    return train_placement_model(tables, TARGETS, hidden=(16,), epochs=10, batch=256, seed=1, threads=1)[0]


def test_the_mix_is_the_share_weighted_mean_of_the_networks_and_the_nearest_garments(tiny, network):
    folder, tables = tiny
    ds = load_dataset(folder)
    src, tgt, garment = ds.body("src"), ds.body("pear"), ds.garment("top", "src")
    lib = nearest_garments(tables, TARGETS, TRAINING)
    binding = bind(garment.V, src.V, src.F)
    mid = src.with_vertices(0.5 * (ds.body("similar").V + tgt.V))
    for body, label in ((tgt, "pear"), (mid, None)):
        net = network.frame_offsets(binding, src, body, garment, label)
        near = lib.frame_offsets(binding, src, body, garment, label)
        assert np.abs(net - near).max() > 1e-4
        for share in (0.0, 0.3, 1.0):
            got = MixedPlacement(network, lib, share).frame_offsets(binding, src, body, garment, label)
            np.testing.assert_allclose(got, (1 - share) * net + share * near, rtol=0, atol=1e-12)
    # It goes where a placement model goes: a body between the training bodies gets the blend.
    mixed = MixedPlacement(network, lib, 0.5)
    r = transfer_garment(src, mid, garment, placement=BlendedPlacement(mixed))
    bodies = [src.with_vertices(ds.body(t).V) for t in TARGETS]
    w = mixed.label_weights_for(mid)
    C = sum(wk * mixed.frame_offsets(binding, src, b, garment, t) for wk, b, t in zip(w, bodies, TARGETS))
    # (the blend of unrotated offsets turned by the source frames: the same frames for every body)
    np.testing.assert_allclose(r.V, transfer_garment(src, mid, garment, placement=C).V, atol=1e-9)
    with pytest.raises(ValueError, match="between 0 and 1"):
        MixedPlacement(network, lib, 1.5)
    with pytest.raises(ValueError, match=">= 0"):
        MixedPlacement(network, lib, 0.5, -0.1)
    # Shrunk where the two disagree: the mix times |m|^2 / (|m|^2 + c v), v = (0.7^2 + 0.3^2) |a - b|^2 / 2,
    # written out here (the frames keep lengths, so the gain is the same in either frame).
    net = network.frame_offsets(binding, src, tgt, garment, "pear")
    near = lib.frame_offsets(binding, src, tgt, garment, "pear")
    plain = 0.7 * net + 0.3 * near
    mm, v = (plain ** 2).sum(1), 2.0 * (0.49 + 0.09) / 2 * ((net - near) ** 2).sum(1)
    gain = np.where(mm + v > 0, mm / np.where(mm + v > 0, mm + v, 1.0), 1.0)
    got = MixedPlacement(network, lib, 0.3, 2.0).frame_offsets(binding, src, tgt, garment, "pear")
    np.testing.assert_allclose(got, gain[:, None] * plain, rtol=0, atol=1e-12)
    assert 0 < gain.min() < 0.99 and np.abs(got).sum() < np.abs(plain).sum()
    other = nearest_garments({**tables, "bodies": tables["bodies"][::-1]}, TARGETS[::-1], TRAINING)
    with pytest.raises(ModelError, match="targets"):
        MixedPlacement(network, other, 0.5)


def test_the_shrink_gain_follows_its_formula():
    from garment_transfer.learning.placement import shrink_gain

    y = np.array([[1.0, 0, 0], [1.0, 0, 0], [0, 0, 0], [0, 3.0, 4.0], [0, 0, 0]])
    diff = np.array([[0.0, 0, 0], [2.0, 0, 0], [0, 0, 0], [0, 0, 1.0], [1.0, 0, 0]])
    # share 0.5: v = (0.25 + 0.25) / 2 |d|^2 = |d|^2 / 4; agreeing predictions are kept whole, nothing
    # predicted stays a gain of 1 (no 0/0), disagreement shrinks: 1 / (1 + 1), 25 / (25 + 0.25).
    np.testing.assert_allclose(shrink_gain(y, diff, 0.5, 1.0), [1, 0.5, 1, 25 / 25.25, 0], rtol=0, atol=1e-15)
    # share 0.2: v = (0.64 + 0.04) / 2 |d|^2; a factor c scales v.
    np.testing.assert_allclose(shrink_gain(y[1:2], diff[1:2], 0.2, 4.0), [1 / (1 + 4 * 0.34 * 4)], rtol=1e-14)
    np.testing.assert_allclose(shrink_gain(y, diff, 0.5, 0.0), 1.0)


def test_a_bundle_with_the_nearest_garments_round_trips_and_is_checked(tiny, tmp_path):
    from garment_transfer.learning.garment_training import train_garment_fit_from_dataset
    from garment_transfer.learning.model_files import read_model_file

    folder, _ = tiny
    path = tmp_path / "garment.npz"
    info = train_garment_fit_from_dataset(folder, "src", TARGETS, garments=TRAINING, epochs=2, placement_epochs=5,
                                          seed=1, out=path, threads=1, placement_members=2, library_share=0.3)
    assert info["library"] == {"share": 0.3, "entries": info["library"]["entries"]} and info["library"]["entries"] > 0
    with np.load(path, allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files}
    md = json.loads(str(arrays.pop("metadata")))
    assert md["format_version"] == 3 and md["placement_members"] == 2 and md["library_share"] == 0.3
    model = read_model_file(path)
    assert model.field_share == 0.5 and read_model_file(path, field_share=1.0).field_share == 1.0
    assert model.describe().endswith("learned placement mixed with the nearest garments' at share 0.3")
    mixed = model.placement.model
    assert isinstance(mixed, MixedPlacement) and mixed.share == 0.3 and len(mixed.model.members) == 2
    ds = load_dataset(folder)
    src, tgt, garment = ds.body("src"), ds.body("pear"), ds.garment("top", "src")
    binding = bind(garment.V, src.V, src.F)
    expect = (0.7 * mixed.model.frame_offsets(binding, src, tgt, garment, "pear")
              + 0.3 * mixed.library.frame_offsets(binding, src, tgt, garment, "pear"))
    np.testing.assert_allclose(model.placement.frame_offsets(binding, src, tgt, garment, "pear"), expect,
                               rtol=0, atol=1e-12)
    # One network and the library: version 3 too; no library (share 0): the earlier versions.
    one = tmp_path / "one.npz"
    train_garment_fit_from_dataset(folder, "src", TARGETS, garments=TRAINING, epochs=2, placement_epochs=5, seed=1,
                                   out=one, threads=1, placement_members=1)
    assert isinstance(read_model_file(one).placement.model, MixedPlacement)
    plain = tmp_path / "plain.npz"
    train_garment_fit_from_dataset(folder, "src", TARGETS, garments=TRAINING, epochs=2, placement_epochs=5, seed=1,
                                   out=plain, threads=1, placement_members=2, library_share=0)
    with np.load(plain, allow_pickle=False) as npz:
        assert json.loads(str(npz["metadata"]))["format_version"] == 2
        assert not any(k.startswith("library.") for k in npz.files)

    def rewrite(out, change=None, drop=(), add=None):
        a = {k: v for k, v in arrays.items() if k not in drop}
        m = json.loads(json.dumps(md))
        if change:
            change(m)
        np.savez(out, metadata=np.array(json.dumps(m)), **a, **(add or {}))
        return out

    cases = {
        "nan.npz": (lambda p: rewrite(p, add={"library.weights": np.full_like(arrays["library.weights"], np.nan)},
                                      drop=("library.weights",)), "'weights' that are not finite"),
        "share.npz": (lambda p: rewrite(p, lambda m: m.update(library_share=1.5)), "bad 'library_share' (1.5)"),
        "no_library.npz": (lambda p: rewrite(p, lambda m: m.pop("library")), "no nearest garments' placement"),
        "newer_library.npz": (lambda p: rewrite(p, lambda m: m["library"].update(format_version=9)),
                              "its nearest garments' placement has format version 9"),
        "v2_with_library.npz": (lambda p: rewrite(p, lambda m: m.update(format_version=2)),
                                "has arrays of no part: library."),
        "other_body.npz": (lambda p: rewrite(p, lambda m: m["library"]["source"].update(faces_hash="x")),
                           "different source bodies"),
    }
    for name, (make, problem) in cases.items():
        bad = make(tmp_path / name)
        with pytest.raises(ModelError) as exc:
            read_model_file(bad)
        assert str(exc.value).startswith(str(bad)) and problem in str(exc.value), (name, str(exc.value))


def test_one_transfer_computes_the_garment_s_context_once(tiny, network, monkeypatch):
    from collections import OrderedDict

    import garment_transfer.learning.placement as pl

    folder, tables = tiny
    ds = load_dataset(folder)
    src, tgt, garment = ds.body("src"), ds.body("pear"), ds.garment("top", "src")
    calls = []
    real = pl.garment_context
    monkeypatch.setattr(pl, "garment_context", lambda *a: calls.append(a) or real(*a))
    monkeypatch.setattr(pl, "_CONTEXT_CACHE", OrderedDict())
    mixed = BlendedPlacement(MixedPlacement(network, nearest_garments(tables, TARGETS, TRAINING), 0.5))
    mid = src.with_vertices(0.5 * (ds.body("similar").V + tgt.V))
    # The networks and the nearest garments, on a body blended from both training bodies: one context.
    first = transfer_garment(src, mid, garment, placement=mixed).V
    assert len(calls) == 1
    np.testing.assert_array_equal(transfer_garment(src, mid, garment, placement=mixed).V, first)
    assert len(calls) == 1
    from garment_transfer.learning.garment_model import garment_features

    X = garment_features(src.V, src.F, garment.V, garment.F)[0]
    shares = tuple(tables["context_shares"])
    ctx = pl.garment_context_cached(src.V, src.F, X, shares)
    np.testing.assert_array_equal(ctx, real(src.V, src.F, X, shares))
    assert not ctx.flags.writeable and len(calls) == 1
    pl.garment_context_cached(src.V, src.F, 1.01 * X, shares)          # another garment: computed
    assert len(calls) == 2
