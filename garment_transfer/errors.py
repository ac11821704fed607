"""Errors raised by the core. Each names the object or file it is about."""


class GarmentTransferError(Exception):
    """Base class: an expected failure with a message meant for the user."""


class MeshError(GarmentTransferError, ValueError):
    """A mesh (file or object) that cannot be used as given."""

    def __init__(self, name, problem):
        self.name = name
        self.problem = problem
        super().__init__(f"{name}: {problem}")


class TopologyMismatchError(MeshError):
    """Two meshes that must share vertex order and faces do not."""


class ModelError(GarmentTransferError, ValueError):
    """A model file that is unreadable, corrupt, or made for other data."""

    def __init__(self, name, problem):
        self.name = name
        self.problem = problem
        super().__init__(f"{name}: {problem}")


class DatasetError(GarmentTransferError, ValueError):
    """A dataset folder that does not follow the layout."""

    def __init__(self, name, problem):
        self.name = name
        self.problem = problem
        super().__init__(f"{name}: {problem}")


class Cancelled(GarmentTransferError):
    """Long work stopped because a progress callback asked for it."""
