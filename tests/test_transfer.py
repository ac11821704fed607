import json

import numpy as np
import pytest
from meshes import arms_down, icosphere, in_pieces, require_makehuman

from garment_transfer.errors import Cancelled, MeshError, PoseError, TopologyMismatchError
from garment_transfer.geometry.mesh import mesh_from_polygons, mesh_from_triangles
from garment_transfer.geometry.obj import read_obj
from garment_transfer.geometry.proximity import TriangleSurface
from garment_transfer.pipeline.metrics import evaluate
from garment_transfer.pipeline import transfer
from garment_transfer.pipeline.outfit import transfer_outfit
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


def test_result_warnings_name_the_file_and_every_kind_of_failure():
    from garment_transfer.pipeline.result_check import result_warnings

    clean = {"garment_edges_through_body": 0, "body_edges_through_garment": 0, "inside_vertices": 0,
             "self_intersections": 4, "self_intersections_source": 4, "self_intersections_new": 0,
             "layer_crossings": 0}
    assert result_warnings(clean, "out.obj") == []
    bad = dict(clean, garment_edges_through_body=2, body_edges_through_garment=5, inside_vertices=1,
               self_intersections=9, self_intersections_new=3, layer_crossings=7)
    text = result_warnings(bad, "out.obj")
    assert len(text) == 4 and all(t.startswith("out.obj: ") for t in text)
    assert "2 garment edges pass through the body and 5 body edges" in text[0]
    assert "1 garment vertices are inside" in text[1]
    assert "3 edge-triangle pairs its source does not (9 in all, 4 on the source)" in text[2]
    assert "7 edge-triangle pairs cross the layers under it" in text[3]


def test_a_target_in_another_pose_is_refused_naming_the_limb_and_the_angle():
    root = require_makehuman()
    source = read_obj(root / "bodies" / "female_average.obj", name="female_average")
    garment = read_obj(root / "garments" / "female_sportsuit01" / "female_average.obj")
    posed = source.with_vertices(arms_down(source.V, np.radians(35)), name="arms_down")
    with pytest.raises(MeshError, match=r"arms_down: is in another pose than the source body female_average: its "
                                        r"(left|right) (upper arm|forearm) points \d+ degrees away.*--skeleton"):
        transfer_garment(source, posed, garment, resolve_crossings=False)
    # An outfit is refused alike (its layers are posed into the target's pose with a skeleton, as one garment is).
    with pytest.raises(PoseError, match=r"arms_down: is in another pose .*--skeleton") as e:
        transfer_outfit(source, posed, [garment])
    assert "degrees away" in e.value.difference and "--skeleton" in e.value.remedy
    # A shape of the same pose, and arms a little lower, are not; the angle is in the result's info.
    pear = read_obj(root / "bodies" / "female_pear.obj")
    near = source.with_vertices(arms_down(source.V, np.radians(10)), name="arms_10")
    for body, most in ((pear, 3.0), (near, transfer.POSE_LIMITS["upper arm"])):
        pose = transfer_garment(source, body, garment, resolve_crossings=False).info["limb_angles"]
        assert 0.0 < pose["degrees"] < most
    unchecked = transfer_garment(source, posed, garment, resolve_crossings=False, check_pose=False)
    assert unchecked.V.shape == garment.V.shape and "limb_angles" not in unchecked.info
    # A garment that leaves the arms bare (the suit's trousers alone) does not care where they point.
    legs = [p for p in garment.polygons() if garment.V[p, 1].max() < 0.0]
    assert len(legs) > 0.2 * garment.n_faces
    used = np.unique(np.concatenate(legs))
    index = np.full(garment.n_vertices, -1)
    index[used] = np.arange(used.size)
    trousers = mesh_from_polygons(garment.V[used], [index[p] for p in legs], name="trousers")
    pose = transfer_garment(source, posed, trousers, resolve_crossings=False).info["limb_angles"]
    assert pose["band"] is None or "arm" not in pose["band"]



