"""Fitting: the source body fitted onto a target body of any mesh, units and axes (registration), so
that the pipeline sees one mesh in two shapes. ``alignment`` brings the target into the source's frame by a
similarity, ``shape_basis`` fits the source as a blend of its own shapes (shape keys, other bodies of its mesh,
MakeHuman's sliders from ``body_model``), ``nonrigid`` fits it closely (non-rigid ICP with an
as-rigid-as-possible regulariser, its first stages on the source decimated by ``coarse``), ``registration`` runs
the stages and checks the fit, ``cache`` keeps fits, and ``limbs`` finds a body's limbs from its shape and
measures how far two shapes of it differ in pose.
Built on ``geometry`` only.
"""

from .alignment import Similarity, align, units_scale
from .body_model import BodyModelBasis, makehuman_shape_basis
from .cache import cache_folder
from .limbs import Limbs, find_limbs, limb_angles
from .nonrigid import nonrigid_fit
from .registration import Registration, register
from .shape_basis import SHAPE_BOUNDS, fit_shape, shape_basis_from_bodies

__all__ = ["Registration", "register", "Similarity", "align", "units_scale", "nonrigid_fit", "SHAPE_BOUNDS",
           "shape_basis_from_bodies", "fit_shape", "BodyModelBasis", "makehuman_shape_basis", "cache_folder",
           "Limbs", "find_limbs", "limb_angles"]
