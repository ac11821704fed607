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
6. ``fix``: penetration removal against the target body (vertices).
7. ``crossings``: the final pass (``clearance.separate``): no garment edge through the body and no
   body edge through the garment, checked with exact predicates. Where it cannot clear them all and
   leaves a vertex inside the body, that vertex goes back where step 6 put it.

``surface`` skips 1, 2, 4 and 5: the garment follows the body alone (what Blender's Surface Deform
does); it is a baseline.
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from ..errors import Cancelled, MeshError, ModelError, PoseError, SettingError
from ..geometry import clearance, penetration
from ..geometry.binding import Binding, bind, carry
from ..geometry.embedding import body_scale, cloth_to_body, interpolation_matrix, unembed, unembed_with_matrix
from ..geometry.gradients import deformation_gradients
from ..geometry.mesh import Mesh, edge_length_and_degenerate, joined_pieces, require_same_topology
from ..geometry.poisson import JoinedPoissonSolver, PoissonSolver, anchor_weight_for, choose_method
from ..geometry.proximity import THREADS, TriangleSurface
from ..geometry.readings import Readings, readings_of
from ..geometry.self_check import pairs_in_full
from ..geometry.threads import ahead
from ..fitting.limbs import find_limbs, limb_angles
from ..learning.placement import anchor_offsets
from .field_mapping import model_field

METHODS = ("direct", "model", "surface")

#: Defaults as shares of the body scale (embedding.body_scale, about 1.1x the height of a body in
#: A-pose; unit-free: metres, decimetres or inches alike).
OFFSET_SHARE = 0.0025         # cloth thickness kept from the skin: ~5 mm on a 1.7 m body
STIFFNESS_SHARE = 0.04        # shape features longer than this follow the body: ~8 cm
FAR_SHARE = 0.2               # a garment whose median distance to the body exceeds this is misplaced
#: A garment with more than INSIDE_SHARE of its vertices deeper than INSIDE_DEPTH_SHARE of the body
#: scale (about 1 cm on a 1.7 m body) inside the source body is not dressed on it. Measured with
#: ``python -m lab.placement_study``: the dressed MakeHuman fixtures have at most 0.36% of their
#: vertices that deep (the demo garments none); moved 0.5 m up or turned 90 degrees about the vertical
#: axis, every MakeHuman garment (80 cases) and every turned demo garment (120) is refused, and 108 of
#: 120 demo garments moved up (tops floating above the shoulders and a few skirts around the chest
#: pass: they are not inside the body, and within FAR_SHARE of it).
INSIDE_DEPTH_SHARE = 0.005
INSIDE_SHARE = 0.01
#: The largest angle each part of a limb the garment lies on may point away from the source's
#: (``limbs.limb_angles``), by part. Measured with ``python -m lab.file_check --poses`` on MakeHuman
#: female_average with both arms turned down about the shoulders (four suits, the same mesh and re-meshed to
#: 47,500 triangles, registered): up to 25 degrees (measured 26.3 on the upper arm; 20 degrees: 21.1, 22.2
#: through a registration) every result is clean and MDC with the pass is 0.84 to 1.12 times the transfer's
#: without it, as on an unposed body; at 30 (measured 31.6) MDC is 1.7 to 3.8 times, and crossings are left on
#: one suit. Forearms: the demo mannequins' point 39 degrees from MakeHuman's (registered), and the suits
#: transferred onto the pear mannequin are clean with MDC no higher than without the pass. Legs turned outward
#: about the hips by 30 degrees: every suit clean, MDC at most 1.08x without the pass
#: (``lab.unseen_bodies.legs_apart``). Shapes of one pose differ by at most 4.6 degrees (the fixture bodies, the
#: heavy and past-the-pear ones).
POSE_LIMITS = {"upper arm": 28.0, "forearm": 40.0, "thigh": 30.0, "shin": 30.0}
#: The largest offset accepted, as a share of the body scale (about 10 cm on a 1.7 m body): cloth
#: thickness, not a way to move the garment.
MAX_OFFSET_SHARE = 0.05


