"""How good a transfer is: design kept (MDC), no penetration, fit changed with the body, error."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..geometry.binding import bind, carry
from ..geometry.embedding import body_scale
from ..geometry.mesh import Mesh, discrete_curvature, edge_lengths_mean, require_same_topology
from ..geometry.penetration import penetration, vertex_adjacency
from ..geometry.proximity import TriangleSurface, one_mesh
from ..geometry.readings import readings_of
from .result_check import check_result


def mdc(V_a, V_b, F):
    """Mean discrete curvature difference (paper eq. 10): ``mean_s |r_A(s) - r_B(s)|``.

    Parameters
    ----------
    V_a, V_b : (n,3) float
        Two shapes of one mesh.
    F : (m,3) int

    Returns
    -------
    float
        0 for identical shapes; lower means the design is kept.
    """
    return float(np.mean(np.abs(discrete_curvature(V_a, F) - discrete_curvature(V_b, F))))


def smooth(V, F, length):
    """Low-pass filter: implicit uniform-Laplacian smoothing ``(I + t L) Vs = V``.

    ``t = (length / h)^2`` for mean edge length h, so features shorter than about ``length`` go.

    Parameters
    ----------
    V : (n,3) float
    F : (m,3) int
    length : float

    Returns
    -------
    Vs : (n,3) float64
    """
    A = vertex_adjacency(V.shape[0], F)
    L = sp.diags(np.asarray(A.sum(axis=1)).ravel()) - A
    t = (length / max(edge_lengths_mean(V, F), 1e-300)) ** 2
    K = (sp.identity(V.shape[0]) + t * L).tocsc()
    return spla.splu(K, permc_spec="COLAMD").solve(np.asarray(V, dtype=np.float64))


def surface_distance(V_a, F_a, V_b, F_b):
    """Symmetric mean surface distance: the mean distance from each mesh's vertices to the other surface,
    averaged over both directions (sliding along a surface costs nothing)."""
    d_ab = TriangleSurface(V_b, F_b).closest(V_a)[1]
    d_ba = TriangleSurface(V_a, F_a).closest(V_b)[1]
    return 0.5 * (float(d_ab.mean()) + float(d_ba.mean()))


def drape_error(V, F, V_ref, F_ref, length):
    """Surface distance between a result and a reference once both are low-pass filtered alike."""
    return surface_distance(smooth(V, F, length), F, smooth(V_ref, F_ref, length), F_ref)


def vertex_error(V, V_ref):
    """Mean and max per-vertex distance to a reference of the same topology."""
    d = np.linalg.norm(np.asarray(V) - np.asarray(V_ref), axis=1)
    return float(d.mean()), float(d.max())


def per_vertex_change(V_source, V_result):
    """(n,) distance each vertex moved: the heatmap of paper fig. 3."""
    return np.linalg.norm(np.asarray(V_result, dtype=np.float64) - np.asarray(V_source), axis=1)


def evaluate(source: Mesh, result: Mesh, target_body: Mesh, reference: Mesh | None = None,
             source_body: Mesh | None = None, smoothing=0.025, intersections=True, layers_below=(), target_cage=None):
    """All quality figures of a transferred garment.

    Parameters
    ----------
    source : Mesh
        The garment on the source body.
    result : Mesh
        The transferred garment (same topology as source).
    target_body : Mesh
    reference : Mesh, optional
        The garment simulated or fitted on the target body (same topology): gives drape and
        vertex errors.
    source_body : Mesh, optional
        Without a reference, the drape error is measured against the source garment carried
        onto the target body by the body alone (the body-driven fit).
    smoothing : float
        Low-pass length for the drape error, as a share of the target body scale (about 4.5 cm on
        a 1.7 m body).
    intersections : bool
        Add the exact intersection figures (``intersections.intersection_report``).
    layers_below : sequence of Mesh
        Garments worn under this one (for ``layer_crossings``).
    target_cage : Mesh, optional
        The mesh a subdivided ``target_body`` refines (``any_body.transfer_to_any_body``'s): the body fit is
        carried onto it, where it is the source body's mesh.

    Returns
    -------
    dict
        ``mdc``, ``penetration_ratio``, ``max_penetration_depth``, ``penetrating_vertices``,
        ``drape_error``, ``drape_error_source``, ``drape_error_relative``, ``drape_reference``
        and, with a reference, ``vertex_error_mean``, ``vertex_error_max``; with ``intersections``, the
        figures of ``result_check.check_result`` (under every triangulation of the result's and the body's
        faces): ``garment_edges_through_body``, ``body_edges_through_garment`` (edges crossing),
        ``garment_edge_body_pairs``, ``body_edge_garment_pairs`` (edge-triangle pairs), ``inside_vertices``,
        ``self_intersections`` (pairs, in the result), ``self_intersections_source`` (in the source garment),
        ``self_intersections_new`` (those counting against the source), ``layer_crossings`` and
        ``min_body_distance``.
    """
    require_same_topology(source, result)
    F = source.F
    out = {"vertices": source.n_vertices, "triangles": source.n_triangles,
           "mdc": mdc(source.V, result.V, F)}
    ratio, depth, inside = penetration(result.V, TriangleSurface(target_body.V, target_body.F))
    out.update(penetration_ratio=ratio, max_penetration_depth=depth,
               penetrating_vertices=int(inside.sum()))
    ref_V, ref_F, kind = None, None, None
    if reference is not None:
        require_same_topology(source, reference)
        ref_V, ref_F, kind = reference.V, F, "reference"
    elif source_body is not None:
        # A target of the source's mesh written with the other winding or triangulated (or a source so written)
        # is that mesh: only the vertices are carried (one_mesh).
        fit_on = target_body
        if not one_mesh(source_body, target_body):
            if target_cage is None or not one_mesh(source_body, target_cage):
                require_same_topology(source_body, target_body if target_cage is None else target_cage)
            fit_on = target_cage
        ref_V = carry(bind(source.V, source_body.V, source_body.F), fit_on.V, source_body.F)
        ref_F, kind = F, "body_fit"
    out["drape_reference"] = kind
    if ref_V is None:
        out.update(drape_error=None, drape_error_source=None, drape_error_relative=None)
    else:
        length = smoothing * body_scale(target_body.V)
        de = drape_error(result.V, F, ref_V, ref_F, length)
        de0 = drape_error(source.V, F, ref_V, ref_F, length)
        out.update(drape_error=de, drape_error_source=de0,
                   drape_error_relative=de / de0 if de0 > 0 else None)
    if intersections:
        out.update(check_result(source, result.V, target_body,
                                layers_below=[(m.V, readings_of(m)) for m in layers_below]))
    if reference is not None:
        out["vertex_error_mean"], out["vertex_error_max"] = vertex_error(result.V, reference.V)
    return out
