"""The figures of a result as written: what the transfer already searched is used only when it is of the body
given."""

from meshes import grid, icosphere

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