def check_offset(offset, target_body: Mesh, what="offset") -> float | None:
    """The offset as a float, or None for the default; ValueError unless finite, >= 0 and at most
    MAX_OFFSET_SHARE of the target body's scale."""
    if offset is None:
        return None
    try:
        value = float(offset)
    except (TypeError, ValueError):
        raise SettingError(what, f"{offset!r} is not a number") from None
    if not np.isfinite(value) or value < 0:
        raise SettingError(what, f"{offset!r} must be a finite distance >= 0 (the cloth thickness kept "
                                 "from the body)")
    limit = MAX_OFFSET_SHARE * body_scale(target_body.V)
    if value > limit:
        raise SettingError(what, f"{value:.4g} is more than {MAX_OFFSET_SHARE:.0%} of the size of the body "
                                 f"{target_body.name} ({limit:.4g} in its units): it is the cloth "
                                 "thickness kept from the skin, not a way to move the garment")
    return value
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
    prepared : PreparedGarment
        What the transfer prepared (or was given): the garment's readings and its own self-intersections on the
        source, for checking the result as written (``result_check.check_result``).
    obstacle : Obstacle or None
        The target body as the crossing pass binned it (``obstacle.Obstacle``), when it ran.
    contact : tuple or None
        A pose fit's (``pose_fit.fit_to_pose``): the posed body's own contact, ``(contact (n,) bool, crossings
        int)`` as ``pose_fit.self_contact`` gives it, for counting the result as written (``posed_counts``).
    surface : TriangleSurface or None
        The target body's own triangles as the penetration fix searched them (its tree built), for a later count
        of the vertices inside the same body.
    """

    V: np.ndarray
    seconds: dict
    penetrating_vertices: int
    info: dict = field(default_factory=dict)
    prepared: "PreparedGarment | None" = field(default=None, repr=False)
    obstacle: object = field(default=None, repr=False)
    contact: object = field(default=None, repr=False)
    surface: object = field(default=None, repr=False)


@dataclass
class PreparedGarment:
    """Everything about a garment on the source body that does not depend on the target.

    Build it with ``prepare_garment`` and pass it to ``transfer_garment`` for every target.
    The garment's own facts (mean edge length, degenerate triangles, vertex graph) are computed
    here once and used by every stage. ``place``: each vertex's place (``mesh.vertex_places``) when some
    vertices lie on others (pieces not joined at their seams: solved, fixed and cleared as the joined garment),
    else None.
    """

    garment: Mesh
    source_body: Mesh
    embed_index: np.ndarray | None
    embed_weights: np.ndarray | None
    binding: Binding
    solver: PoissonSolver | None
    seconds: dict
    edge_length: float = 0.0
    degenerate: np.ndarray | None = None
    embed_matrix: object = None
    anchoring: str = "everywhere"
    place: np.ndarray | None = None
    _adjacency: object = field(default=None, repr=False)
    _readings: object = field(default=None, repr=False)
    _source_pairs: object = field(default=None, repr=False)
    _limbs: object = field(default=None, repr=False)
    _pieces: object = field(default=None, repr=False)
    _joined: object = field(default=None, repr=False)

    def adjacency(self):
        """The garment's (n,n) vertex adjacency (csr), built on first use (only a fix needs it)."""
        if self._adjacency is None:
            self._adjacency = penetration.vertex_adjacency(self.garment.n_vertices, self.garment.F)
        return self._adjacency

    def readings(self) -> Readings:
        """Every reading of the garment's polygons (``readings.readings_of``), made on first use."""
        if self._readings is None:
            self._readings = readings_of(self.garment)
        return self._readings

    def joined(self):
        """The garment with the vertices of each place made one (``place``: its pieces joined at their seams, in the
        order of their first vertices, with the garment's own polygons and triangulation), for the penetration fix
        and the crossing pass: ``(PreparedGarment of it, first)``, ``first`` the first vertex at each place (the
        joined garment is ``V[first]``; back, ``V_joined[place]``). None when no vertex lies on another."""
        if self.place is None:
            return None
        if self._joined is None:
            mesh, first = self._pieces
            b = self.binding
            binding = Binding(b.triangle[first], b.bary[first], b.local[first], b.distance[first])
            self._joined = (PreparedGarment(mesh, self.source_body, None, None, binding, None, {},
                                            edge_length=edge_length_and_degenerate(mesh.V, mesh.F)[0],
                                            anchoring=self.anchoring), first)
        return self._joined

    def covered(self):
        """(n,) bool: the source body's vertices the garment lies on (the corners of the triangles it is bound
        to)."""
        mask = np.zeros(self.source_body.n_vertices, bool)
        mask[self.source_body.F[self.binding.triangle]] = True
        return mask

    def limbs(self):
        """The source body's limb bands (``limbs.find_limbs``; None when none are found), found on first use."""
        if self._limbs is None:
            self._limbs = find_limbs(self.source_body.V, self.source_body.F) or False
        return self._limbs or None

    def source_pairs(self):
        """(k,2) the garment's own self-intersecting pairs on the source body, under every reading (the
        count a result is held to), found on first use."""
        if self._source_pairs is None:
            self._source_pairs = pairs_in_full(self.garment.V, self.readings())
        return self._source_pairs


