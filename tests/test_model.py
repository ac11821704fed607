import json
import os

import numpy as np
import pytest
from meshes import icosphere
from test_dataset import make_tiny_dataset

from garment_transfer.errors import Cancelled, ModelError
from garment_transfer.geometry.mesh import mesh_from_triangles
from garment_transfer.learning.dataset import build_training_fields
from garment_transfer.learning.model import load_model

torch = pytest.importorskip("torch")

from garment_transfer.learning.training import train_from_dataset, train_model  # noqa: E402

TARGETS = ["similar", "pear"]


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    return make_tiny_dataset(tmp_path_factory.mktemp("tiny") / "ds")


@pytest.fixture(scope="module")
def fields(tiny):
    return build_training_fields(tiny, "src", TARGETS, keep_raw=True)


@pytest.fixture(scope="module")
def trained(fields):
    return train_model(fields.select(["band", "skirt"]), latent=4, epochs=150, seed=3, threads=1,
                       holdout=fields.select(["top"]), patience=1000)


@pytest.fixture(scope="module")
def saved(trained, tmp_path_factory):
    path = tmp_path_factory.mktemp("model") / "m.npz"
    trained[0].save(path)
    return path


def torch_forward(arrays, md, x, k):
    """The network written directly in torch (float32) from the model's arrays."""
    K = len(md["targets"])
    t = {key: torch.from_numpy(np.asarray(v, np.float32)) for key, v in arrays.items()
         if key.startswith(("enc_", "dec_"))}
    oh = torch.zeros(len(x), K)
    oh[:, k] = 1
    h = torch.cat([torch.from_numpy(x.astype(np.float32)), oh], 1)
    for i in range(md["encoder_layers"]):
        h = torch.sigmoid(h @ t[f"enc_W{i}"].T + t[f"enc_b{i}"])
    z = h
    h = torch.cat([z, oh], 1)
    for i in range(md["decoder_layers"]):
        h = h @ t[f"dec_W{i}"].T + t[f"dec_b{i}"]
        if i < md["decoder_layers"] - 1:
            h = torch.sigmoid(h)
    return z.numpy(), h.numpy()


def inputs(model, fields, g, k):
    dev = fields.deviation[g, k][model.active] / model.scale
    return dev.reshape(1, -1).astype(np.float64)


def test_training_lowers_the_loss(trained):
    _, info = trained
    hist = [loss for _, loss in info["loss_history"]]
    assert hist[-1] < 0.5 * hist[0]
    assert info["epochs"] == 150 and info["final_loss"] < hist[0]
    json.dumps(info)


def test_numpy_inference_equals_torch(trained, fields):
    model, _ = trained
    x = np.vstack([inputs(model, fields, g, 1) for g in range(3)])
    z_t, y_t = torch_forward(model.arrays, model.metadata, x, 1)
    z = model.encode(x, "pear")
    np.testing.assert_allclose(z, z_t, atol=1e-5)
    np.testing.assert_allclose(model.decode(z, "pear"), y_t, atol=1e-5)


def test_exported_network_is_the_trained_one(trained, fields):
    model, info = trained
    train = fields.select(["band", "skirt"])
    err, n = 0.0, 0
    for g in range(2):
        for k, t in enumerate(TARGETS):
            x = inputs(model, train, g, k)
            y = model.decode(model.encode(x, t), t)
            m = np.repeat(train.covered[g][model.active], 9)
            err += float((((y[0] - x[0]) * m) ** 2).sum())
            n += int(m.sum())
    assert err / n == pytest.approx(info["final_loss"], rel=1e-4)


def test_saved_and_loaded_model_gives_the_same_field(trained, saved):
    model, _ = trained
    loaded = load_model(saved)
    assert loaded.targets == TARGETS
    assert loaded.metadata == json.loads(json.dumps(model.metadata))
    for t in TARGETS:
        for how in ("mean_latent", "mean_decoded", "mean_field", "body"):
            np.testing.assert_array_equal(loaded.body_field(t, how), model.body_field(t, how))
    with np.load(saved, allow_pickle=False) as npz:
        assert "metadata" in npz.files
    assert not [f for f in os.listdir(saved.parent) if f.startswith(".tmp-")]


