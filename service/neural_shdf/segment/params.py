"""Parameters of a segmentation run."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

Partitioner = Literal["graphcut", "metis"]


@dataclass(frozen=True)
class SegmentParams:
    """What to segment with; ``None`` means "choose automatically".

    Attributes:
        partitioner: ``graphcut`` (alpha expansion; connected components become
            parts) or ``metis`` (k-way partition into exactly ``parts`` parts).
        clusters: Gaussian mixture components k (a level of detail, not a part count).
        smoothing: smoothness weight lambda of the graph cut.
        parts: number of parts for ``metis``.
        refine: recursively re-segment parts that are themselves heterogeneous.
        boundary_smoothing: alpha-expansion pass that straightens part boundaries.
        seed: seed of every random step.
    """

    partitioner: Partitioner = "graphcut"
    clusters: int | None = None
    smoothing: float | None = None
    parts: int | None = None
    refine: bool = False
    boundary_smoothing: bool = False
    seed: int = 0