def _check_placement(source_body: Mesh, garment: Mesh, surface: TriangleSurface, binding: Binding):
    """Refuse a garment that is not dressed on the source body: far from it, or deep inside it."""
    scale = body_scale(source_body.V)
    median = float(np.median(binding.distance))
    if median > FAR_SHARE * scale:
        raise MeshError(garment.name,
                        f"is far from the source body {source_body.name} (median distance "
                        f"{median:.3g}, body size {scale:.3g}): is it dressed on that body, "
                        "in the same units and space?")
    closest = np.einsum("pk,pkj->pj", binding.bary, source_body.V[source_body.F[binding.triangle]])
    normal = surface.normals_at(binding.triangle, binding.bary)
    side = np.einsum("ij,ij->i", garment.V - closest, normal)
    deep = float(np.mean((side < 0) & (binding.distance > INSIDE_DEPTH_SHARE * scale)))
    if deep > INSIDE_SHARE:
        raise MeshError(garment.name,
                        f"is not around the source body {source_body.name}: {deep:.1%} of its vertices "
                        f"are more than {INSIDE_DEPTH_SHARE * scale:.3g} inside it (a dressed garment has "
                        f"under {INSIDE_SHARE:.0%}). Is it moved, turned or dressed on another body?")


def anchor_weights(garment: Mesh, distance, scale, stiffness, anchoring="everywhere", contact=None,
                   edge_length=None):
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
    edge_length : float, optional
        The garment's mean edge length, when known.

    Returns
    -------
    w : float or (n,) float64
    """
    lam = anchor_weight_for(garment.V, garment.F, stiffness, edge_length)
    if anchoring == "everywhere":
        return lam
    if anchoring != "contact":
        raise ValueError(f"anchoring must be one of {', '.join(ANCHORINGS)}, got {anchoring!r}")
    contact = CONTACT_SHARE * scale if contact is None else float(contact)
    free = anchor_weight_for(garment.V, garment.F, FREE_SHARE * scale, edge_length)
    resting = np.clip(2.0 - np.asarray(distance, dtype=np.float64) / contact, 0.0, 1.0)
    return free + (lam - free) * resting


def prepare_garment(source_body: Mesh, garment: Mesh, *, interpolate=True, stiffness=None,
                    need_solver=True, anchoring="everywhere", contact=None, reused=True,
                    solver_method=None, energy="gradients") -> PreparedGarment:
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
    reused : bool
        Whether the garment goes to several targets: a factor then pays for itself; for one target a
        large garment is solved by multigrid (``poisson.choose_method``).
    solver_method : {"factor", "multigrid"}, optional
        The Poisson solver, instead of the choice by size and ``reused``.
    energy : {"gradients", "edges"}
        The Poisson solve's gradient term (``poisson.PoissonSolver``): the finite-element energy, or the
        paper's sum over edges.
    """
    if anchoring not in ANCHORINGS:
        raise ValueError(f"anchoring must be one of {', '.join(ANCHORINGS)}, got {anchoring!r}")
    seconds = {}
    t = time.perf_counter()
    scale = body_scale(source_body.V)
    length = stiffness if stiffness else STIFFNESS_SHARE * scale
    method = solver_method or choose_method(garment.n_vertices, reused)
    pieces = joined_pieces(garment)
    place = None if pieces is None else pieces[2]

    def garment_facts():
        h, degenerate = edge_length_and_degenerate(garment.V, garment.F)
        if degenerate.all():
            raise MeshError(garment.name, "every face has zero area")
        return h, degenerate

    def make_solver(distance, h, degenerate, with_adjacency=False):
        started = time.perf_counter()
        w = anchor_weights(garment, distance, scale, length, anchoring, contact, edge_length=h)
        if pieces is None:
            solver = PoissonSolver(garment.V, garment.F, w, triangle_weights=(~degenerate).astype(np.float64),
                                   method=method, energy=energy)
        else:
            # Pieces not joined at their seams: solved as the one surface they make (their seams kept closed).
            mesh, first, _ = pieces
            solver = JoinedPoissonSolver(PoissonSolver(mesh.V, mesh.F, w if np.ndim(w) == 0 else w[first],
                                                       triangle_weights=(~degenerate).astype(np.float64),
                                                       method=method, energy=energy), first, place)
        seconds["factor"] = time.perf_counter() - started
        # The penetration fix's vertex graph, while the main thread binds (otherwise built on first use).
        adjacency = penetration.vertex_adjacency(garment.n_vertices, garment.F) if with_adjacency else None
        return solver, adjacency

    def beside_binding():
        h, degenerate = garment_facts()
        return (h, degenerate, *make_solver(None, h, degenerate, with_adjacency=True))

    with ThreadPoolExecutor(1) as pool:
        # Anchors everywhere do not depend on the binding: the garment's own facts and the solver are
        # made on a thread while the garment is bound (mostly compiled code that releases the GIL).
        early = None
        if need_solver and anchoring == "everywhere" and THREADS > 1:
            early = pool.submit(beside_binding)
        else:
            h, degenerate = garment_facts()
        try:
            surface = TriangleSurface(source_body.V, source_body.F)
            binding = bind(garment.V, source_body.V, source_body.F, surface)
            _check_placement(source_body, garment, surface, binding)
        except Exception:
            if early is not None:
                early.result()  # a garment with no area is refused for that first
            raise
        seconds["bind"] = time.perf_counter() - t
        index = weights = matrix = None
        t = time.perf_counter()
        if interpolate:
            matrix = interpolation_matrix(source_body.F, source_body.n_vertices, binding.triangle, binding.bary,
                                          garment.F)
        else:
            index, weights = cloth_to_body(source_body.V, source_body.F, garment.V, garment.F, k=1)
        seconds["embed"] = time.perf_counter() - t
        solver = adjacency = None
        if early is not None:
            h, degenerate, solver, adjacency = early.result()
        elif need_solver:
            solver, adjacency = make_solver(binding.distance, h, degenerate)
    return PreparedGarment(garment, source_body, index, weights, binding, solver, seconds,
                           edge_length=h, degenerate=degenerate, embed_matrix=matrix, anchoring=anchoring,
                           place=place, _pieces=None if pieces is None else pieces[:2], _adjacency=adjacency)


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
        if getattr(model, "conditions_on_garment", False):
            model.check_source_body(source_body)
            return model.body_field(target, garment=garment, source_body=source_body, target_body=target_body)
        if target is None:
            raise ModelError(getattr(model, "name", "model"),
                             f"say which target to transfer to; the model knows {', '.join(model.targets)}")

        return model_field(model, target, source_body)
    raise ValueError(f"unknown method {method!r}; choose one of {', '.join(METHODS)}")


