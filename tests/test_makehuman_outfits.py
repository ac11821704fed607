"""lab.makehuman_procedural's outfits: a top and a bottom of the catalogue carried onto the MakeHuman source body
as one garment of two pieces, each piece where the catalogue's own garment is carried."""

import numpy as np
from meshes import require_makehuman

from garment_transfer.geometry.mesh import connected_pieces
from garment_transfer.geometry.obj import read_obj


def test_an_outfit_is_its_two_pieces_carried_as_the_garments_are():
    from lab.makehuman_procedural import MANNEQUIN, OUTFITS, fit, fit_outfit
    from lab.paths import DEMO_DATA, MAKEHUMAN_SOURCE
    from lab.procedural.garments import EXTRA_GARMENTS, TEST_GARMENTS, TRAIN_GARMENTS

    assert all(set(parts) <= set(TRAIN_GARMENTS) | set(TEST_GARMENTS) | set(EXTRA_GARMENTS)
               for parts in OUTFITS.values())
    root = require_makehuman()
    mannequin = read_obj(DEMO_DATA / "bodies" / f"{MANNEQUIN}.obj")
    body = read_obj(root / "bodies" / f"{MAKEHUMAN_SOURCE}.obj")
    mesh, pins, info, registration = fit_outfit("outfit_tank_top_shorts", mannequin, body)
    assert pins is None and info["pieces"] == ["tank_top", "shorts"]
    top, _, top_info, _ = fit("tank_top", mannequin, body, registration)
    bottom, _, bottom_info, _ = fit("shorts", mannequin, body, registration)
    n = top.n_vertices
    np.testing.assert_array_equal(mesh.V, np.vstack([top.V, bottom.V]))
    expected = top.polygons() + [p + n for p in bottom.polygons()]
    assert mesh.n_faces == len(expected) and all(np.array_equal(a, b) for a, b in zip(mesh.polygons(), expected))
    count, label = connected_pieces(mesh.n_vertices, mesh.F)
    assert count == 2 and len(set(label[:n])) == 1 and len(set(label[n:])) == 1 and label[0] != label[-1]
    assert info["inside_after_transfer"] == top_info["inside_after_transfer"] + bottom_info["inside_after_transfer"]
