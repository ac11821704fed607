"""One model file of the garment fit model and its learned placement; one loader for every kind of file."""

import json

import numpy as np
import pytest
from test_dataset import make_tiny_dataset

from garment_transfer.errors import ModelError
from garment_transfer.learning.dataset import load_dataset
from garment_transfer.learning.garment_model import GarmentFitModel
from garment_transfer.learning.model_files import DEFAULT_FIELD_SHARE, read_model_file, save_garment_fit_bundle
from garment_transfer.learning.placement import BlendedPlacement, PlacementModel
from garment_transfer.pipeline.any_body import transfer_to_any_body
from garment_transfer.pipeline.transfer import transfer_garment

torch = pytest.importorskip("torch")

TARGETS = ["similar", "pear"]


@pytest.fixture(scope="module")
def bundle(tmp_path_factory):
    from garment_transfer.learning.garment_training import train_garment_fit_from_dataset

    folder = tmp_path_factory.mktemp("bundle")
    ds = make_tiny_dataset(folder / "ds")
    path = folder / "garment.npz"
    info = train_garment_fit_from_dataset(ds, "src", TARGETS, garments=["band", "skirt"], epochs=3,
                                          placement_epochs=10, seed=1, out=path, threads=1, placement_members=1,
                                          library_share=0)
    return ds, path, info


@pytest.fixture(scope="module")
def ensemble_bundle(bundle):
    """The same training with two placement members: a file of format version 2."""
    from garment_transfer.learning.garment_training import train_garment_fit_from_dataset

    ds, single, _ = bundle
    path = single.parent / "ensemble.npz"
    info = train_garment_fit_from_dataset(ds, "src", TARGETS, garments=["band", "skirt"], epochs=3,
                                          placement_epochs=10, seed=1, out=path, threads=1, placement_members=2,
                                          library_share=0)
    return ds, path, info


def parts_by_hand(path):
    """The two models rebuilt from the file's arrays without ``read_model_file``."""
    with np.load(path, allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files}
    md = json.loads(str(arrays.pop("metadata")))
    field = {k[6:]: v for k, v in arrays.items() if k.startswith("field.")}
    placed = {k[10:]: v for k, v in arrays.items() if k.startswith("placement.")}
    return GarmentFitModel(field, md["field"], "field"), PlacementModel(placed, md["placement"], "placement"), md


def test_training_writes_one_file_with_both_models(bundle):
    ds, path, info = bundle
    assert info["kind"] == "garment" and info["out"] == str(path)
    assert info["field"]["epochs"] == 3 and info["placement"]["epochs"] == 10
    assert info["field"]["samples"] > 0 and info["placement"]["samples"] > 0
    field, placed, md = parts_by_hand(path)
    assert md["format"] == "garment_transfer.garment_fit_bundle" and md["format_version"] == 1
    assert md["dataset"] == {"folder": "ds", "units": "metres", "up_axis": "Z"}
    assert field.targets == TARGETS and placed.targets == TARGETS
    model = read_model_file(path)
    assert model.kind == "garment" and model.field_share == DEFAULT_FIELD_SHARE == 0.5
    assert model.placement is not None and model.has_placement
    assert model.summary() == {"model": str(path), "model_kind": "garment", "field_share": 0.5, "placement": True,
                               "nearest_garments": None,
                               "targets": TARGETS}
    assert model.describe() == "garment fit model (garment.npz), field share 0.5, learned placement"


def test_the_file_transfers_as_the_core_with_the_same_models(bundle):
    ds, path, _ = bundle
    ds = load_dataset(ds)
    src, tgt, garment = ds.body("src"), ds.body("pear"), ds.garment("top", "src")
    field, placed, _ = parts_by_hand(path)
    expect = transfer_garment(src, tgt, garment, method="model", model=field.with_field_share(0.5),
                              placement=BlendedPlacement(placed)).V
    model = read_model_file(path)
    # The command line's call: transfer_to_any_body, the same mesh.
    got, registration = transfer_to_any_body(src, tgt, garment, method="model", model=model.model,
                                             placement=model.placement)
    assert registration is None
    np.testing.assert_allclose(got.V, expect, rtol=0, atol=1e-12)
    # On a training body named by its label the blend is the network's own placement.
    labelled = transfer_garment(src, tgt, garment, method="model", model=field.with_field_share(0.5),
                                placement=placed, target="pear").V
    np.testing.assert_allclose(transfer_garment(src, tgt, garment, method="model", model=model.model,
                                                placement=model.placement, target="pear").V,
                               labelled, rtol=0, atol=1e-12)
    # The share and the placement each change the result: the comparison above could fail.
    whole = transfer_garment(src, tgt, garment, method="model", model=read_model_file(path, 1.0).model,
                             placement=placed).V
    unplaced = read_model_file(path, use_placement=False)
    assert unplaced.placement is None and unplaced.has_placement
    alone = transfer_garment(src, tgt, garment, method="model", model=unplaced.model).V
    scale = np.ptp(src.V, axis=0).max()
    assert np.abs(whole - expect).max() > 1e-6 * scale and np.abs(alone - expect).max() > 1e-6 * scale