def test_body_field_shape_and_uncovered_triangles_follow_the_body(trained, fields):
    model, _ = trained
    Q = model.body_field("pear")
    assert Q.shape == (320, 3, 3) and Q.dtype == np.float64 and np.isfinite(Q).all()
    body = fields.body_deviation[1].reshape(-1, 3, 3) + np.eye(3)
    np.testing.assert_allclose(Q[~model.active], body[~model.active], atol=1e-6)
    assert not model.active.all()
    # where every training garment deformed by exactly 1.2 I, the prediction is near it (much nearer
    # than the identity, 0.2 away)
    Qs = model.body_field("similar")
    seen = fields.select(["band", "skirt"]).covered.all(axis=0)
    err = np.abs(Qs[seen] - 1.2 * np.eye(3)).max(axis=(1, 2))
    assert np.median(err) < 0.1
    np.testing.assert_allclose(model.body_field("similar", how="mean_field")[seen],
                               np.broadcast_to(1.2 * np.eye(3), (seen.sum(), 3, 3)), atol=1e-5)


def test_metadata_describes_the_model(trained):
    md = trained[0].metadata
    assert md["format_version"] == 1
    assert md["source"]["n_triangles"] == 320 and len(md["source"]["faces_hash"]) == 16
    assert md["latent"] == 4 and len(md["normalisation"]["scale"]) == 9
    assert md["training"]["seed"] == 3 and md["training"]["masked"] is True
    assert md["losses"]["best_validation"] is not None


def test_same_seed_same_model_other_seed_other_model(fields):
    part = fields.select(["band", "top"])
    a, _ = train_model(part, latent=3, epochs=20, seed=7, threads=1)
    b, _ = train_model(part, latent=3, epochs=20, seed=7, threads=1)
    c, _ = train_model(part, latent=3, epochs=20, seed=8, threads=1)
    for key in a.arrays:
        np.testing.assert_array_equal(a.arrays[key], b.arrays[key])
    assert not np.array_equal(a.arrays["dec_W0"], c.arrays["dec_W0"])


@pytest.mark.parametrize("optimizer", ["lbfgs", "scg"])
def test_other_optimisers_run(fields, optimizer):
    _, info = train_model(fields.select(["band", "top"]), latent=3, epochs=15, optimizer=optimizer, threads=1)
    assert np.isfinite(info["final_loss"]) and info["final_loss"] <= info["loss_history"][0][1] + 1e-6


def test_unmasked_loss_learns_every_triangle(fields):
    model, info = train_model(fields.select(["band", "top"]), latent=3, epochs=20, masked=False, threads=1)
    assert model.active.all() and info["masked"] is False
    assert model.metadata["training"]["masked"] is False


def test_early_stopping_keeps_the_best_weights(fields):
    held = fields.select(["top"])
    model, info = train_model(fields.select(["band", "skirt"]), latent=3, epochs=400, threads=1,
                              holdout=held, patience=20, eval_every=5, lr=0.05)
    assert info["stopped_early"] and info["epochs"] < 400
    assert info["best_validation_epoch"] <= info["epochs"] - 20
    # the saved weights are those of the best held-out epoch: recompute its held-out error
    err, n = 0.0, 0
    for k, t in enumerate(TARGETS):
        y = model.decode(model.arrays["latent_mean"][k][None], t)[0]
        x = inputs(model, held, 0, k)[0]
        m = np.repeat(held.covered[0][model.active], 9)
        err += float((((y - x) * m) ** 2).sum())
        n += int(m.sum())
    assert err / n == pytest.approx(info["best_validation_loss"], rel=1e-4)


def test_train_from_dataset_writes_the_model_and_reports(tiny, tmp_path):
    out = tmp_path / "model.npz"
    seen = []
    info = train_from_dataset(tiny, "src", TARGETS, epochs=10, latent=3, out=out, threads=1,
                              holdout=["top"], progress=lambda f, loss: seen.append((f, loss)))
    json.dumps(info)
    assert info["out"] == str(out) and info["garments"] == ["band", "skirt"] and info["epochs"] == 10
    assert seen[0][1] is None and seen[-1][0] == pytest.approx(1.0)
    assert all(b[0] >= a[0] for a, b in zip(seen, seen[1:]))
    assert load_model(out).metadata["training"]["holdout"] == ["top"]


def test_cancel_writes_nothing(tiny, tmp_path):
    out = tmp_path / "model.npz"
    with pytest.raises(Cancelled):
        train_from_dataset(tiny, "src", TARGETS, epochs=50, latent=3, out=out, threads=1,
                           progress=lambda f, loss: loss is not None and f > 0.5)
    assert os.listdir(tmp_path) == []


