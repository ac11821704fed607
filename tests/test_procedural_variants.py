import numpy as np
import pytest

from lab.procedural.garments import EXTRA_GARMENTS, TEST_GARMENTS, TRAIN_GARMENTS, garment


def test_extra_garments_are_new_training_garments_only():
    assert len(EXTRA_GARMENTS) == len(set(EXTRA_GARMENTS)) == 40
    assert not set(EXTRA_GARMENTS) & set(TRAIN_GARMENTS + TEST_GARMENTS)
    assert len(TRAIN_GARMENTS + EXTRA_GARMENTS + TEST_GARMENTS) >= 60
    with pytest.raises(ValueError, match="shorts_loose"):
        garment("shorts_loose")         # no variants of the test garments: they stay unseen


@pytest.mark.parametrize("style", ["mini_skirt", "culottes"])
def test_loose_hangs_farther_from_the_body_than_regular_and_tight(style):
    def radius(g):
        return float(np.mean(np.hypot(g.V[:, 0], g.V[:, 1] - g.V[:, 1].mean())))

    tight, regular, loose = (garment(f"{style}{s}") for s in ("_tight", "", "_loose"))
    assert tight.V.shape == regular.V.shape == loose.V.shape
    np.testing.assert_array_equal(tight.polygons, regular.polygons)
    assert radius(tight) < radius(regular) < radius(loose)
    assert loose.name == f"{style}_loose"
