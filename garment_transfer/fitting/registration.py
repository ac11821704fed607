"""Registration: the source body mesh fitted onto a target body of any mesh, units and axes.

The rest of the pipeline needs the source and target bodies as one mesh in two shapes. A customer's
body is often another mesh (a scan, another character base) in other units and axes. Registration
produces the source body in the target's shape, with the source's vertex order and faces, so that the
``direct`` and ``model`` methods run unchanged.

Stages:

1. **Alignment** (``align``): the target is brought into the source's frame by a similarity
   ``x = s R p + t``. The scale is a units factor: the ratio of the two surfaces' RMS radii, snapped
   to a known unit ratio (10^k, inches, feet) when it is near one, so that a shorter person stays
   shorter. The rotation is chosen among the principal-axis frames (4 sign choices) and the 24
   axis-aligned rotations, each refined by trimmed rigid ICP; the one with the smallest two-way
   distance wins.
2. **Global similarity** of the source onto the target: the scale and the placement along the long
   axis from the two heights (a taller or shorter person; not from closest points, which shrink a
   thinner body and move a wider one), the rotation and the rest from closest points both ways.
   Then **landmarks** from the shapes (the ends of the limbs and the head) where they are far from
   their match: a limb held at another angle.
   With a **shape basis** (``shape_basis``: deltas of the source body, such as its shape keys), the
   source is first fitted as a blend of them with a similarity (``fit_shape``: closest points both
   ways, bounded ridge least squares of the weights) and the stages below start from the blend, when
   it explains at least half of the misfit. A body model's sliders (``body_model=True``, e.g.
   MakeHuman's targets from ``body_model.makehuman_shape_basis``) are fitted with a sparse (L1) prior
   and the size from the model instead.
3. **Non-rigid ICP** with an as-rigid-as-possible regulariser (Sorkine & Alexa 2007) on the source
   graph, its weight annealed from stiff to soft. Data terms both ways: every source vertex towards
   its closest target point, and target points towards their closest point on the current fit (this
   keeps limbs from collapsing onto the torso); pairs whose normals disagree or that lie far apart
   are dropped. In the soft stages a weak pull holds each vertex at its height along the body's long
   axis, sliding along the surface (a body grows and thins across that axis). Each step solves one
   sparse system (vertex count squared, three right-hand sides). Coarse to fine (``nonrigid.LEVELS``):
   the stiff stages on the source decimated to 2,000 triangles, the soft ones on 6,000, the last two on
   the whole source, each level carried from the one before (``coarse``).
   Then the **hands and feet** (found from the shape as the ends of the body) are fitted each as a
   whole, by a similarity (point-to-plane ICP both ways), and blended into the fit: between body
   shapes they change by a similarity, which the ARAP fit (keeping their size) lets slide.
4. **Quality**: surface distance both ways (mean, 95th percentile, max) and the share of triangles
   that flipped or stretched beyond reason. A fit beyond the limits is refused with an error that
   names the figure (another pose, a partial or non-human mesh).

Results are cached per (source, target) pair in ``cache_folder()``: ``$GARMENT_TRANSFER_CACHE``, or
``$XDG_CACHE_HOME/garment_transfer/registration`` (``~/.cache/...``); ``GARMENT_TRANSFER_CACHE=off``
or ``cache=False`` turns it off. Cache files are ``.npz`` read with ``allow_pickle=False``.
"""

from __future__ import annotations

import hashlib
import logging
import time
from dataclasses import dataclass, field

import numpy as np

from ..errors import MeshError, RegistrationError
from ..geometry.mesh import Mesh, triangle_normals
from ..geometry.proximity import TriangleSurface, facing_outward
from .alignment import ASPECT_FACTOR, Similarity, align, closest_points, surface_samples
from .cache import cache_folder, cache_key, load_cached, save_cached
from .nonrigid import LEVELS, global_similarity, nonrigid_fit
from .shape_basis import (
    SHAPE_BOUNDS,
    SHAPE_ITERATIONS,
    SHAPE_MIN_EXPLAINED,
    SHAPE_MODEL_ITERATIONS,
    SHAPE_REFIT_ITERATIONS,
    SHAPE_REFIT_SHARE,
    SHAPE_RIDGE,
    SHAPE_SAMPLES,
    SHAPE_SPARSITY,
    check_shape_basis,
    fit_shape,
    weight_bounds,
)