def rewrite(path, out, metadata=None, drop=(), add=None):
    with np.load(path, allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files if k not in drop}
    md = json.loads(str(arrays.pop("metadata")))
    if metadata:
        metadata(md)
    np.savez(out, metadata=np.array(json.dumps(md)), **arrays, **(add or {}))
    return out


def test_wrong_or_damaged_files_are_refused_naming_them(bundle, tmp_path):
    _, path, _ = bundle
    cases = {
        "newer.npz": (lambda p: rewrite(path, p, lambda md: md.update(format_version=4)),
                      "has format version 4; this version of garment_transfer reads versions 1, 2 and 3"),
        "v1_members.npz": (lambda p: rewrite(path, p, lambda md: md.update(placement_members=1)),
                           "has 'placement_members' (1), which format version 1 does not have"),
        "newer_part.npz": (lambda p: rewrite(path, p, lambda md: md["placement"].update(format_version=7)),
                           "its placement model has format version 7"),
        "stray.npz": (lambda p: rewrite(path, p, add={"extra": np.zeros(3)}), "has arrays of no part: extra"),
        "short.npz": (lambda p: rewrite(path, p, drop=("field.W0",)), "array 'W0' is missing"),
        "other_body.npz": (lambda p: rewrite(path, p, lambda md: md["placement"]["source"].update(faces_hash="x")),
                           "trained on different source bodies"),
        "no_metadata.npz": (lambda p: rewrite(path, p, lambda md: md["field"].pop("source")),
                            "metadata lacks 'source'"),
        "unknown.npz": (lambda p: rewrite(path, p, lambda md: md.update(format="something.else")),
                        "is not a garment transfer model (metadata 'format' is 'something.else')"),
    }
    for name, (make, problem) in cases.items():
        bad = make(tmp_path / name)
        with pytest.raises(ModelError, match=None) as exc:
            read_model_file(bad)
        assert str(exc.value).startswith(str(bad)) and problem in str(exc.value), (name, str(exc.value))
    truncated = tmp_path / "truncated.npz"
    truncated.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    with pytest.raises(ModelError, match="truncated.npz: is not a model file"):
        read_model_file(truncated)
    pickled = tmp_path / "pickled.npz"
    np.savez(pickled, metadata=np.array("{}"), W0=np.array([object()], dtype=object))
    with pytest.raises(ModelError, match="pickled.npz: holds Python objects"):
        read_model_file(pickled)
    text = tmp_path / "body.obj"
    text.write_text("v 0 0 0\n")
    with pytest.raises(ModelError, match=r"body.obj: is not a model file \(.npz, a zip archive\) but a text file"):
        read_model_file(text)
    with pytest.raises(ValueError, match="between 0 and 1"):
        read_model_file(path, field_share=1.5)


def test_a_placement_alone_is_refused_and_a_garment_model_alone_is_read(bundle, tmp_path):
    _, path, _ = bundle
    field, placed, _ = parts_by_hand(path)
    placed.save(tmp_path / "placement.npz")
    with pytest.raises(ModelError, match="placement.npz: holds a placement model alone"):
        read_model_file(tmp_path / "placement.npz")
    field.save(tmp_path / "field.npz")
    alone = read_model_file(tmp_path / "field.npz", field_share=0.25)
    assert alone.kind == "garment" and alone.placement is None and not alone.has_placement
    assert alone.model.field_share == 0.25
    assert alone.describe().endswith("field share 0.25, no placement in the file")
    other = read_model_file(path).with_field_share(0.25)
    assert other.field_share == other.model.field_share == 0.25 and other.placement is not None
    save_garment_fit_bundle(tmp_path / "no_placement.npz", field)
    assert read_model_file(tmp_path / "no_placement.npz").placement is None


def test_the_shared_model_is_read_as_before_and_takes_no_field_share(bundle, tmp_path):
    from garment_transfer.learning.training import train_from_dataset

    ds, _, _ = bundle
    shared = tmp_path / "shared.npz"
    train_from_dataset(ds, "src", TARGETS, garments=["band", "skirt"], epochs=3, latent=2, out=shared)
    model = read_model_file(shared)
    assert model.kind == "shared" and model.placement is None and model.field_share is None
    assert model.targets == TARGETS and model.describe() == "shared deformation model (shared.npz)"
    for read in (lambda: read_model_file(shared, field_share=0.5), lambda: model.with_field_share(0.5)):
        with pytest.raises(ModelError, match="shared.npz: holds the paper's shared deformation model"):
            read()