def test_a_target_standing_turned_in_the_world_is_in_the_same_pose():
    # A character facing another way in the scene: the source's mesh in the pear's shape, a quarter turn about
    # the vertical (MakeHuman's y) and moved. The limbs are compared after turning its trunk onto the source's.
    from garment_transfer.fitting.limbs import TURN_NOISE, find_limbs, limb_angles, trunk_rotation

    root = require_makehuman()
    source = read_obj(root / "bodies" / "female_average.obj", name="female_average")
    garment = read_obj(root / "garments" / "female_sportsuit01" / "female_average.obj")
    pear = read_obj(root / "bodies" / "female_pear.obj")
    t = np.radians(90.0)
    R = np.array([[np.cos(t), 0.0, np.sin(t)], [0.0, 1.0, 0.0], [-np.sin(t), 0.0, np.cos(t)]])
    shift = np.array([30.0, 5.0, -20.0])
    turned = pear.with_vertices(pear.V @ R.T + shift, name="pear_turned")
    limbs = find_limbs(source.V, source.F)
    np.testing.assert_allclose(trunk_rotation(pear.V, turned.V, limbs.trunk), R, atol=1e-12)
    straight = limb_angles(source.V, source.F, pear.V, limbs)
    # The same angles, but for the pear's own trunk turn (0.06 degrees), taken out with the world's.
    assert limb_angles(source.V, source.F, turned.V, limbs)["bands"] == pytest.approx(straight["bands"], abs=0.1)
    # The shapes' own trunks differ by less than the turn taken for the world's (measured: 2.1 degrees from women
    # to men), so a target in the source's frame is measured as before.
    men = read_obj(root / "bodies" / "male_average.obj")
    R_men = trunk_rotation(source.V, men.V, limbs.trunk)
    assert 0.5 < np.degrees(np.arccos((np.trace(R_men) - 1.0) / 2.0)) < TURN_NOISE
    # The transfer onto it is the transfer onto the pear, turned and moved (up to the rounds of the crossing pass).
    expected = transfer_garment(source, pear, garment).V @ R.T + shift
    result = transfer_garment(source, turned, garment)
    assert result.info["limb_angles"]["degrees"] == pytest.approx(straight["degrees"], abs=0.1)
    assert np.linalg.norm(result.V - expected, axis=1).mean() < 0.001
    # Turned and in another pose, it is refused with the figure of the same pose in the source's frame.
    lowered = arms_down(source.V, np.radians(35))
    degrees = limb_angles(source.V, source.F, lowered, limbs)["degrees"]
    posed = source.with_vertices(lowered @ R.T + shift, name="arms_down_turned")
    with pytest.raises(MeshError, match=rf"arms_down_turned: is in another pose .* points {degrees:.0f} degrees away"):
        transfer_garment(source, posed, garment, resolve_crossings=False)


def test_a_garment_whose_pieces_are_not_joined_is_transferred_as_the_joined_one_with_its_seams_closed():
    from garment_transfer.geometry.mesh import shared_places, vertex_places
    from garment_transfer.geometry.poisson import JoinedPoissonSolver, PoissonSolver

    source, target, _ = spheres()
    GV, GF = icosphere(3, radius=1.05)
    keep = GV[GF].mean(axis=1)[:, 2] < 0.3
    used = np.unique(GF[keep])
    index = np.full(len(GV), -1)
    index[used] = np.arange(used.size)
    V, F = GV[used], index[GF[keep]]
    joined = mesh_from_triangles(V, F, name="joined")
    # The band cut into two pieces at x = 0: each vertex they share written again for the second piece.
    PV, PF, seam, twin = in_pieces(V, F)
    pieces = mesh_from_triangles(PV, PF, name="pieces")
    place, first = vertex_places(pieces.V)
    assert np.array_equal(first, np.arange(len(V))) and np.array_equal(place[len(V):], seam)
    assert np.array_equal(shared_places(pieces.V), np.stack([twin, seam], axis=1))
    # The solve of the pieces is the joined garment's, given to every vertex of a place.
    w = np.linspace(0.5, 2.0, pieces.n_vertices)
    Q = np.tile(np.diag([1.3, 1.3, 1.0]), (pieces.n_triangles, 1, 1))
    anchors = pieces.V * [1.3, 1.3, 1.0]
    expected = PoissonSolver(V, F, w[:len(V)]).solve(Q, anchors[:len(V)])
    joined_solver = PoissonSolver(V, place[pieces.F], w[first])
    assert np.array_equal(JoinedPoissonSolver(joined_solver, first, place).solve(Q, anchors), expected[place])
    # And it is the solve a transfer prepares for the pieces.
    prepared = prepare_garment(source, pieces)
    assert isinstance(prepared.solver, JoinedPoissonSolver)
    assert np.array_equal(prepared.solver.solve(Q, anchors),
                          prepare_garment(source, joined).solver.solve(Q, anchors[:len(V)])[place])
    # The whole transfer (the fix and the crossing pass too): each seam vertex where its twin is, clear of the
    # body, and the joined garment's result.
    r = transfer_garment(source, target, pieces, offset=0.07)          # nearer than the offset: the fix pushes
    assert np.array_equal(r.V[twin], r.V[seam]) and r.info["crossings_after"] == 0
    assert r.info["pushed_vertices"] > 0 and r.penetrating_vertices == 0
    assert np.abs(r.V[:len(V)] - transfer_garment(source, target, joined, offset=0.07).V).max() < 1e-4
