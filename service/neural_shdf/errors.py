"""Typed errors whose messages tell a user what is wrong with their mesh or request."""


class NeuralShdfError(Exception):
    """Base class of every error this package raises on purpose."""


class MeshError(NeuralShdfError, ValueError):
    """The mesh cannot be used; the message says why and what to do."""


class UnsupportedFormatError(MeshError):
    """The file format is not one we read."""


class MeshParseError(MeshError):
    """The file is empty, truncated or not a mesh of its declared format."""


class InvalidGeometryError(MeshError):
    """The mesh parsed but its geometry is unusable (NaN, bad indices, only degenerate faces)."""


class MeshTooLargeError(MeshError):
    """The mesh exceeds a configured size limit."""


class ParameterError(NeuralShdfError, ValueError):
    """A parameter is out of range or inconsistent with the mesh."""


class ModelUnavailableError(NeuralShdfError, RuntimeError):
    """The neural ShDF model is missing or cannot be loaded."""
