"""The committed demo dataset (data/demo): complete, consistent, compact, and with
every garment outside the body it was draped on."""

from __future__ import annotations

import numpy as np
import pytest

from garment_transfer.geometry.mesh import require_same_topology
from garment_transfer.geometry.proximity import TriangleSurface
from garment_transfer.learning.dataset import load_dataset
from lab.paths import DEMO_DATA

DEMO = DEMO_DATA


@pytest.fixture(scope="module")
def demo():
    return load_dataset(DEMO)


def test_manifest_describes_the_dataset(demo):
    m = demo.manifest
    assert (m["units"], m["up_axis"], m["forward_axis"]) == ("metres", "Z", "-Y")
    assert m["source"] == "banana" and "pear" in m["targets"]
    assert m["bodies"] == [m["source"]] + m["targets"]
    assert len(m["train_garments"]) == 15 and len(m["test_garments"]) == 5
    assert sorted(m["garments"]) == sorted(m["train_garments"] + m["test_garments"])
    demo.require_complete(m["garments"], m["bodies"])


def test_bodies_share_one_topology(demo):
    src = demo.body("banana")
    assert src.n_triangles >= 10_000
    for name in demo.bodies:
        require_same_topology(src, demo.body(name))


def test_dataset_is_compact():
    size = sum(f.stat().st_size for f in DEMO.rglob("*") if f.is_file())
    assert size < 30e6


@pytest.mark.parametrize("garment", ["pleated_skirt", "shorts", "tshirt"])
def test_garments_keep_topology_and_stay_outside_every_body(demo, garment):
    F = demo.body("banana").F
    src = demo.garment(garment, "banana")
    for body in demo.bodies:
        tgt = demo.garment(garment, body)
        require_same_topology(src, tgt)
        sd = TriangleSurface(demo.body(body).V, F).signed_distance(tgt.V)[0]
        # 5 significant digits in the files: a rounding of up to 0.05 mm.
        assert sd.min() > -1e-4, body
        if body != "banana":
            assert np.abs(tgt.V - src.V).max() > 0.01, body  # it followed the body
