"""The whole transfer: a garment on the source body becomes the same garment on a target body.

Stages (timed one by one):

1. ``field``: a deformation gradient field on the source body's triangles: the body's own
   source-to-target gradients (``direct``), or the shared model's prediction for the target
   (``model``).
2. ``bind``: each garment vertex bound to its closest point on the source body and carried to the
   target body: where the garment must land (the anchors).
3. ``embed``: the field carried onto the garment's triangles: interpolated over the body surface
   at the bound points, or (the paper's ClothToBody) from the nearest body triangle.
4. ``factor``: the Poisson matrix of the garment, factored (once per garment; reused).
5. ``solve``: the garment rebuilt from its new gradients, placed by the anchors.
6. ``fix``: penetration removal against the target body.

``surface`` skips 1, 2, 4 and 5: the garment follows the body alone (what Blender's Surface Deform
does); it is a baseline.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from .binding import Binding, bind, carry
from .embedding import body_scale, cloth_to_body, unembed, unembed_interpolated
from .errors import Cancelled, MeshError, ModelError
from .gradients import deformation_gradients
from .mesh import Mesh, degenerate_triangles, require_same_topology
from . import penetration
from .poisson import PoissonSolver, anchor_weight_for
from .proximity import TriangleSurface

METHODS = ("direct", "model", "surface")

#: Defaults as shares of the body scale (embedding.body_scale, about 1.1x the height of a body in
#: A-pose; unit-free: metres, decimetres or inches alike).
OFFSET_SHARE = 0.0025         # cloth thickness kept from the skin: ~5 mm on a 1.7 m body
STIFFNESS_SHARE = 0.04        # shape features longer than this follow the body: ~8 cm
FAR_SHARE = 0.2               # a garment whose median distance to the body exceeds this is misplaced
CONTACT_SHARE = 0.012         # "contact" anchoring: closer than this rests on the body (~2 cm)
FREE_SHARE = 1.0              # ... and farther than twice that is placed by the field up to this length
ANCHORINGS = ("everywhere", "contact")


@dataclass
class TransferResult:
    """A transferred garment.

    Attributes
    ----------
    V : (n,3) float64
        Vertex positions on the target body, in the garment's vertex order.
    seconds : dict
        Seconds per stage and ``total``.
    penetrating_vertices : int
        Garment vertices inside the target body after the fix (or without it, with ``fix=False``).
    info : dict
        Method, settings and penetration-fix details.
    """

    V: np.ndarray
    seconds: dict
    penetrating_vertices: int
    info: dict = field(default_factory=dict)


@dataclass
class PreparedGarment:
    """Everything about a garment on the source body that does not depend on the target.

    Build it with ``prepare_garment`` and pass it to ``transfer_garment`` for every target.
    """

    garment: Mesh
    source_body: Mesh
    embed_index: np.ndarray | None
    embed_weights: np.ndarray | None
    binding: Binding
    solver: PoissonSolver | None
    seconds: dict
    anchoring: str = "everywhere"


def _check_placement(source_body: Mesh, garment: Mesh, distance):
    scale = body_scale(source_body.V)
    median = float(np.median(distance))
    if median > FAR_SHARE * scale:
        raise MeshError(garment.name,
                        f"is far from the source body {source_body.name} (median distance "
                        f"{median:.3g}, body size {scale:.3g}): is it dressed on that body, "
                        "in the same units and space?")


def anchor_weights(garment: Mesh, distance, scale, stiffness, anchoring="everywhere", contact=None):
    """Per-vertex weights of the Poisson solve's anchors.

    ``everywhere``: every vertex is tied weakly to where the body carries it (shape features longer
    than ``stiffness`` follow the body). ``contact``: only vertices resting on the body (closer than
    ``contact``) are tied so; from ``contact`` to twice that the tie fades to one that only decides
    features longer than the body itself, so a hanging skirt's shape is the field's, not the body's.

    Parameters
    ----------
    garment : Mesh
    distance : (n,) float
        Each vertex's distance from the source body.
    scale, stiffness : float
        The body scale and the stiffness length.
    anchoring : {"everywhere", "contact"}
    contact : float, optional
        Default ``CONTACT_SHARE * scale``.

    Returns
    -------
    w : float or (n,) float64
    """
    lam = anchor_weight_for(garment.V, garment.F, stiffness)
    if anchoring == "everywhere":
        return lam
    if anchoring != "contact":
        raise ValueError(f"anchoring must be one of {', '.join(ANCHORINGS)}, got {anchoring!r}")
    contact = CONTACT_SHARE * scale if contact is None else float(contact)
    free = anchor_weight_for(garment.V, garment.F, FREE_SHARE * scale)
    resting = np.clip(2.0 - np.asarray(distance, dtype=np.float64) / contact, 0.0, 1.0)
    return free + (lam - free) * resting


def prepare_garment(source_body: Mesh, garment: Mesh, *, interpolate=True, stiffness=None,
                    need_solver=True, anchoring="everywhere", contact=None) -> PreparedGarment:
    """The target-independent part of a transfer: embedding, binding, Poisson factor.

    Parameters
    ----------
    source_body : Mesh
    garment : Mesh
        Dressed on the source body (same space and units).
    interpolate : bool
        Interpolate the field over the body at each garment vertex's closest point (True), or
        take the body triangle nearest to each garment triangle (False, the paper).
    stiffness : float, optional
        Length above which the garment's shape follows the body (default 4% of the body scale,
        about 8 cm on a 1.7 m body).
    need_solver : bool
        False skips the factorisation (for the ``surface`` method).
    anchoring : {"everywhere", "contact"}
        Where the garment is tied to the body (``anchor_weights``).
    contact : float, optional
        For ``contact``: the distance under which the garment rests on the body.
    """
    if anchoring not in ANCHORINGS:
        raise ValueError(f"anchoring must be one of {', '.join(ANCHORINGS)}, got {anchoring!r}")
    seconds = {}
    t = time.perf_counter()
    if degenerate_triangles(garment.V, garment.F).all():
        raise MeshError(garment.name, "every face has zero area")
    binding = bind(garment.V, source_body.V, source_body.F)
    _check_placement(source_body, garment, binding.distance)
    seconds["bind"] = time.perf_counter() - t
    index = weights = None
    if not interpolate:
        t = time.perf_counter()
        index, weights = cloth_to_body(source_body.V, source_body.F, garment.V, garment.F, k=1)
        seconds["embed"] = time.perf_counter() - t
    solver = None
    if need_solver:
        t = time.perf_counter()
        scale = body_scale(source_body.V)
        length = stiffness if stiffness else STIFFNESS_SHARE * scale
        w = anchor_weights(garment, binding.distance, scale, length, anchoring, contact)
        solver = PoissonSolver(garment.V, garment.F, w)
        seconds["factor"] = time.perf_counter() - t
    return PreparedGarment(garment, source_body, index, weights, binding, solver, seconds, anchoring)


def body_field(source_body: Mesh, target_body: Mesh, method="direct", model=None, target=None,
               garment: Mesh | None = None):
    """The deformation gradient field on the source body's triangles for a method.

    A model with ``conditions_on_garment`` (``garment_model.GarmentFitModel``) predicts the field of
    ``garment`` itself, for any target body; the shared model gives one field per target label.

    Returns
    -------
    B : (M,3,3) float64
    """
    if method == "direct":
        return deformation_gradients(source_body.V, target_body.V, source_body.F)[0]
    if method == "model":
        if model is None:
            raise ModelError("model", "the model method needs a model file (--model)")
        model.check_source_body(source_body)
        if getattr(model, "conditions_on_garment", False):
            return model.body_field(target, garment=garment, source_body=source_body, target_body=target_body)
        if target is None:
            raise ModelError(getattr(model, "name", "model"),
                             f"say which target to transfer to; the model knows {', '.join(model.targets)}")
        return model.body_field(target)
    raise ValueError(f"unknown method {method!r}; choose one of {', '.join(METHODS)}")


def transfer_garment(source_body: Mesh, target_body: Mesh, garment: Mesh, *, method="direct",
                     model=None, target=None, offset=None, fix_penetration=True, interpolate=True,
                     stiffness=None, prepared: PreparedGarment | None = None, anchoring="everywhere",
                     progress=None):
    """Transfer ``garment`` from ``source_body`` to ``target_body``.

    Parameters
    ----------
    source_body, target_body : Mesh
        One body mesh in two shapes (same vertex order and faces).
    garment : Mesh
        The garment dressed on the source body.
    method : {"direct", "model", "surface"}
    model : SharedDeformationModel, optional
        For ``method="model"``, with ``target`` one of ``model.targets``.
    offset : float, optional
        Smallest distance kept from the target body (default 0.25% of its scale, about 5 mm on a 1.7 m body).
    fix_penetration : bool
    interpolate : bool
        Blend nearby body triangles when carrying the field to the garment.
    stiffness : float, optional
        See ``prepare_garment``.
    prepared : PreparedGarment, optional
        Reuse the embedding, binding and factor of an earlier call for this garment (its anchoring
        is used).
    anchoring : {"everywhere", "contact"}
        See ``prepare_garment``: ``contact`` lets the field shape what does not rest on the body.
    progress : callable, optional
        ``progress(fraction, stage)``; returning True cancels (raises Cancelled).

    Returns
    -------
    TransferResult
    """
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; choose one of {', '.join(METHODS)}")
    require_same_topology(source_body, target_body)

    def step(fraction, stage):
        if progress is not None and progress(fraction, stage):
            raise Cancelled(f"transfer of {garment.name} cancelled during {stage}")

    t0 = time.perf_counter()
    seconds = {}
    step(0.0, "field")
    if method != "surface":
        t = time.perf_counter()
        B = body_field(source_body, target_body, method, model, target, garment)
        seconds["field"] = time.perf_counter() - t
    step(0.15, "prepare")
    if prepared is None:
        prepared = prepare_garment(source_body, garment, interpolate=interpolate, stiffness=stiffness,
                                   need_solver=method != "surface", anchoring=anchoring)
        seconds.update(prepared.seconds)
    elif prepared.garment is not garment or prepared.source_body is not source_body:
        raise ValueError("prepared was made for another garment or source body")
    step(0.5, "bind")
    t = time.perf_counter()
    anchors = carry(prepared.binding, target_body.V, source_body.F)
    seconds["bind"] = seconds.get("bind", 0.0) + time.perf_counter() - t
    if method == "surface":
        V = anchors
    else:
        t = time.perf_counter()
        if prepared.embed_index is None:
            b = prepared.binding
            Q = unembed_interpolated(B, source_body.F, source_body.n_vertices, b.triangle, b.bary, garment.F)
        else:
            Q = unembed(B, prepared.embed_index, prepared.embed_weights)
        seconds["embed"] = seconds.get("embed", 0.0) + time.perf_counter() - t
        step(0.6, "solve")
        t = time.perf_counter()
        V = prepared.solver.solve(Q, anchors)
        seconds["solve"] = time.perf_counter() - t
    step(0.8, "fix")
    t = time.perf_counter()
    surface = TriangleSurface(target_body.V, target_body.F)
    if offset is None:
        offset = OFFSET_SHARE * body_scale(target_body.V)
    info = {"method": method, "target": target, "offset": float(offset),
            "interpolate": bool(interpolate), "fix_penetration": bool(fix_penetration),
            "anchoring": prepared.anchoring}
    if fix_penetration:
        V, fix_info = penetration.fix_penetration(V, garment.F, surface, offset)
        info.update(fix_info)
        inside = fix_info["inside_after"]
    else:
        inside = int((surface.signed_distance(V)[0] < 0).sum())
    seconds["fix"] = time.perf_counter() - t
    seconds["total"] = time.perf_counter() - t0
    step(1.0, "done")
    return TransferResult(V, seconds, inside, info)

