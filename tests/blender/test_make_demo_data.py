"""lab/blender/make_demo_data.py: the demo's garments draped by Blender's cloth solver, with each target a
restart from the settled garment (the demo data as built) or one simulation from the start (--continuous)."""

from __future__ import annotations

import json

import numpy as np
import pytest

pytestmark = pytest.mark.lab

GARMENT = "mini_skirt"          # the catalogue's smallest (1,296 vertices)
FRAMES = ["--source-frames", "4", "--morph-frames", "3", "--frames", "3"]


def test_continuous_targets_share_the_source_drape_and_are_recorded(tmp_path):
    from garment_transfer.geometry.obj import read_obj
    from garment_transfer.geometry.proximity import TriangleSurface
    from lab.blender.make_demo_data import main

    runs = {}
    for kind, extra in (("restart", []), ("continuous", ["--continuous"])):
        out = tmp_path / kind
        assert main(["--out", str(out), "--garments", GARMENT, "--targets", "pear", *FRAMES, *extra]) == 0
        generator = json.loads((out / "manifest.json").read_text())["generator"]
        assert generator["continuous"] is (kind == "continuous") and generator["source_frames"] == 4
        runs[kind] = {b: read_obj(out / "garments" / GARMENT / f"{b}.obj").V for b in ("banana", "pear")}
    # The source drape is the same run's state before the morph: equal to the restart's to the written digits.
    np.testing.assert_array_equal(runs["continuous"]["banana"], runs["restart"]["banana"])
    # The target is simulated otherwise (no restart), outside the body, and moved by the body's change.
    assert not np.array_equal(runs["continuous"]["pear"], runs["restart"]["pear"])
    body = read_obj(tmp_path / "continuous" / "bodies" / "pear.obj")
    assert TriangleSurface(body.V, body.F).signed_distance(runs["continuous"]["pear"])[0].min() >= 0.0
    assert np.linalg.norm(runs["continuous"]["pear"] - runs["continuous"]["banana"], axis=1).mean() > 1e-3
