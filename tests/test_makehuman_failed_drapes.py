"""lab.makehuman_drape's check for a failed drape: a piece that reaches the shoulders slid down the body."""

import numpy as np
import pytest
from meshes import icosphere

from garment_transfer.geometry.binding import bind, carry
from garment_transfer.geometry.mesh import mesh_from_triangles


def part(V, F, keep):
    """The faces of (V, F) whose vertices all satisfy ``keep``, reindexed."""
    F = F[keep[F].all(axis=1)]
    used = np.unique(F)
    index = np.full(V.shape[0], -1)
    index[used] = np.arange(used.size)
    return V[used], index[F]


@pytest.fixture
def scene():
    body = mesh_from_triangles(*icosphere(3), name="body")               # Y from -1 to 1
    GV, GF = icosphere(3, radius=1.05)
    top = part(GV, GF, GV[:, 1] > 0.3)                                    # reaches the "shoulders"
    skirt = part(GV, GF, GV[:, 1] < -0.2)                                 # hangs below them
    garment = mesh_from_triangles(np.vstack([top[0], skirt[0]]), np.vstack([top[1], skirt[1] + len(top[0])]),
                                  name="garment")
    target = body.with_vertices(body.V * 1.2, name="target")             # 2.4 high
    carried = carry(bind(garment.V, body.V, body.F), target.V, body.F)
    return body, garment, target, carried, np.arange(garment.n_vertices) < len(top[0])


def test_a_drape_where_the_body_carries_the_garment_did_not_slide(scene):
    from lab.makehuman_drape import shoulder_drops

    body, garment, target, carried, _ = scene
    assert shoulder_drops(body, garment, [target], [carried]) == [pytest.approx(0.0, abs=1e-12)]


def test_the_top_piece_slid_down_is_measured_over_the_target_height(scene):
    from lab.makehuman_drape import shoulder_drops

    body, garment, target, carried, on_top = scene
    down = carried.copy()
    down[on_top, 1] -= 0.12
    up = carried.copy()
    up[on_top, 1] += 0.12                                                 # rising is not sliding off
    skirt_down = carried.copy()
    skirt_down[~on_top, 1] -= 0.5                                         # a piece below the shoulders
    # Each target measured on its own, the garment bound once.
    assert shoulder_drops(body, garment, [target] * 3, [down, up, skirt_down]) == [
        pytest.approx(0.12 / 2.4, rel=1e-9), pytest.approx(0.0, abs=1e-12), pytest.approx(0.0, abs=1e-12)]


def test_failed_drapes_lists_only_the_garments_and_targets_past_the_limit(scene):
    from types import SimpleNamespace

    from lab.makehuman_drape import SLID_SHARE, failed_drapes

    body, garment, target, carried, on_top = scene
    slid, held = carried.copy(), carried.copy()
    slid[on_top, 1] -= 2.4 * (SLID_SHARE + 0.01)
    held[on_top, 1] -= 2.4 * (SLID_SHARE - 0.01)
    drapes = {("fell", "t1"): slid, ("fell", "t2"): held, ("stayed", "t1"): held, ("stayed", "t2"): carried}
    ds = SimpleNamespace(garments=["fell", "stayed"], body=lambda name: body if name == "src" else target,
                         garment=lambda g, b: garment if b == "src" else garment.with_vertices(drapes[g, b]))
    assert failed_drapes(ds, "src", ["t1", "t2"]) == {"fell": {"t1": round(SLID_SHARE + 0.01, 4)}}
