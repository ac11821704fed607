import pytest
from test_dataset import make_tiny_dataset

from garment_transfer.errors import Cancelled, DatasetError, SettingError
from garment_transfer.pipeline.model_check import check_lines, check_model, training_garments


def test_training_garments_leave_the_held_out_ones_out_and_refuse_what_cannot_be(tmp_path):
    ds = make_tiny_dataset(tmp_path / "ds")
    assert training_garments(ds, "src", ["pear"], None, ["top"]) == ["band", "skirt"]
    assert training_garments(ds, "src", ["pear"], ["skirt", "band"], ["top"]) == ["skirt", "band"]
    with pytest.raises(DatasetError, match="has no garment 'coat'"):
        training_garments(ds, "src", ["pear"], None, ["coat"])
    with pytest.raises(SettingError, match="skirt is also among the garments to train on"):
        training_garments(ds, "src", ["pear"], ["skirt", "band"], ["skirt"])
    with pytest.raises(SettingError, match="none is left to train on"):
        training_garments(ds, "src", ["pear"], None, ["top", "band", "skirt"])
    (ds / "garments" / "top" / "pear.obj").unlink()
    with pytest.raises(DatasetError, match="pear.obj"):
        training_garments(ds, "src", ["pear"], None, ["top"])


def test_the_check_reports_per_target_and_stops_when_cancelled(tmp_path):
    pytest.importorskip("torch")
    from garment_transfer.learning.training import train_from_dataset

    ds = make_tiny_dataset(tmp_path / "ds")
    model = tmp_path / "m.npz"
    train_from_dataset(ds, "src", ["similar", "pear"], garments=["band", "skirt"], epochs=20, latent=2, out=model)
    written = model.read_bytes()
    check = check_model(ds, "src", ["similar", "pear"], ["top"], model)
    assert len(check["rows"]) == 4 and {r["method"] for r in check["rows"]} == {"model", "direct"}
    lines = check_lines(check)
    assert lines[0].startswith("held out of training: top;") and lines[1].startswith("  similar: vertex error ")
    assert lines[-1].endswith(f"on {len(check['beats_direct'])} of 2 targets")
    calls = []
    with pytest.raises(Cancelled, match="held-out garments was cancelled"):
        check_model(ds, "src", ["similar", "pear"], ["top"], model,
                    progress=lambda f, stage: calls.append(stage) or True)
    assert calls == ["top on similar"] and model.read_bytes() == written
