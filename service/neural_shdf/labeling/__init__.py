"""Named parts: a labeller trained from labelled meshes gives every face of a new mesh a
label and a confidence (``train_labeler``, ``label_mesh``, ``save_labeler``, ``load_labeler``)."""

from neural_shdf.labeling.labeler import describe_mesh, label_mesh, train_labeler
from neural_shdf.labeling.model import (
    Labeler,
    LabelerFileError,
    labeler_bytes,
    labeler_id,
    load_labeler,
    save_labeler,
)

__all__ = [
    "Labeler",
    "LabelerFileError",
    "describe_mesh",
    "label_mesh",
    "labeler_bytes",
    "labeler_id",
    "load_labeler",
    "save_labeler",
    "train_labeler",
]