log = logging.getLogger(__name__)


#: Bumped whenever the algorithm or its defaults change, so old cache entries are not reused.
ALGORITHM_VERSION = 12

#: Limits of an acceptable fit, as shares of the target's height (a 1.7 m body: 1% = 17 mm).
#: Measured fits of MakeHuman bodies onto each other and onto the procedural mannequins stay below
#: a third of these (docs/registration.md).
LIMITS = {
    "p95": 0.012,          # 95th percentile of the distance, either way
    "max": 0.06,           # largest distance, either way
    "distorted": 0.02,     # share of source triangles flipped or stretched more than 4x
}

#: Points of each surface at which the fit's distances are measured.
QUALITY_SAMPLES = 20000


@dataclass
class Registration:
    """The source body fitted onto a target body.

    Attributes
    ----------
    V : (n,3) float64
        The fitted body: the source's vertex order and faces, the target's shape, in the target's
        frame and units.
    V_source_frame : (n,3) float64
        The same in the source's frame and units (the alignment's: ``placed``).
    alignment : Similarity
        Target frame to source frame.
    quality : dict
        Surface distances both ways (``to_target_*``, ``from_target_*``: mean, p95, max, in the
        target's units, and ``*_share`` of its height) and ``distorted`` (share of triangles).
    seconds : dict
        Per stage.
    cached : bool
        Read from the cache.
    shape_weights : (k,) float64 or None
        The weights of the shape basis fitted before the non-rigid stages (None without a basis).
    """

    V: np.ndarray
    V_source_frame: np.ndarray
    alignment: Similarity
    quality: dict
    seconds: dict = field(default_factory=dict)
    cached: bool = False
    shape_weights: np.ndarray | None = None

    def body(self, source: Mesh, name=None) -> Mesh:
        """The fitted body as a Mesh in the target's frame (the source's faces)."""
        return source.with_vertices(self.V, name=name or f"{source.name}_registered")

    def cache_entry(self) -> tuple[dict, dict]:
        """``(arrays, meta)`` as the cache keeps them (``cache.save_cached``)."""
        arrays = {"V": self.V, "V_source_frame": self.V_source_frame}
        if self.shape_weights is not None:
            arrays["shape_weights"] = np.asarray(self.shape_weights)
        return arrays, {"alignment": self.alignment.as_dict(), "quality": self.quality, "seconds": self.seconds}

    @classmethod
    def from_cache(cls, arrays: dict, meta: dict, n_vertices: int):
        """The registration a cache entry holds, or None when it is not one of ``n_vertices``."""
        V = arrays.get("V")
        if V is None or V.shape != (n_vertices, 3) or "V_source_frame" not in arrays:
            return None
        a = meta["alignment"]
        alignment = Similarity(a["scale"], np.asarray(a["rotation"]), np.asarray(a["translation"]))
        return cls(V, arrays["V_source_frame"], alignment, meta["quality"], meta.get("seconds", {}), cached=True,
                   shape_weights=arrays.get("shape_weights"))

    def summary(self) -> dict:
        """Plain numbers for JSON output."""
        out = {"quality": {k: float(v) for k, v in self.quality.items()},
               "alignment": self.alignment.as_dict(),
               "seconds": {k: float(v) for k, v in self.seconds.items()},
               "cached": bool(self.cached)}
        if self.shape_weights is not None:
            out["shape_weights"] = [float(v) for v in self.shape_weights]
        return out


# --- quality ----------------------------------------------------------------------------------