def test_one_transfer_computes_the_target_body_s_features_once(bundle, monkeypatch):
    from collections import OrderedDict

    import garment_transfer.learning.garment_model as gm

    ds, path, _ = bundle
    ds = load_dataset(ds)
    src, tgt, garment = ds.body("src"), ds.body("pear"), ds.garment("top", "src")
    calls = []
    real = gm.target_features
    monkeypatch.setattr(gm, "target_features", lambda *a, **k: calls.append(k["rows"].copy()) or real(*a, **k))
    monkeypatch.setattr(gm, "_TARGET_CACHE", OrderedDict())
    model = read_model_file(path)
    first = transfer_garment(src, tgt, garment, method="model", model=model.model, placement=model.placement).V
    # The field model's triangles (those the garment covers), then the placement's bound ones it lacks: no
    # triangle twice, and far from all of them.
    assert len(calls) in (1, 2)
    if len(calls) == 2:
        assert not (calls[0] & calls[1]).any()
    computed = np.logical_or.reduce(calls)
    assert 0 < computed.sum() < 0.8 * src.n_triangles
    again = transfer_garment(src, tgt, garment, method="model", model=model.model, placement=model.placement).V
    assert len(calls) in (1, 2) and np.array_equal(first, again)     # nothing computed again
    n = len(calls)
    shares = tuple(model.model.metadata["neighbourhood_shares"])
    full, full_dev = real(src.V, tgt.V, src.F, shares)
    X, dev = gm.target_features_cached(src.V, tgt.V, src.F, shares, computed)
    assert len(calls) == n
    np.testing.assert_allclose(X[computed], full[computed], rtol=0, atol=1e-12)
    assert np.isnan(X[~computed][:, 9:]).all() and np.array_equal(dev, full_dev)
    assert not X.flags.writeable and not dev.flags.writeable
    X, _ = gm.target_features_cached(src.V, tgt.V, src.F, shares)    # every triangle: the rest computed
    assert len(calls) == n + 1 and np.array_equal(calls[-1], ~computed)
    np.testing.assert_allclose(X, full, rtol=0, atol=1e-12)
    gm.target_features_cached(src.V, 1.01 * tgt.V, src.F, shares)    # another body: computed
    assert len(calls) == n + 2 and calls[-1].all()


def test_a_placement_of_several_members_round_trips_through_one_file(bundle, ensemble_bundle):
    from garment_transfer.learning.placement import PlacementEnsemble

    ds, path, info = ensemble_bundle
    assert info["placement"]["members"] == 2 and info["placement"]["epochs"] == 10
    with np.load(path, allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files}
    md = json.loads(str(arrays.pop("metadata")))
    assert md["format_version"] == 2 and md["placement_members"] == 2 and len(md["placement"]) == 2
    assert not any(k.startswith("placement.W") for k in arrays)
    members = [PlacementModel({k[len(f"placement.{i}."):]: v for k, v in arrays.items()
                               if k.startswith(f"placement.{i}.")}, md["placement"][i], f"member {i}")
               for i in range(2)]
    assert [m.metadata["training"]["seed"] for m in members] == [1, 2]
    model = read_model_file(path)
    assert isinstance(model.placement, BlendedPlacement) and isinstance(model.placement.model, PlacementEnsemble)
    read = model.placement.model.members
    assert len(read) == 2 and model.has_placement and model.placement.model.name == str(path)
    for got, want in zip(read, members):
        assert got.metadata == want.metadata and all(np.array_equal(got.arrays[k], want.arrays[k])
                                                     for k in want.arrays)
    # The first member is the single-placement file's model (same seed and data).
    _, single, _ = parts_by_hand(bundle[1])
    assert all(np.array_equal(read[0].arrays[k], single.arrays[k]) for k in single.arrays)
    ds = load_dataset(ds)
    src, tgt, garment = ds.body("src"), ds.body("pear"), ds.garment("top", "src")
    field = GarmentFitModel({k[6:]: v for k, v in arrays.items() if k.startswith("field.")}, md["field"], "field")
    expect = transfer_garment(src, tgt, garment, method="model", model=field.with_field_share(0.5),
                              placement=BlendedPlacement(PlacementEnsemble(members))).V
    got = transfer_garment(src, tgt, garment, method="model", **model.transfer_arguments()).V
    np.testing.assert_allclose(got, expect, rtol=0, atol=1e-12)
    alone = transfer_garment(src, tgt, garment, method="model", model=field.with_field_share(0.5),
                             placement=BlendedPlacement(members[0])).V
    assert np.abs(alone - expect).max() > 1e-6 * np.ptp(src.V, axis=0).max()
    # Written again from what was read: the same file contents.
    again = path.parent / "again.npz"
    save_garment_fit_bundle(again, model.model, model.placement.model, dataset=md["dataset"])
    with np.load(again, allow_pickle=False) as npz:
        assert sorted(npz.files) == sorted([*arrays, "metadata"])
        assert json.loads(str(npz["metadata"])) == md
    # An ensemble of one member is written as the single model (format version 1).
    one = path.parent / "one.npz"
    save_garment_fit_bundle(one, field, PlacementEnsemble(members[:1]))
    with np.load(one, allow_pickle=False) as npz:
        assert json.loads(str(npz["metadata"]))["format_version"] == 1 and "placement.W0" in npz.files
    assert isinstance(read_model_file(one).placement.model, PlacementModel)