def test_model_for_another_source_body(saved, tiny):
    from garment_transfer.geometry.obj import read_obj
    from garment_transfer.learning.model import SharedDeformationModel

    # A model holds the body it was trained on: it serves other bodies through a registration
    # (tests/test_field_mapping.py), and knows which bodies are its own mesh.
    held = load_model(saved)
    src = read_obj(tiny / "bodies" / "src.obj")
    assert held.same_body(src) and held.source_body.n_triangles == src.n_triangles
    np.testing.assert_array_equal(held.source_body.V, src.V)
    V, F = icosphere(3)
    assert not held.same_body(mesh_from_triangles(V, F, name="other.obj"))
    # A model file without its body serves its own body's mesh only.
    model = SharedDeformationModel({k: v for k, v in held.arrays.items() if not k.startswith("source_")},
                                   held.metadata, name=held.name)
    model.check_source_body(src)
    with pytest.raises(ModelError, match=r"m\.npz: was trained on source body 'src' \(162 vertices.*has 642"):
        model.check_source_body(mesh_from_triangles(V, F, name="other.obj"))
    V, F = icosphere(2)
    with pytest.raises(ModelError, match="faces hash"):
        model.check_source_body(mesh_from_triangles(V, F[:, [0, 2, 1]], name="flipped"))


def test_unknown_target_lists_the_known_ones(saved):
    with pytest.raises(ModelError, match="unknown target 'giant'; this model knows: similar, pear"):
        load_model(saved).body_field("giant")


def test_object_arrays_are_refused(saved, tmp_path):
    with np.load(saved, allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files}
    arrays["payload"] = np.array([{"run": "code"}], dtype=object)
    bad = tmp_path / "bad.npz"
    np.savez(bad, **arrays)
    with pytest.raises(ModelError, match="bad.npz: holds Python objects"):
        load_model(bad)


def test_other_bad_files(saved, tmp_path):
    with pytest.raises(ModelError, match="not found"):
        load_model(tmp_path / "none.npz")
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"not a zip at all")
    with pytest.raises(ModelError, match="junk.npz"):
        load_model(junk)
    with np.load(saved, allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files}
    md = json.loads(str(arrays["metadata"]))
    md["format_version"] = 99
    arrays["metadata"] = np.array(json.dumps(md))
    np.savez(tmp_path / "future.npz", **arrays)
    with pytest.raises(ModelError, match="format version 99"):
        load_model(tmp_path / "future.npz")
    md["format_version"] = 1
    arrays["metadata"] = np.array(json.dumps(md))
    arrays["dec_W0"] = arrays["dec_W0"][:-9]
    np.savez(tmp_path / "cut.npz", **arrays)
    with pytest.raises(ModelError, match="cut.npz: decoder"):
        load_model(tmp_path / "cut.npz")


def test_model_module_does_not_import_torch():
    import subprocess
    import sys

    code = ("import sys; import garment_transfer.learning.model, garment_transfer.learning.dataset; "
            "sys.exit(1 if 'torch' in sys.modules else 0)")
    assert subprocess.run([sys.executable, "-c", code]).returncode == 0


@pytest.mark.parametrize("hidden", [(), (5,), (6, 4)])
def test_hand_written_gradient_matches_autograd(hidden):
    from garment_transfer.learning.training import DeformationNet

    gen = torch.Generator().manual_seed(0)
    S, D, K, L = 6, 27, 2, 3
    X = torch.randn(S, D, generator=gen)
    mask = (torch.rand(S, D, generator=gen) > 0.3).float()
    onehot = torch.eye(K)[torch.arange(S) % K]
    basis, _ = torch.linalg.qr(X.T)
    coords = X @ basis
    net = DeformationNet(basis, D, K, L, list(hidden), X.mean(0), gen)
    n = float(mask.sum())
    loss = net.loss_and_grad(coords, onehot, X, mask, n)

    ps = [p.detach().clone().requires_grad_() for p in net.parameters()]
    A, Wc, b0 = ps[:3]
    h = torch.sigmoid(coords @ A.T + onehot @ Wc.T + b0)
    rest = ps[3:]
    n_enc = len(hidden)
    for i in range(n_enc):
        h = torch.sigmoid(h @ rest[2 * i].T + rest[2 * i + 1])
    h = torch.cat([h, onehot], 1)
    dec = rest[2 * n_enc:]
    for i in range(len(dec) // 2):
        h = h @ dec[2 * i].T + dec[2 * i + 1]
        if i < len(dec) // 2 - 1:
            h = torch.sigmoid(h)
    ref = (((h - X) * mask) ** 2).sum() / n
    ref.backward()
    assert loss == pytest.approx(float(ref.detach()), rel=1e-5)
    for p, g in zip(ps, net.grads):
        torch.testing.assert_close(g, p.grad, rtol=1e-4, atol=1e-6)