def fit_quality(X, F, source_X0, target_V, target_F, X_source_frame=None, aligned=None):
    """Surface distance both ways and distortion of a fit.

    Parameters
    ----------
    X : (n,3) float
        The fitted source body (same frame as the target).
    F : (m,3) int
        Source triangles.
    source_X0 : (n,3) float
        The source body, for the distortion figure.
    target_V, target_F : the target surface.
    X_source_frame : (n,3) float, optional
        The fit in the source's frame (default X): normals are compared there.
    aligned : tuple, optional
        ``(surface, scale)``: the target already built in the frame of ``X_source_frame`` (a
        TriangleSurface) and the scale of that frame to the target's (the alignment's). The distances
        are then measured there, with its search tree, and divided by the scale: the same points
        (area-uniform samples do not depend on a similarity), the same distances.

    Returns
    -------
    dict
        ``to_target_mean/p95/max`` (points of the fit to the target surface), ``from_target_mean/p95/max``
        (points of the target to the fit; both over area-uniform points), each also as ``*_share``
        of the target's height, and
        ``distorted`` (share of triangles flipped or with an area changed more than 4x beyond the
        overall change).
    """
    height = float(np.ptp(np.asarray(target_V), axis=0).max())
    # Area-uniform points: a surface distance, not a vertex one (a body dense in the fingers and
    # face would otherwise be judged by them).
    if aligned is None:
        target, Y, scale = TriangleSurface(target_V, target_F), X, 1.0
    else:
        (target, scale), Y = aligned, X_source_frame
    d1 = closest_points(target, surface_samples(Y, F, QUALITY_SAMPLES, seed=3)[0])[1] / scale
    d2 = closest_points(TriangleSurface(Y, F), surface_samples(target.V, target.F, QUALITY_SAMPLES, seed=4)[0])[1]
    d2 = d2 / scale
    q = {}
    for name, d in (("to_target", d1), ("from_target", d2)):
        for stat, v in (("mean", d.mean()), ("p95", np.quantile(d, 0.95)), ("max", d.max())):
            q[f"{name}_{stat}"] = float(v)
            q[f"{name}_{stat}_share"] = float(v / height)
    N0, a0 = triangle_normals(source_X0, F)
    N1, a1 = triangle_normals(X if X_source_frame is None else X_source_frame, F)
    ratio = (a1 / max(a1.sum(), 1e-300)) / np.maximum(a0 / max(a0.sum(), 1e-300), 1e-300)
    flipped = np.einsum("ij,ij->i", N0, N1) < 0.0
    stretched = (ratio > 4.0) | (ratio < 0.25)
    q["distorted"] = float((flipped | stretched).mean())
    q["height"] = height
    return q


def check_quality(quality, source_name, target_name, limits=None):
    """Raise RegistrationError naming the first figure beyond its limit."""
    limits = dict(LIMITS, **(limits or {}))
    hint = (f"is {target_name} a whole person in the same pose as {source_name} "
            "(arms, legs), in one piece?")
    for way, text in (("from_target", f"from {target_name} to the fitted body"),
                      ("to_target", f"from the fitted body to {target_name}")):
        for stat, label in (("p95", "95th percentile of the distance"), ("max", "largest distance")):
            share = quality[f"{way}_{stat}_share"]
            if share > limits[stat]:
                raise RegistrationError(
                    target_name, f"registration failed: the {label} {text} is "
                                 f"{quality[f'{way}_{stat}']:.4g} ({share:.2%} of the height; the limit "
                                 f"is {limits[stat]:.2%}): {hint}")
    if quality["distorted"] > limits["distorted"]:
        raise RegistrationError(
            target_name, f"registration failed: {quality['distorted']:.1%} of the fitted body's "
                         f"triangles are flipped or stretched more than 4x (the limit is "
                         f"{limits['distorted']:.1%}): {hint}")