def test_a_bad_count_of_placement_members_is_refused_naming_the_file(ensemble_bundle, tmp_path):
    _, path, _ = ensemble_bundle

    def member(i, **changes):
        return lambda md: md["placement"][i].update(changes)

    cases = {
        "more.npz": (lambda md: md.update(placement_members=3), "says it holds 3 placement members, but its "
                                                                "'placement' metadata has 2 entries"),
        "one.npz": (lambda md: md.update(placement_members=1), "has a bad 'placement_members' (1)"),
        "text.npz": (lambda md: md.update(placement_members="2"), "has a bad 'placement_members' ('2')"),
        "flag.npz": (lambda md: md.update(placement_members=True), "has a bad 'placement_members' (True)"),
        "none.npz": (lambda md: md.pop("placement_members"), "has a bad 'placement_members' (None)"),
        "not_list.npz": (lambda md: md.update(placement=md["placement"][0]),
                         "says it holds 2 placement members, but its 'placement' metadata has dict"),
        "null_member.npz": (lambda md: md["placement"].__setitem__(1, None),
                            "its 'placement member 1' metadata is not a table"),
        "other_member.npz": (member(1, smoothing_share=0.5),
                             "placement member 1 differs from member 0 in 'smoothing_share'"),
        "old_member.npz": (member(0, format_version=7), "its placement member 0 model has format version 7"),
    }
    for name, (change, problem) in cases.items():
        bad = rewrite(path, tmp_path / name, change)
        with pytest.raises(ModelError) as exc:
            read_model_file(bad)
        assert str(exc.value).startswith(str(bad)) and problem in str(exc.value), (name, str(exc.value))
    # Arrays of a member the file does not list, or a member without its arrays.
    for name, kw, problem in (("stray.npz", {"add": {"placement.2.W0": np.zeros(3)}},
                               "has arrays of no part: placement.2.W0"),
                              ("short.npz", {"drop": ("placement.1.W0",)}, "array 'W0' is missing")):
        bad = rewrite(path, tmp_path / name, **kw)
        with pytest.raises(ModelError) as exc:
            read_model_file(bad)
        assert str(exc.value).startswith(str(bad)) and problem in str(exc.value), (name, str(exc.value))


def test_the_default_placement_is_residual_and_a_file_without_the_base_still_reads(bundle, tmp_path):
    from garment_transfer.geometry.binding import bind
    from garment_transfer.learning.garment_training import PLACEMENT_RESIDUAL, train_garment_fit_from_dataset

    ds, path, _ = bundle
    field, placed, md = parts_by_hand(path)
    assert PLACEMENT_RESIDUAL and md["placement"]["format_version"] == 2 and md["format_version"] == 1
    assert placed.arrays["offset_base"].shape == (len(TARGETS), field.metadata["source"]["n_triangles"], 3)
    assert np.abs(placed.arrays["offset_base"]).max() > 0
    # Without the residual: a placement of format version 1, as files written before it, read alike.
    old = tmp_path / "old.npz"
    train_garment_fit_from_dataset(ds, "src", TARGETS, garments=["band", "skirt"], epochs=3, placement_epochs=10,
                                   seed=1, out=old, threads=1, placement_members=1, placement_residual=False,
                                   library_share=0)
    field_old, placed_old, md_old = parts_by_hand(old)
    assert md_old["placement"]["format_version"] == 1 and "offset_base" not in placed_old.arrays
    dataset = load_dataset(ds)
    src, tgt, g = dataset.body("src"), dataset.body("pear"), dataset.garment("top", "src")
    binding = bind(g.V, src.V, src.F)
    for p, own in ((path, placed), (old, placed_old)):
        np.testing.assert_array_equal(read_model_file(p).placement.frame_offsets(binding, src, tgt, g, "pear"),
                                      own.frame_offsets(binding, src, tgt, g, "pear"))
    assert np.abs(placed.frame_offsets(binding, src, tgt, g, "pear")
                  - placed_old.frame_offsets(binding, src, tgt, g, "pear")).max() > 1e-6