def _undo_pushes_inside(V, V_fixed, surface):
    """Where the crossings pass left a vertex inside the body (it can, when it cannot clear every crossing:
    a garment pressed through a fold of the body), the vertex goes back to where the penetration fix had it,
    outside. Returns (V, vertices inside after that, vertices put back)."""
    inside = surface.signed_distance(V)[0] < 0
    if not inside.any():
        return V, 0, 0
    V = V.copy()
    V[inside] = V_fixed[inside]
    left = int((surface.signed_distance(V[inside])[0] < 0).sum())
    return V, left, int(inside.sum())


def pass_inputs_ahead(prepared: PreparedGarment, body: Mesh):
    """What the crossing pass on ``body`` needs that the stages before it (the field, the solve, the penetration
    fix) do not touch, started on a free core meanwhile (``threads.ahead``): the garment's own self-intersections
    on the source (its readings' topology with them) and the body's readings. ``fit_to_body(..., early=)`` waits
    for it."""
    cloth = prepared if prepared.place is None else prepared.joined()[0]
    return ahead(lambda: (cloth.source_pairs(), readings_of(body)))


def fit_to_body(V, prepared: PreparedGarment, body: Mesh, offset, *, fix_penetration=True, resolve_crossings=True,
                source_V=None, info=None, seconds=None, step=None, early=None):
    """The last two stages on ``body`` as given (its own frame and faces): the penetration fix, then the crossing
    pass under every reading of the garment's and the body's polygons.

    Parameters
    ----------
    V : (n,3) float
        The garment, in ``body``'s frame.
    prepared : PreparedGarment
    body : Mesh
    offset : float
        In ``body``'s units.
    fix_penetration, resolve_crossings : bool
        As ``transfer_garment``'s.
    source_V : (n,3) float, optional
        The garment's source shape in ``body``'s frame (default: ``prepared.garment.V``, the same frame).
    info, seconds : dict, optional
        Added to (the fix's and the pass's figures; ``fix`` and ``crossings`` seconds).
    step : callable, optional
        ``step(fraction, stage)`` before each stage.
    early : threads.Ahead, optional
        ``pass_inputs_ahead(prepared, body)``, started earlier, waited for before the pass.

    Returns
    -------
    V : (n,3) float64
    inside : int
        Garment vertices inside ``body``.
    obstacle : Obstacle or None
        ``body`` as the crossing pass binned it (None when the pass did not run).
    surface : TriangleSurface
        ``body``'s own triangles as the fix searched them.
    """
    info = {} if info is None else info
    seconds = {} if seconds is None else seconds
    if prepared.place is not None:
        # Pieces not joined at their seams: fixed and cleared as the one surface they make (the solve made the
        # vertices of each place one), so that the seams stay closed.
        joined, first = prepared.joined()
        V, *rest = fit_to_body(np.asarray(V)[first], joined, body, offset, fix_penetration=fix_penetration,
                               resolve_crossings=resolve_crossings,
                               source_V=None if source_V is None else np.asarray(source_V)[first], info=info,
                               seconds=seconds, step=step, early=early)
        return (V[prepared.place], *rest)
    garment = prepared.garment
    if step is not None:
        step(0.8, "fix")
    t = time.perf_counter()
    surface = TriangleSurface(body.V, body.F)
    if fix_penetration:
        V, fix_info = penetration.fix_penetration(V, garment.F, surface, offset, edge_length=prepared.edge_length,
                                                  adjacency=prepared.adjacency)
        info.update(fix_info)
        inside = fix_info["inside_after"]
    else:
        inside = int((surface.signed_distance(V)[0] < 0).sum())
    seconds["fix"] = time.perf_counter() - t
    info["resolve_crossings"] = bool(fix_penetration and resolve_crossings)
    if not (fix_penetration and resolve_crossings):
        return V, inside, None, surface
    if step is not None:
        step(0.9, "crossings")
    t = time.perf_counter()
    if early is not None:
        early.result()
    V_fixed = V
    G = prepared.readings()
    obstacle = clearance.Obstacle(body.V, readings_of(body), surface, clearance.edge_length(V, G))
    V, sep_info = clearance.separate(V, G, body.V, obstacle, offset,
                                     source_V=garment.V if source_V is None else source_V,
                                     source_pairs=prepared.source_pairs)
    info.update(sep_info)
    if sep_info["moved_vertices"]:
        V, inside, info["crossings_pass_inside_undone"] = _undo_pushes_inside(V, V_fixed, surface)
        info["inside_after"] = inside
    seconds["crossings"] = time.perf_counter() - t
    return V, inside, obstacle, surface