def placed(alignment: Similarity, Xs, similarity):
    """The alignment with the global fit's placement, and the fit in its frame.

    ``align`` places the target by samples of both bodies (about their spacing); the global fit then
    places the source on it against the exact surfaces (``nonrigid.global_similarity``: its rotation and
    translation, the scale being the heights' ratio). Taking that rotation and translation into the
    alignment leaves the fit in the target's frame as it is, and gives the alignment the precision the
    refinement of ``align`` would (a model's field is turned by its rotation:
    ``pipeline.field_mapping``).

    Parameters
    ----------
    alignment : Similarity
        Target frame to source frame.
    Xs : (n,3) float
        The fit in that source frame.
    similarity : tuple
        ``(scale, R (3,3), t (3,))`` of the global fit, in that frame.

    Returns
    -------
    alignment : Similarity
    Xs : (n,3) float64
    """
    _, R, t = similarity
    moved = Similarity(alignment.scale, R.T @ alignment.R, R.T @ (alignment.t - t))
    return moved, (np.asarray(Xs, dtype=np.float64) - t) @ R


def check_aspect(info, source_name, target_name):
    """Refuse a target whose principal shape is unlike the source's (a sphere, a box, a head)."""
    a, b = info["aspect_source"], info["aspect_target"]
    if max(a / b, b / a) > ASPECT_FACTOR:
        raise RegistrationError(
            target_name, f"registration refused: its principal aspect ratio (longest to second axis) "
                         f"is {b:.2f} but {source_name}'s is {a:.2f} (factor over {ASPECT_FACTOR}): "
                         f"it does not look like a person in the source's pose")


# --- the whole stage --------------------------------------------------------------------------

