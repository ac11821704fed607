"""Broken and unusual inputs: a clear error naming the problem, or a documented repair; never NaN."""

import numpy as np
import pytest
from meshes import icosphere

from garment_transfer.errors import MeshError
from garment_transfer.geometry.mesh import mesh_from_polygons, mesh_from_triangles, mesh_report
from garment_transfer.geometry.obj import read_obj
from garment_transfer.geometry.proximity import TriangleSurface
from garment_transfer.pipeline.transfer import transfer_garment


@pytest.fixture(scope="module")
def bodies():
    V, F = icosphere(3)
    return mesh_from_triangles(V, F, name="src"), mesh_from_triangles(V * [1.25, 1.1, 1.0], F, name="tgt")


def skirt(radius=1.05, cut=0.2):
    V, F = icosphere(3, radius=radius)
    keep = V[F].mean(axis=1)[:, 2] < cut
    used = np.unique(F[keep])
    remap = -np.ones(V.shape[0], np.int64)
    remap[used] = np.arange(used.size)
    return V[used], remap[F[keep]]


def check(result, garment, target):
    assert np.all(np.isfinite(result.V))
    used = np.unique(garment.F)
    assert (TriangleSurface(target.V, target.F).signed_distance(result.V[used])[0] >= 0).all()


def test_single_triangle(bodies):
    src, tgt = bodies
    g = mesh_from_triangles([[1.05, 0, 0], [1.0, 0.3, 0.1], [1.0, 0, 0.3]], [[0, 1, 2]], name="tri")
    check(transfer_garment(src, tgt, g), g, tgt)


def test_zero_area_needle_duplicate_and_loose(bodies):
    src, tgt = bodies
    V, F = skirt()
    n = V.shape[0]
    # Duplicates, a loose vertex inside the body and one outside.
    V2 = np.vstack([V, V[:3], [[0, 0, 0.2]], [[2, 0, 0]]])
    F2 = np.vstack([F, [[0, 0, 1]], [[0, 1, 1]], [[n, n + 1, n + 2]],       # zero-area faces
                    [[F[0, 0], F[0, 1], F[0, 1]]]])
    needle = V2[F[1]].copy()
    needle[2] = needle[0] + 1e-9 * (needle[1] - needle[0])
    g = mesh_from_polygons(V2, [list(f) for f in F2], name="messy")
    report = mesh_report(g)
    assert report["degenerate_triangles"] >= 3 and report["loose_vertices"] == 2
    r = transfer_garment(src, tgt, g)
    assert np.all(np.isfinite(r.V))
    # The loose vertex that was inside the body is outside afterwards too.
    assert TriangleSurface(tgt.V, tgt.F).signed_distance(r.V[[n + 3]])[0][0] >= 0


def test_flipped_faces_give_nearly_the_same_result(bodies):
    # Deformation gradients do not depend on a face's orientation; the Poisson energy uses two of a
    # triangle's three edges, and which two follows the vertex order: results agree to a small
    # fraction of an edge.
    src, tgt = bodies
    V, F = skirt()
    flipped = F.copy()
    flipped[::3] = flipped[::3, ::-1]
    a = transfer_garment(src, tgt, mesh_from_triangles(V, F, name="a"))
    b = transfer_garment(src, tgt, mesh_from_triangles(V, flipped, name="b"))
    edge = np.linalg.norm(V[F[:, 0]] - V[F[:, 1]], axis=1).mean()
    assert np.max(np.abs(a.V - b.V)) < 0.02 * edge


def test_non_manifold_and_disconnected_pieces(bodies):
    src, tgt = bodies
    V, F = skirt()
    n = V.shape[0]
    # A fin sharing an edge with two faces (non-manifold) and a second, separate piece.
    e = F[0, :2]
    V2 = np.vstack([V, [V[e].mean(axis=0) * 1.1], V * [1, 1, -1] * 1.02])
    F2 = np.vstack([F, [[e[0], e[1], n]], F + n + 1])
    g = mesh_from_triangles(V2, F2, name="pieces")
    rep = mesh_report(g)
    assert rep["non_manifold_edges"] >= 1 and rep["pieces"] == 2
    check(transfer_garment(src, tgt, g), g, tgt)


def test_garment_inside_the_body_is_pushed_out(bodies):
    src, tgt = bodies
    # Skin-tight: inside by 0.15% of the body scale (the placement check refuses more than 1% of
    # the vertices deeper than 0.5%).
    V, F = skirt(radius=0.997)
    g = mesh_from_triangles(V, F, name="inside")
    r = transfer_garment(src, tgt, g)
    assert r.info["inside_before"] > 0 and r.penetrating_vertices == 0
    check(r, g, tgt)


def test_bodies_with_holes(bodies):
    src, tgt = bodies
    keep = src.V[src.F].mean(axis=1)[:, 2] < 0.85          # an open neck
    s = mesh_from_triangles(src.V, src.F[keep], name="open_src")
    t = mesh_from_triangles(tgt.V, tgt.F[keep], name="open_tgt")
    V, F = skirt()
    g = mesh_from_triangles(V, F, name="g")
    check(transfer_garment(s, t, g), g, t)


def test_all_zero_area_garment_is_refused(bodies):
    src, tgt = bodies
    g = mesh_from_triangles([[1.05, 0, 0], [1.05, 0, 0], [1.05, 0, 0]], [[0, 1, 2]], name="flat.obj")
    with pytest.raises(MeshError, match="flat.obj: every face has zero area"):
        transfer_garment(src, tgt, g)


@pytest.mark.parametrize("threads", [1, 2])
def test_zero_area_is_named_before_distance_from_the_body(bodies, monkeypatch, threads):
    # With several cores the garment's area is checked on a thread while it is bound; a garment that is
    # both flat and far away is still refused for its area first, as on one core.
    from garment_transfer.pipeline import transfer

    monkeypatch.setattr(transfer, "THREADS", threads)
    src, tgt = bodies
    g = mesh_from_triangles([[90.0, 0, 0], [90.0, 0, 0], [90.0, 0, 0]], [[0, 1, 2]], name="far_flat.obj")
    with pytest.raises(MeshError, match="far_flat.obj: every face has zero area"):
        transfer_garment(src, tgt, g)


@pytest.mark.parametrize("text, problem", [
    ("v 0 0 0\nv 1 0 0\nv 0 1", "line 3: the file ends in the middle of a record.*cut off"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2", "line 5: the file ends in the middle of a record"),
    ("v 0 0 0\nv 1 0 0\nv 0 1\n", "3 coordinates"),
    ("v 0 0 inf\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "NaN or infinite"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n", "out of range"),
])
def test_truncated_or_corrupt_obj(tmp_path, text, problem):
    p = tmp_path / "cut.obj"
    p.write_text(text)
    with pytest.raises(MeshError, match=problem):
        read_obj(p)


def test_lines_and_points_are_ignored_with_faces_kept(tmp_path):
    p = tmp_path / "with_lines.obj"
    p.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 5 5 5\nl 1 4\np 4\nf 1 2 3\n")
    m = read_obj(p)
    assert m.n_faces == 1 and mesh_report(m)["loose_vertices"] == 1
