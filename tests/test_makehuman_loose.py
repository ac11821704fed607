"""lab.makehuman_drape's looser cut of a garment (--loose): away from the body by the ease, the pinned band kept."""

import numpy as np
from meshes import icosphere

from lab.makehuman_drape import LOOSE_FADE, loose_variant


def test_a_looser_cut_moves_away_from_the_body_but_at_its_pins():
    BV, BF = icosphere(3)
    GV, GF = icosphere(3, radius=1.05)
    pins = np.flatnonzero(GV[:, 2] > 1.0)                          # a cap, as a waistband would be
    W = loose_variant(GV, GF, BV, BF, pins, 0.01)
    grew = np.linalg.norm(W, axis=1) - np.linalg.norm(GV, axis=1)
    far = GV[:, 2] < 1.0 - 2 * LOOSE_FADE
    assert np.allclose(grew[far], 0.01, atol=2e-4)                # the ease, away from the body
    np.testing.assert_array_equal(W[pins], GV[pins])               # the pinned band stays
    assert np.all(grew >= -1e-12)