def pose_check(source_body: Mesh, body_V, name, limbs=None, covered=None) -> dict:
    """The pose difference between the source body and another shape of its mesh (``limbs.limb_angles``),
    refused where a part of a limb the garment covers turns further than ``POSE_LIMITS`` allows.

    Parameters
    ----------
    source_body : Mesh
    body_V : (n,3) float
        The target (or the source fitted onto the target), in the source's frame.
    name : str
        The target's name, for the error.
    limbs : Limbs, optional
        The source's, if known.
    covered : (n,) bool, optional
        The source body's vertices the garment lies on (``PreparedGarment.covered()``): a part of a limb with none
        of them is not held to its limit (a skirt does not care where the arms point). Default: every part.

    Returns
    -------
    dict
        ``degrees`` and ``band`` of the part furthest over its limit, or under it, of those the garment covers
        (None when the source's limbs are not found or none is covered), and ``bands``: every part's angle.

    Raises
    ------
    MeshError
        Naming the target, the part of the limb, its angle and the limit.
    """
    limbs = find_limbs(source_body.V, source_body.F) if limbs is None else limbs
    d = limb_angles(source_body.V, source_body.F, body_V, limbs)
    held = [b for k, b in enumerate(limbs.names) if covered is None or covered[limbs.near[k]].any()
            or covered[limbs.far[k]].any()] if limbs is not None else []
    if d["degrees"] is None or not held:
        return {"degrees": None, "band": None, "bands": d["bands"]}
    over = {band: d["bands"][band] / POSE_LIMITS[band.split(" ", 1)[1]] for band in held}
    band = max(over, key=over.get)
    limit = POSE_LIMITS[band.split(" ", 1)[1]]
    if over[band] > 1.0:
        raise PoseError(name, f"is in another pose than the source body {source_body.name}: its {band} points "
                              f"{d['bands'][band]:.0f} degrees away from the source's (a transfer keeps the design "
                              f"up to {limit:.0f} for a{'n' if band.split(' ', 1)[1][0] in 'aeiou' else ''} "
                              f"{band.split(' ', 1)[1]})")
    return {"degrees": d["bands"][band], "band": band, "bands": d["bands"]}