def register(source: Mesh, target: Mesh, *, cache=True, check=True, limits=None, progress=None,
             levels=LEVELS, shape_basis=None, shape_bounds=SHAPE_BOUNDS, body_model=False) -> Registration:
    """Fit the source body onto the target body (any mesh, units and axes; a similar pose).

    Parameters
    ----------
    source : Mesh
        The source body (the garment's body).
    target : Mesh
        Any body mesh of a person in a similar pose.
    cache : bool or str
        True: the default cache folder (``cache_folder()``); a path: that folder; False: no cache.
    check : bool
        Refuse a failed fit (RegistrationError). False returns it with its figures.
    limits : dict, optional
        Overrides of ``LIMITS``.
    progress : callable, optional
        ``progress(fraction)``; returning True cancels.
    levels : sequence of (int or None, sequence of (alpha, steps))
        The non-rigid stages, coarse to fine (``nonrigid.LEVELS``).
    shape_basis : (k,n,3) float, optional
        Shape deltas of the source body (its vertex order, its frame and units): for example its
        shape keys relative to the basis shape, or other bodies of its mesh less the source
        (``shape_basis_from_bodies``). After the alignment the weights of this linear shape space
        are fitted to the target with a similarity (``fit_shape``), and the non-rigid stages start
        from the blended body: where the space holds the target's kind of body, it carries the
        correspondence that the surfaces alone do not give (along the limbs, around the torso).
    shape_bounds : (2,) or (k,2) float
        Bounds of the weights (1 = one delta's worth); ``SHAPE_BOUNDS`` by default.
    body_model : bool
        The basis is a body model's sliders (``body_model.makehuman_shape_basis``): fitted with the
        sparse prior (``SHAPE_SPARSITY``) and the size from the model (``rigid``), see ``fit_shape``.

    Returns
    -------
    Registration

    Raises
    ------
    RegistrationError
        The fit failed; the message names the figure and its limit.
    ValueError
        A shape basis or bounds of the wrong shape, or not finite (the message says which).
    """
    for role, m in (("source body", source), ("target body", target)):
        if m.n_triangles < 4:
            raise MeshError(m.name, f"the {role} has {m.n_triangles} triangles; a body is needed")
    # The fit compares normals: a body written with the other winding (its faces pointing inward) is fitted
    # as the same body facing outward, which is decided by the sign of the volume it encloses.
    source, target = facing_outward(source), facing_outward(target)
    settings = {"levels": [[faces, [list(s) for s in stages]] for faces, stages in levels]}
    if shape_basis is not None:
        shape_basis = check_shape_basis(shape_basis, source.n_vertices)
        lo, hi = weight_bounds(shape_bounds, shape_basis.shape[0])
        # Only with a basis: the key of a registration without one is unchanged.
        settings["shape_basis"] = {"sha256": hashlib.sha256(np.ascontiguousarray(shape_basis).tobytes()).hexdigest(),
                                   "shape": list(shape_basis.shape), "low": lo.tolist(), "high": hi.tolist(),
                                   "ridge": SHAPE_RIDGE, "iterations": SHAPE_ITERATIONS,
                                   "min_explained": SHAPE_MIN_EXPLAINED, "samples": SHAPE_SAMPLES}
        if body_model:
            settings["shape_basis"].update({"body_model": True, "sparsity": SHAPE_SPARSITY,
                                            "iterations": SHAPE_MODEL_ITERATIONS,
                                            "refit": [SHAPE_REFIT_SHARE, SHAPE_REFIT_ITERATIONS]})
    folder = cache_folder() if cache is True else (cache or None)
    key = cache_key(source, target, settings, ALGORITHM_VERSION) if folder else None
    entry = load_cached(folder, key) if folder else None
    if entry is not None:
        hit = Registration.from_cache(*entry, source.n_vertices)
        if hit is not None:
            if check:
                check_quality(hit.quality, source.name, target.name, limits)
            warn_facing(hit.quality, source.name, target.name)
            return hit

    seconds = {}
    t = time.perf_counter()
    # The global fit of the non-rigid stage refines the pose against the surfaces, with the scale.
    alignment, info = align(source, target, refine=False)
    check_aspect(info, source.name, target.name)
    seconds["align"] = time.perf_counter() - t
    t = time.perf_counter()
    T = alignment.apply(target.V)
    # One target surface (its search tree, its normals) for the shape fit and the non-rigid fit.
    surface = TriangleSurface(T, target.F)
    start, weights, similarity = source.V, None, None
    if shape_basis is not None:
        weights, start, shape_info = fit_shape(source.V, source.F, shape_basis, T, target.F,
                                               bounds=shape_bounds, surface=surface,
                                               sparsity=SHAPE_SPARSITY if body_model else None,
                                               rigid=bool(body_model),
                                               iterations=SHAPE_MODEL_ITERATIONS if body_model else SHAPE_ITERATIONS)
        if not shape_info["used"]:
            # The non-rigid fit starts from the source itself: the shape fit's first step was its global fit.
            similarity = shape_info.get("similarity")
        seconds["shape"] = time.perf_counter() - t
        t = time.perf_counter()
    if similarity is None:
        similarity = global_similarity(start, source.F, surface,
                                       surface_samples(T, target.F, min(start.shape[0], 8000), seed=0)[0])
    Xs = nonrigid_fit(start, source.F, T, target.F, levels=levels, progress=progress, surface=surface,
                      start_similarity=similarity)
    seconds["fit"] = time.perf_counter() - t
    t = time.perf_counter()
    V = alignment.inverse().apply(Xs)
    quality = fit_quality(V, source.F, source.V, target.V, target.F, X_source_frame=Xs,
                          aligned=(surface, alignment.scale))
    alignment, Xs = placed(alignment, Xs, similarity)
    quality.update({k: float(v) for k, v in info.items() if k != "snapped"})
    quality["units_snapped"] = float(info["snapped"])
    if shape_basis is not None:
        quality["shape_explained"] = shape_info["explained"]
        quality["shape_used"] = float(shape_info["used"])
    seconds["quality"] = time.perf_counter() - t
    seconds["total"] = sum(seconds.values())
    reg = Registration(V, Xs, alignment, quality, seconds, shape_weights=weights)
    log.info("registered %s onto %s in %.2f s: %s", source.name, target.name, seconds["total"], quality)
    if check:
        check_quality(quality, source.name, target.name, limits)
    warn_facing(quality, source.name, target.name)
    if folder:
        save_cached(folder, key, *reg.cache_entry())
    return reg


def warn_facing(quality, source_name, target_name):
    """Say when the toes could not tell which way the bodies face (``alignment.toe_shift``): the closest pose
    was kept, and a body turned front to back fits about as closely."""
    if "toes_source" not in quality:
        log.warning("%s: no feet found on it or on %s to tell which way it faces; the closest fit was kept: check "
                    "that the result is not back to front", target_name, source_name)
