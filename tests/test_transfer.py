import json

import numpy as np
import pytest
from meshes import icosphere, require_makehuman

from garment_transfer.errors import Cancelled, MeshError, TopologyMismatchError
from garment_transfer.geometry.mesh import mesh_from_triangles
from garment_transfer.geometry.obj import read_obj
from garment_transfer.geometry.proximity import TriangleSurface
from garment_transfer.pipeline.metrics import evaluate
from garment_transfer.pipeline.transfer import prepare_garment, transfer_garment


def spheres():
    V, F = icosphere(3)
    source = mesh_from_triangles(V, F, name="source")
    target = mesh_from_triangles(V * [1.3, 1.3, 1.0], F, name="target")
    GV, GF = icosphere(3, radius=1.05)
    keep = GV[GF].mean(axis=1)[:, 2] < 0.3      # a skirt-like open band
    garment = mesh_from_triangles(GV, GF[keep], name="garment")
    return source, target, garment


def test_direct_transfer_follows_a_scaled_body_and_stays_outside():
    source, target, garment = spheres()
    r = transfer_garment(source, target, garment)
    used = np.unique(garment.F)
    radial = np.linalg.norm(r.V[used][:, :2], axis=1)
    radial0 = np.linalg.norm(garment.V[used][:, :2], axis=1)
    assert np.median(radial / np.maximum(radial0, 1e-9)) > 1.2
    assert r.penetrating_vertices == 0
    assert (TriangleSurface(target.V, target.F).signed_distance(r.V[used])[0] >= 0).all()
    assert set(r.seconds) >= {"field", "embed", "bind", "factor", "solve", "fix", "total"}


def test_identity_transfer_keeps_the_garment():
    source, _, garment = spheres()
    r = transfer_garment(source, source, garment, fix_penetration=False)
    used = np.unique(garment.F)
    np.testing.assert_allclose(r.V[used], garment.V[used], atol=1e-9)


def test_prepared_garment_gives_the_same_result():
    source, target, garment = spheres()
    prepared = prepare_garment(source, garment)
    a = transfer_garment(source, target, garment, prepared=prepared)
    b = transfer_garment(source, target, garment)
    np.testing.assert_allclose(a.V, b.V, atol=1e-12)
    assert "factor" not in a.seconds


def test_bodies_of_different_topology_are_refused():
    source, _, garment = spheres()
    V, F = icosphere(2)
    with pytest.raises(TopologyMismatchError):
        transfer_garment(source, mesh_from_triangles(V, F, name="other"), garment)


def test_garment_far_from_the_body_is_refused():
    source, target, garment = spheres()
    far = garment.with_vertices(garment.V + [10.0, 0, 0], name="far.obj")
    with pytest.raises(MeshError, match="far.obj.*far from the source body"):
        transfer_garment(source, target, far)


def test_progress_can_cancel():
    source, target, garment = spheres()
    seen = []

    def progress(fraction, stage):
        seen.append(stage)
        return stage == "solve"

    with pytest.raises(Cancelled):
        transfer_garment(source, target, garment, progress=progress)
    assert "fix" not in seen


def test_makehuman_direct_transfer_average_to_pear_every_garment():
    root = require_makehuman()
    manifest = json.loads((root / "manifest.json").read_text())
    source = read_obj(root / "bodies" / "female_average.obj")
    target = read_obj(root / "bodies" / "female_pear.obj")
    surface = TriangleSurface(target.V, target.F)
    for name in manifest["garments"]:
        garment = read_obj(root / "garments" / name / "female_average.obj")
        reference = read_obj(root / "garments" / name / "female_pear.obj")
        r = transfer_garment(source, target, garment)
        assert r.penetrating_vertices == 0, name
        assert (surface.signed_distance(r.V)[0] < 0).sum() == 0, name
        result = garment.with_vertices(r.V)
        e = evaluate(garment, result, target, reference=reference)
        # The garment moved toward its fitted shape on the pear body: closer than the untransferred one.
        assert e["drape_error_relative"] < 0.5, (name, e)
        assert e["vertex_error_mean"] < 0.06, (name, e)   # 6 mm (the files are in decimetres)


def test_result_moves_with_the_scene():
    # A rigid motion of all three inputs moves the result by the same motion (settings derived from
    # the body are rotation-invariant).
    from meshes import random_rotation

    source, target, garment = spheres()
    # Jittered, so that no garment vertex lies exactly over a body vertex (a tie between triangles).
    jitter = np.random.default_rng(8).normal(scale=1e-3, size=garment.V.shape)
    garment = garment.with_vertices(garment.V + jitter)
    R = random_rotation(np.random.default_rng(7))
    t = np.array([3.0, -2.0, 0.5])

    def moved(m):
        return m.with_vertices(m.V @ R.T + t)

    a = transfer_garment(source, target, garment, fix_penetration=False)
    b = transfer_garment(moved(source), moved(target), moved(garment), fix_penetration=False)
    np.testing.assert_allclose(b.V, a.V @ R.T + t, atol=1e-9)


def test_crossings_left_names_what_the_pass_could_not_clear():
    from garment_transfer.pipeline.transfer import crossings_left

    assert crossings_left({}) is None                                  # the pass did not run
    assert crossings_left({"crossings_after": 0, "crossings_before": 12}) is None
    text = crossings_left({"crossings_after": 7, "crossings_before": 9, "kept_input": False})
    assert "7 garment-body crossings are left" in text and "penetration fix" not in text
    assert "as the penetration fix left it" in crossings_left({"crossings_after": 9, "kept_input": True})