def transfer_garment(source_body: Mesh, target_body: Mesh, garment: Mesh, *, method="direct",
                     model=None, target=None, offset=None, fix_penetration=True, interpolate=True,
                     stiffness=None, prepared: PreparedGarment | None = None, anchoring="everywhere",
                     progress=None, resolve_crossings=True, placement=None, check_pose=True):
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
    resolve_crossings : bool
        After the penetration fix, remove every edge-triangle crossing between garment and body
        and undo the self-intersections the source garment does not have by giving the cloth
        there its source shape (``clearance.separate``; only with ``fix_penetration``).
    placement : placement.PlacementModel, PlacementEnsemble or BlendedPlacement, or (M,3) array, optional
        Move the anchors from where the body carries the garment by a learned placement (or given
        offsets per source body triangle, in the triangle's frame on the target: ``placement.true_offsets``).
    check_pose : bool
        Refuse a target whose limbs point further from the source's than ``POSE_LIMITS`` allows
        (``pose_check``; the angle is ``info["limb_angles"]``).

    Returns
    -------
    TransferResult
    """
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; choose one of {', '.join(METHODS)}")
    require_same_topology(source_body, target_body)
    offset = check_offset(offset, target_body)

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
                                   need_solver=method != "surface", anchoring=anchoring, reused=False)
        seconds.update(prepared.seconds)
    elif prepared.garment is not garment or prepared.source_body is not source_body:
        raise ValueError("prepared was made for another garment or source body")
    early = pass_inputs_ahead(prepared, target_body) if fix_penetration and resolve_crossings else None
    pose = (pose_check(source_body, target_body.V, target_body.name, prepared.limbs(), prepared.covered())
            if check_pose else None)
    step(0.5, "bind")
    t = time.perf_counter()
    anchors = carry(prepared.binding, target_body.V, source_body.F)
    if placement is not None:

        anchors = anchors + anchor_offsets(placement, prepared.binding, source_body, target_body, garment, target)
    seconds["bind"] = seconds.get("bind", 0.0) + time.perf_counter() - t
    if method == "surface":
        V = anchors
    else:
        t = time.perf_counter()
        if prepared.embed_index is None:
            Q = unembed_with_matrix(B, source_body.F, prepared.embed_matrix)
        else:
            Q = unembed(B, prepared.embed_index, prepared.embed_weights)
        seconds["embed"] = seconds.get("embed", 0.0) + time.perf_counter() - t
        step(0.6, "solve")
        t = time.perf_counter()
        V = prepared.solver.solve(Q, anchors)
        seconds["solve"] = time.perf_counter() - t
    if offset is None:
        offset = OFFSET_SHARE * body_scale(target_body.V)
    info = {"method": method, "target": target, "offset": float(offset),
            "interpolate": bool(interpolate), "fix_penetration": bool(fix_penetration),
            "anchoring": prepared.anchoring, "placement": placement is not None}
    if pose is not None:
        info["limb_angles"] = pose
    if prepared.solver is not None:
        info["solver"] = prepared.solver.method
    V, inside, obstacle, surface = fit_to_body(V, prepared, target_body, offset, fix_penetration=fix_penetration,
                                               resolve_crossings=resolve_crossings, info=info, seconds=seconds,
                                               step=step, early=early)
    seconds["total"] = time.perf_counter() - t0
    step(1.0, "done")
    return TransferResult(V, seconds, inside, info, prepared, obstacle, surface=surface)

