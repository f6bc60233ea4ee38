"""Python client of the neural-shdf service (sync and async, over httpx).

from neural_shdf.client import Client

with Client("http://127.0.0.1:8000") as client:
    mesh_id = client.upload("model.obj").mesh_id    # ShDF computed once, cached
    parts = client.segment(mesh_id, partitioner="metis", parts=6)
    parts.labels                                    # numpy int32, one per input face
    shdf = client.shdf(mesh_id)                     # numpy float32, one per input face
"""

from neural_shdf.client import edits
from neural_shdf.client.clients import AsyncClient, Client
from neural_shdf.client.errors import (
    InvalidRequestError,
    JobFailedError,
    NotFoundError,
    PayloadTooLargeError,
    ServiceError,
    ServiceTimeoutError,
    ServiceUnavailableError,
    UnsupportedMediaError,
)
from neural_shdf.client.operations import SegmentArgs
from neural_shdf.client.results import (
    Job,
    LabelerInfo,
    MeshInfo,
    PartHierarchy,
    PartSummary,
    Segmentation,
    Upload,
)
from neural_shdf.client.unwrapping import UnwrapArgs, UvLayout

__all__ = [
    "AsyncClient",
    "Client",
    "InvalidRequestError",
    "Job",
    "JobFailedError",
    "LabelerInfo",
    "MeshInfo",
    "NotFoundError",
    "PartHierarchy",
    "PartSummary",
    "PayloadTooLargeError",
    "SegmentArgs",
    "Segmentation",
    "ServiceError",
    "ServiceTimeoutError",
    "ServiceUnavailableError",
    "UnsupportedMediaError",
    "UnwrapArgs",
    "Upload",
    "UvLayout",
    "edits",
]
