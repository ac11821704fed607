"""Transfer onto any target body: the source body registered onto it first when it is another mesh."""

from __future__ import annotations

import time

from ..fitting.registration import Registration, register
from ..fitting.shape_basis import SHAPE_BOUNDS
from ..geometry import penetration
from ..geometry.embedding import body_scale
from ..geometry.mesh import Mesh
from ..geometry.proximity import TriangleSurface, as_same_mesh
from .transfer import OFFSET_SHARE, transfer_garment


def transfer_to_any_body(source_body: Mesh, target_body: Mesh, garment: Mesh, *, cache=True,
                         limits=None, registration: Registration | None = None, progress=None,
                         shape_basis=None, shape_bounds=SHAPE_BOUNDS, body_model=False, **options):
    """``transfer_garment`` onto any target body: registered first when it is another mesh.

    The garment is transferred in the source's frame onto the fitted body (so the ``model`` method
    sees the frame and units it was trained in), kept out of the real target surface, and taken to
    the target's frame.

    Parameters
    ----------
    source_body, target_body, garment : Mesh
    cache : bool or str
        See ``register``.
    limits : dict, optional
        See ``register``.
    registration : Registration, optional
        A registration of these two bodies made earlier (skips ``register``).
    progress : callable, optional
        ``progress(fraction, stage)``; returning True cancels.
    shape_basis : (k,n,3) float, optional
        See ``register`` (used only when the target is another mesh).
    shape_bounds : (2,) or (k,2) float
        See ``register``.
    body_model : bool
        See ``register``.
    **options
        Passed to ``transfer_garment`` (method, model, target, offset, fix_penetration, ...).

    Returns
    -------
    result : TransferResult
        In the target's frame; ``info["registration"]`` holds the fit's figures when one was made.
    registration : Registration or None
        None when the two bodies are one mesh (also when the target is the source's mesh with every face
        turned the other way round, an OBJ of the other winding: ``proximity.as_same_mesh``;
        ``info["target_faces_turned"]`` then says so).
    """
    same = as_same_mesh(source_body, target_body)
    if same is not None:
        result = transfer_garment(source_body, same, garment, progress=progress, **options)
        if same is not target_body:
            result.info["target_faces_turned"] = True
        return result, None

    def sub(lo, hi):
        if progress is None:
            return None
        return lambda f, *stage: progress(lo + (hi - lo) * f, *(stage or ("register",)))

    reg = registration or register(source_body, target_body, cache=cache, limits=limits,
                                   progress=sub(0.0, 0.6), shape_basis=shape_basis,
                                   shape_bounds=shape_bounds, body_model=body_model)
    options = dict(options)
    if options.get("offset") is not None:
        options["offset"] = options["offset"] * reg.alignment.scale
    fitted = source_body.with_vertices(reg.V_source_frame,
                                       name=f"{source_body.name} fitted to {target_body.name}")
    result = transfer_garment(source_body, fitted, garment, progress=sub(0.6, 0.95), **options)
    t = time.perf_counter()
    # The fitted body follows the target within the fit's residual; the cloth must clear the real one.
    surface = TriangleSurface(reg.alignment.apply(target_body.V), target_body.F)
    offset = options.get("offset")
    if offset is None:
        offset = OFFSET_SHARE * body_scale(surface.V)
    if options.get("fix_penetration", True):
        V, fix = penetration.fix_penetration(result.V, garment.F, surface, offset)
        result.info["target_fix"] = fix
        inside = fix["inside_after"]
    else:
        V = result.V
        inside = int((surface.signed_distance(V)[0] < 0).sum())
    result.V = reg.alignment.inverse().apply(V)
    result.penetrating_vertices = inside
    result.info["registration"] = reg.summary()
    result.info["offset"] = float(offset / reg.alignment.scale)
    result.seconds["register"] = float(reg.seconds.get("total", 0.0)) if not reg.cached else 0.0
    result.seconds["target_fix"] = time.perf_counter() - t
    result.seconds["total"] += result.seconds["register"] + result.seconds["target_fix"]
    return result, reg
