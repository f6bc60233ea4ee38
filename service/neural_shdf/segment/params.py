"""Parameters of a segmentation run."""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Literal

Partitioner = Literal["graphcut", "metis"]

#: Default smoothing lambda, tuned on psb-dev (1-RI 0.1745 with DEFAULT_CLUSTERS; CGAL's
#: own default 0.26 under-segments with our area/length-normalised energy: 0.209).
DEFAULT_SMOOTHING = 0.12
#: Default mixture size, tuned on psb-dev (k = 8..9 is a plateau; BIC per mesh scored 0.204).
DEFAULT_CLUSTERS = 9
#: ``clusters=AUTO_CLUSTERS`` picks k per mesh by BIC among ``CLUSTER_CANDIDATES``.
AUTO_CLUSTERS = 0
#: Mixture sizes tried by the BIC choice.
CLUSTER_CANDIDATES = tuple(range(2, 9))
#: Largest mixture size a user may ask for.
MAX_CLUSTERS = 32
#: Parts smaller than this fraction of the surface area are merged into a neighbour.
DEFAULT_MIN_PART_FRACTION = 0.002
#: How many times refinement may re-segment a part of a part.
DEFAULT_REFINE_DEPTH = 2


@dataclass(frozen=True)
class SegmentParams:
    """What to segment with; ``None`` means "choose automatically".

    Attributes:
        partitioner: ``graphcut`` (alpha expansion; connected components become
            parts) or ``metis`` (k-way partition into exactly ``parts`` parts).
        clusters: Gaussian mixture components k (a level of detail, not a part
            count); None: ``DEFAULT_CLUSTERS``; ``AUTO_CLUSTERS`` (0): k in
            ``CLUSTER_CANDIDATES`` chosen per mesh by BIC.
        smoothing: smoothness weight lambda of the graph cut (None: ``DEFAULT_SMOOTHING``).
        parts: number of parts for ``metis`` (None: as many as the graph cut finds).
        refine: recursively re-segment parts that are themselves heterogeneous.
        boundary_smoothing: alpha-expansion pass that straightens part boundaries.
        seed: seed of every random step.
        min_part_fraction: parts below this fraction of the total surface area
            are merged into the neighbour they share the longest boundary with
            (a small shell with no neighbour joins the nearest part); 0 keeps all.
            ``metis`` parts are never merged (their count is exact).
        refine_depth: how deep ``refine`` may recurse.
        reference_faces: resolution normalisation of the graph cut. CGAL's
            energy counts data per face and smoothness per edge, so a finer
            tessellation of the same shape gets more parts. When set, edge
            weights are scaled by ``sqrt(faces / reference_faces)``, so any
            tessellation segments like one with ``reference_faces`` faces
            (e.g. 10000). None: CGAL's behaviour.
    """

    partitioner: Partitioner = "graphcut"
    clusters: int | None = None
    smoothing: float | None = None
    parts: int | None = None
    refine: bool = False
    boundary_smoothing: bool = False
    seed: int = 0
    min_part_fraction: float = DEFAULT_MIN_PART_FRACTION
    refine_depth: int = DEFAULT_REFINE_DEPTH
    reference_faces: int | None = None

    @classmethod
    def from_attributes(cls, source: object) -> SegmentParams:
        """Parameters from same-named attributes of ``source`` (CLI arguments, API requests).

        Attributes ``source`` lacks keep their defaults; others it has are ignored.
        """
        present = [field.name for field in fields(cls) if hasattr(source, field.name)]
        return cls(**{name: getattr(source, name) for name in present})
