"""The main job on the built-in demo data, in its quick form (renders are tested in tests/blender)."""

import json

import pytest
from demo_results import quick_demo_results

from lab.outfits import OUTFITS


@pytest.fixture(scope="module")
def quick_demo(tmp_path_factory, worker_id):
    return quick_demo_results(tmp_path_factory, worker_id)


def test_quick_demo_writes_meshes_report_and_results(quick_demo):
    out, summary = quick_demo
    report = (out / "report.md").read_text()
    assert "Table 1" in report
    data = json.loads((out / "results.json").read_text())
    methods = {r["method"] for r in data["rows"]}
    assert methods == {"simulation", "ours", "paper", "direct", "surface"}
    garments, targets = summary["test_garments"], summary["targets"]
    assert len(garments) == 2 and len(targets) == 2
    for g in garments:
        for t in targets:
            for m in ("ours", "paper", "direct", "surface", "simulation"):
                assert (out / "meshes" / f"{g}__{t}__{m}.obj").is_file()
    ours = [r for r in data["rows"] if r["method"] == "ours"]
    sim = {(r["garment"], r["target"]): r for r in data["rows"] if r["method"] == "simulation"}
    for r in ours:
        assert r["penetrating_vertices"] == 0
        # The design is kept far better than re-simulation keeps it, even after 20 epochs.
        assert r["mdc"] < 0.5 * sim[(r["garment"], r["target"])]["mdc"]
        assert r["drape_error_relative"] < 1.0
    assert (out / "model_ours.npz").is_file() and (out / "model_paper.npz").is_file()


def test_quick_demo_reports_outfits_without_crossings(quick_demo):
    out, summary = quick_demo
    outfits = json.loads((out / "results.json").read_text())["outfits"]
    target = summary["targets"][0]
    assert [(r["outfit"], r["target"], r["garment"]) for r in outfits["rows"]] == [
        (" under ".join(o), target, g) for o in OUTFITS for g in o]
    for r in outfits["rows"]:
        assert r["garment_edge_body_pairs"] == r["body_edge_garment_pairs"] == r["layer_crossings"] == 0, r
        assert r["min_body_distance"] > 0 and (r["layer"] == 1 or r["min_layer_distance"] > 0)
        assert r["self_intersections"] is not None and 0 < r["mdc"] < 0.2
    # The garments were draped one by one, so the outer layer passed through the inner one as given.
    assert all(r["layer_crossings_source"] > 0 for r in outfits["rows"] if r["layer"] == 2)
    assert [(f["order"], f["refused"]) for f in outfits["refusals"]] == [(list(o[::-1]), True) for o in OUTFITS]
    for f in outfits["refusals"]:
        assert all(g in f["message"] for g in f["order"])
    report = (out / "report.md").read_text()
    assert "## Outfits of several layers" in report
    assert f"Crossings left: 0 of {2 * len(OUTFITS)} layers in {len(OUTFITS)} outfit transfers." in report


def test_quick_demo_ours_is_the_model_file_as_transfer_uses_it(quick_demo):
    # "ours" is what the product recommends: the garment fit model file that train writes by default, read back
    # and used as transfer --model uses it (half its field, the placement mixed with the nearest garments').
    from garment_transfer import load_dataset, read_model_file, read_obj, transfer_garment
    from lab.paths import DEMO_DATA

    out, summary = quick_demo
    model = read_model_file(out / "model_ours.npz")
    assert model.kind == "garment" and model.has_placement and model.field_share == 0.5
    assert model.summary()["nearest_garments"] == 0.5
    assert sorted(model.targets) == sorted(summary["targets"])
    assert summary["training"]["ours"]["garments"] == len(summary["train_garments"])
    g, t = summary["test_garments"][0], summary["targets"][0]
    ds = load_dataset(DEMO_DATA)
    garment = ds.garment(g, summary["source"])
    V = transfer_garment(ds.body(summary["source"]), ds.body(t), garment, method="model", target=t,
                         **model.transfer_arguments()).V
    written = read_obj(out / "meshes" / f"{g}__{t}__ours.obj").V
    assert abs(V - written).max() < 1e-6
