"""The figures of a result as written: what the transfer already searched is used only when it is of the body
given."""

from meshes import grid, icosphere, in_pieces

from garment_transfer.geometry.intersections import crossings
from garment_transfer.geometry.mesh import mesh_from_triangles
from garment_transfer.geometry.proximity import TriangleSurface
from garment_transfer.geometry.readings import readings_of
from garment_transfer.pipeline.result_check import check_result


def test_a_surface_of_the_body_given_gives_the_same_figures_and_one_of_another_body_is_not_used():
    BV, BF = icosphere(3)
    body = mesh_from_triangles(BV, BF, name="body")
    sheet = grid(nx=6, ny=6, size=2.4)                  # quads over the sphere's top, which pokes through them
    V = sheet.V + [-1.2, -0.96, 0.97]
    garment = sheet.with_vertices(V + [0.0, 0.0, 0.5])   # its source, clear of the body
    plain = check_result(garment, V, body)
    c = crossings(V, readings_of(garment), BV, BF)
    assert plain["body_edges_through_garment"] == c["b_edges_through_a"] > 0
    assert plain["inside_vertices"] == int((TriangleSurface(BV, BF).signed_distance(V)[0] < 0).sum())
    assert plain["min_body_distance"] == 0.0
    assert check_result(garment, V, body, surface=TriangleSurface(BV, BF)) == plain
    # A surface of another body (the sphere grown past the sheet) must not stand in for the body given.
    other = TriangleSurface(BV * 1.2, BF)
    assert check_result(garment, V, body, surface=other) == plain
    grown = check_result(garment, V, mesh_from_triangles(BV * 1.2, BF, name="grown"))
    assert grown["inside_vertices"] > plain["inside_vertices"]


def test_a_garment_whose_pieces_are_not_joined_has_its_seams_measured_on_the_result_and_said_when_opened():
    import numpy as np

    from garment_transfer.geometry.mesh import shared_places
    from garment_transfer.pipeline.result_check import SEAM_TOLERANCE, result_warnings, seam_gap

    BV, BF = icosphere(2)
    body = mesh_from_triangles(BV, BF, name="body")
    # A shell around the body cut into two pieces at x = 0: each vertex the two halves share written twice.
    SV, SF = icosphere(2, radius=1.1)
    PV, PF, seam, twin = in_pieces(SV, SF)
    pieces = mesh_from_triangles(PV, PF, name="pieces")
    pairs = shared_places(pieces.V)
    assert sorted(map(tuple, pairs)) == sorted(zip(twin.tolist(), seam.tolist()))
    assert shared_places(SV).shape == (0, 2)
    # The result moves the right piece's copies 1 mm out along x: the seam opens by exactly that at each pair.
    V = pieces.V.copy()
    V[twin] += [0.001, 0.0, 0.0]
    check = check_result(pieces, V, body)
    assert (check["seam_vertices"], check["seam_gap"]) == (seam.size, seam_gap(pieces.V, V)[1])
    assert abs(check["seam_gap"] - 0.001) < 1e-15
    assert check["seam_tolerance"] == SEAM_TOLERANCE * float(np.linalg.norm(np.ptp(pieces.V, axis=0)))
    said = [w for w in result_warnings(check, "out.obj") if "not joined" in w]
    assert said == [f"out.obj: {seam.size} of the garment's vertices lie on another of its vertices (its pieces are "
                    "not joined at their seams), and the result moves them apart by up to 0.001: join the pieces "
                    "(Merge by Distance in Blender) before the transfer"]
    # Moved as one, or joined: nothing said.
    closed = check_result(pieces, pieces.V * 1.01, body)
    assert closed["seam_gap"] == 0.0 and not [w for w in result_warnings(closed, "out.obj") if "not joined" in w]
    joined = check_result(mesh_from_triangles(SV, SF, name="joined"), SV * 1.01, body)
    assert (joined["seam_vertices"], joined["seam_gap"]) == (0, 0.0)
