"""Errors raised by the core. Each names the object or file it is about."""


class GarmentTransferError(Exception):
    """Base class: an expected failure with a message meant for the user."""


class NamedError(GarmentTransferError, ValueError):
    """An error about one named thing (file, object, model): ``"<name>: <problem>"``."""

    def __init__(self, name, problem):
        self.name = name
        self.problem = problem
        super().__init__(f"{name}: {problem}")


class MeshError(NamedError):
    """A mesh (file or object) that cannot be used as given."""


class TopologyMismatchError(MeshError):
    """Two meshes that must share vertex order and faces do not."""


class PoseError(MeshError):
    """A target body standing in another pose than the source, beyond what a transfer carries: ``difference``
    (the figure) and ``remedy`` (what to do), ``"<name>: <difference>. <remedy>"``."""

    REMEDY = ("Pose the two bodies alike first, or give both a skeleton with the same bones to pose the source into "
              "the target's rest pose (in Blender an armature on each body; on the command line --skeleton, "
              "--source-joints, --source-weights and --target-joints)")

    def __init__(self, name, difference, remedy=REMEDY):
        self.difference = difference
        self.remedy = remedy
        super().__init__(name, f"{difference}. {remedy}")


class ModelError(NamedError):
    """A model file that is unreadable, corrupt, or made for other data."""


class DatasetError(NamedError):
    """A dataset folder that does not follow the layout."""


class SettingError(NamedError):
    """A setting (command-line option, operator property, function argument) out of its range."""


class Cancelled(GarmentTransferError):
    """Long work stopped because a progress callback asked for it."""


class RegistrationError(MeshError):
    """A body that could not be fitted onto another (another pose, a partial or non-human mesh)."""


class RigError(NamedError):
    """A skeleton, joints, weights or motion file (or a rig in Blender) that cannot be used as given."""
