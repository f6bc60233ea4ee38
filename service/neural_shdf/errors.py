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
    """The mesh exceeds a configured size limit.

    ``limit`` names the limit (``max_faces``, ``max_vertices``, ``max_node_visits``,
    ``memory``), ``maximum`` is its value and ``found`` what the file needs (at least).
    """

    def __init__(
        self,
        message: str,
        *,
        limit: str = "size",
        maximum: int | None = None,
        found: int | None = None,
    ) -> None:
        super().__init__(message)
        self.limit = limit
        self.maximum = maximum
        self.found = found

    def detail(self) -> dict[str, object]:
        """The limit as structured data (the API's error ``detail``)."""
        return {"limit": self.limit, "maximum": self.maximum, "found": self.found}


class ParameterError(NeuralShdfError, ValueError):
    """A parameter is out of range or inconsistent with the mesh."""


class ModelUnavailableError(NeuralShdfError, RuntimeError):
    """The neural ShDF model is missing or cannot be loaded."""
