"""The promise checked on a result as the user has it: the file as written and read back (or the object as
Blender evaluates it), against the body the user gave, under every triangulation of both.

The crossing pass (``geometry.clearance``) keeps its own counts as it works, on the coordinates it computed.
What a user gets is those coordinates written (rounded to the file's digits, taken back to the target's frame
after a registration, stored as 32-bit floats by Blender) and triangulated by whatever tool reads it. So the
figures a user is told (the command line's JSON, the batch records, Blender's panel) are measured again here,
on what was written, with every reading of the garment's and the body's polygons
(``geometry.readings``): a quad's two splits, an n-gon's triangles, every diagonal as an edge.
"""

from __future__ import annotations

import numpy as np

from ..geometry.intersections import crossings
from ..geometry.mesh import Mesh, shared_places
from ..geometry.obstacle import Obstacle, edge_length, garment_crossings, garment_distance
from ..geometry.proximity import TriangleSurface, made_of
from ..geometry.readings import Readings, readings_of
from ..geometry.self_check import beyond_source, pairs_in_full
from ..geometry.threads import together

#: Vertices of a result that lay on each other on the source and lie apart by more than this share of the
#: garment's size are said to be opened (a file's 9 significant digits round far finer).
SEAM_TOLERANCE = 1e-6

#: The keys of a transfer's ``info`` that describe the result as the pass left it in memory; a report of the
#: result as written gives ``check_result``'s figures instead.
PASS_RESULT_KEYS = ("crossings_after", "near_after", "inside_after", "self_intersections_after",
                    "self_intersections_new", "self_intersections_added", "self_intersections_source")


def seam_gap(garment_V, V) -> tuple[int, float]:
    """How far a result opens the seams of its garment's unjoined pieces.

    Parameters
    ----------
    garment_V : (n,3) float
        The garment on its source body.
    V : (n,3) float
        The result.

    Returns
    -------
    vertices : int
        Vertices that lie on another on the source (``mesh.shared_places``).
    gap : float
        The largest distance between such a vertex and the one it lay on, in the result (0 with none).
    """
    pairs = shared_places(garment_V)
    if pairs.shape[0] == 0:
        return 0, 0.0
    V = np.asarray(V, dtype=np.float64)
    return int(pairs.shape[0]), float(np.linalg.norm(V[pairs[:, 0]] - V[pairs[:, 1]], axis=1).max())


def check_result(garment: Mesh, V, target_body: Mesh, *, source_pairs=None, readings: Readings | None = None,
                 body_readings: Readings | None = None, layers_below=(), obstacle: Obstacle | None = None,
                 surface: TriangleSurface | None = None) -> dict:
    """Every figure of the promise, measured on a result.

    Parameters
    ----------
    garment : Mesh
        The garment on the source body (its faces, and its source shape for the self-intersections).
    V : (n,3) float
        The result as the user has it (read back from the file written).
    target_body : Mesh
        The body the user gave, in the result's frame.
    source_pairs : (k,2) int, optional
        The garment's own self-intersecting pairs on the source (``PreparedGarment.source_pairs()``), if known.
    readings, body_readings : Readings, optional
        ``readings_of(garment)``, ``readings_of(target_body)``, if known.
    layers_below : sequence of (V (k,3), Readings or (l,3) int)
        Garments worn under this one, as the user has them.
    obstacle : Obstacle, optional
        ``target_body`` binned already (``TransferResult.obstacle``: the same body, as the crossing pass saw it);
        used only when it holds ``target_body``'s own polygons (a target written triangulated is checked on its
        own triangles, though the pass saw the source's polygons).
    surface : TriangleSurface, optional
        ``target_body``'s own triangles searched already (``TransferResult.surface``: the body the penetration fix
        searched), for the body binned here when ``obstacle`` is not of it.

    Returns
    -------
    dict
        ``garment_edges_through_body``, ``body_edges_through_garment`` (edges of every reading),
        ``garment_edge_body_pairs``, ``body_edge_garment_pairs`` ((edge, triangle) pairs), ``inside_vertices``
        (garment vertices inside the body), ``self_intersections`` (pairs of the result),
        ``self_intersections_source`` (of the garment on the source), ``self_intersections_new`` (pairs of the
        result that count against the source: ``self_check.beyond_source``), ``layer_crossings`` (pairs with
        the layers below, both ways), ``min_body_distance`` (0 where it crosses the body), ``seam_vertices`` and
        ``seam_gap`` (``seam_gap``: the vertices that lay on another on the source, pieces not joined, and how far
        apart the result puts them) and ``seam_tolerance`` (the gap said to open a seam: ``SEAM_TOLERANCE`` of the
        garment's size).
    """
    V = np.asarray(V, dtype=np.float64)
    G = readings if readings is not None else readings_of(garment)
    if made_of(obstacle, target_body.V) and np.array_equal(obstacle.R.face_start, target_body.face_start) \
            and np.array_equal(obstacle.R.face_vertices, target_body.face_vertices):
        body = obstacle
    else:
        B = body_readings if body_readings is not None else readings_of(target_body)
        if not made_of(surface, target_body.V, target_body.F):
            surface = TriangleSurface(target_body.V, target_body.F)
        body = Obstacle(target_body.V, B, surface, edge_length(V, G))
    surface = body.surface

    def apart():
        # Measured whatever the crossings (it assumes none): where there are some, 0 is reported instead.
        return garment_distance(V, G, body), int((surface.signed_distance(V)[0] < 0).sum())

    def crossed():
        c = garment_crossings(V, G, body)
        pairs = pairs_in_full(V, G)
        source = pairs_in_full(garment.V, G) if source_pairs is None else source_pairs
        layer = 0
        for V_l, F_l in layers_below:
            cl = crossings(V, G, V_l, F_l)
            layer += cl["a_edge_pairs"] + cl["b_edge_pairs"]
        return c, pairs, source, int(beyond_source(pairs, G, garment.V, source).shape[0]), layer

    # The distances on one core, the crossings of the body, of itself and of the layers under it on another.
    (distance, inside), (c, pairs, source, new, layer) = together(apart, crossed)
    if c["a_edge_pairs"] + c["b_edge_pairs"] > 0:
        distance = 0.0
    seam_vertices, gap = seam_gap(garment.V, V)
    size = float(np.linalg.norm(np.ptp(np.asarray(garment.V, dtype=np.float64), axis=0))) if garment.n_vertices else 0.0
    return {"garment_edges_through_body": c["a_edges_through_b"],
            "body_edges_through_garment": c["b_edges_through_a"],
            "garment_edge_body_pairs": c["a_edge_pairs"], "body_edge_garment_pairs": c["b_edge_pairs"],
            "inside_vertices": inside, "self_intersections": int(pairs.shape[0]),
            "self_intersections_source": int(source.shape[0]), "self_intersections_new": new,
            "layer_crossings": int(layer), "min_body_distance": distance, "seam_vertices": seam_vertices,
            "seam_gap": gap, "seam_tolerance": SEAM_TOLERANCE * size}


def result_warnings(check: dict, name: str) -> list:
    """What a user must be told about a result (``check_result``'s figures), one sentence each, naming it."""
    out = []
    through = check["garment_edges_through_body"] + check["body_edges_through_garment"]
    if through:
        out.append(f"{name}: {check['garment_edges_through_body']} garment edges pass through the body and "
                   f"{check['body_edges_through_garment']} body edges through the garment, under some "
                   "triangulation of the faces: look at the result before using it")
    if check["inside_vertices"]:
        out.append(f"{name}: {check['inside_vertices']} garment vertices are inside the body")
    if check["self_intersections_new"]:
        out.append(f"{name}: the garment crosses itself at {check['self_intersections_new']} edge-triangle pairs "
                   f"its source does not ({check['self_intersections']} in all, "
                   f"{check['self_intersections_source']} on the source)")
    if check.get("layer_crossings"):
        out.append(f"{name}: {check['layer_crossings']} edge-triangle pairs cross the layers under it")
    if check.get("seam_gap", 0.0) > check.get("seam_tolerance", 0.0):
        out.append(f"{name}: {check['seam_vertices']} of the garment's vertices lie on another of its vertices (its "
                   f"pieces are not joined at their seams), and the result moves them apart by up to "
                   f"{check['seam_gap']:.3g}: join the pieces (Merge by Distance in Blender) before the transfer")
    return out
