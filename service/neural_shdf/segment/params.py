"""Parameters of a segmentation run."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Literal

import numpy as np

from neural_shdf.constants import FINE_TESSELLATION_FACES
from neural_shdf.errors import ParameterError

Partitioner = Literal["graphcut", "metis"]

#: Default smoothing (the graph cut's lambda, ``SegmentParams.smoothing``), whose parts are
#: the leaves of the part tree: finer than what scores best without a tree, so that the
#: tree has the parts people cut (tuned on psb-dev at the humans' part count). CGAL's own
#: 0.26 under-segments with our area/length-normalised energy.
DEFAULT_SMOOTHING = 0.06
#: Default mixture size, tuned on psb-dev (a plateau there; BIC per mesh scored worse).
DEFAULT_CLUSTERS = 9
#: ``clusters=AUTO_CLUSTERS`` picks k per mesh by BIC among ``CLUSTER_CANDIDATES``.
AUTO_CLUSTERS = 0
#: Mixture sizes tried by the BIC choice.
CLUSTER_CANDIDATES = tuple(range(2, 9))
#: Largest mixture size a user may ask for.
MAX_CLUSTERS = 32
#: Largest graph-cut smoothness lambda accepted (beyond it every face joins one part).
MAX_SMOOTHING = 100.0
#: Most parts a user may ask for (also bounded by the mesh's face count).
MAX_PARTS = 10_000
#: Largest seed accepted (a non-negative 31-bit integer, the same in the CLI, API and library).
MAX_SEED = 2**31 - 1
#: Deepest refinement accepted.
MAX_REFINE_DEPTH = 8
#: Parts smaller than this fraction of the surface area are merged into a neighbour.
DEFAULT_MIN_PART_FRACTION = 0.002
#: Boundary refinement onto concave creases (``segment.creases``) is on by default: with
#: the automatic count's threshold tuned for it (``hierarchy.AUTO_COST_THRESHOLD``) it
#: lowers the cut discrepancy on psb-dev, held-out models included, and leaves the human
#: body set unchanged (``benchmarks/bench_psb.py``, ``bench_human_seg.py``).
DEFAULT_CREASE_BOUNDARIES = True
#: Default resolution normalisation of the graph cut (``SegmentParams.reference_faces``):
#: its energy weighs each face by its share of the surface and each cut edge by its length
#: against the mean edge, so a finer tessellation of the same shape cuts into more, smaller
#: parts. Meshes above this many faces are segmented as if they had this many (above every
#: psb-dev mesh, so those segment as tuned; normalising every mesh to 20k-40k faces scored
#: better on the psb-dev tuning models but worse on the held-out ones:
#: ``benchmarks/bench_psb.py``, ``bench_production.py --variants subdivided``).
DEFAULT_REFERENCE_FACES = FINE_TESSELLATION_FACES
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
        smoothing: the graph cut's smoothness weight (CGAL's lambda; None:
            ``DEFAULT_SMOOTHING``): its edge weights are ``smoothing`` times the dihedral
            weights at smoothing 1 (``graphcut.dihedral_weights``), after the resolution
            normalisation of ``reference_faces`` (``smoothing_for``). The one name from the
            route and the CLI to ``CutHierarchy.solve``.
        parts: number of parts. ``graphcut``: a cut of the merge tree over its parts
            (``segment.hierarchy``; more than its leaves gives every leaf); ``metis``:
            exactly this many. None: automatic (``metis``: as many as the graph cut finds).
        refine: recursively re-segment parts that are themselves heterogeneous.
        boundary_smoothing: an alpha-expansion pass that straightens part boundaries
            (``refine.smooth_boundaries``; it reads the graph cut's edge weights, so
            ``smoothing`` scales it too).
        crease_boundaries: move the graph cut's part boundaries onto nearby concave
            creases (a min cut in a band around each boundary, ``segment.creases``),
            before the part tree is built, so every cut of the tree has them.
        seed: seed of every random step, in 0..``MAX_SEED``. The one seed convention of
            the CLI, the API and the evaluation: the same seed also seeds the ShDF
            (``compute_shdf(mesh, seed=params.seed)``).
        min_part_fraction: parts below this fraction of the total surface area
            are merged into the neighbour they share the longest boundary with
            (a small shell with no neighbour joins the nearest part); 0 keeps all.
            ``metis`` parts are never merged (their count is exact).
        refine_depth: how deep ``refine`` may recurse.
        symmetry: when the mesh has a global reflective symmetry (``segment.symmetry``:
            a mirror plane pairing at least ``MIN_MATCHED_AREA`` of the surface), each
            face's ShDF evidence is averaged with its mirror face's before the mixture,
            so both sides are cut alike; no symmetry found: no change.
        reference_faces: resolution normalisation of the graph cut. CGAL's
            energy counts data per face and smoothness per edge, so a finer
            tessellation of the same shape gets more parts. Edge weights are
            scaled by ``sqrt(faces / reference_faces)`` on meshes with more faces, so
            any finer tessellation segments like one with ``reference_faces`` faces
            (default ``DEFAULT_REFERENCE_FACES``). None: CGAL's behaviour (no scaling).
    """

    partitioner: Partitioner = "graphcut"
    clusters: int | None = None
    smoothing: float | None = None
    parts: int | None = None
    refine: bool = False
    boundary_smoothing: bool = False
    crease_boundaries: bool = DEFAULT_CREASE_BOUNDARIES
    seed: int = 0
    min_part_fraction: float = DEFAULT_MIN_PART_FRACTION
    refine_depth: int = DEFAULT_REFINE_DEPTH
    reference_faces: int | None = DEFAULT_REFERENCE_FACES
    symmetry: bool = False

    def __post_init__(self) -> None:
        """Every parameter checked here, once, whoever builds the parameters (CLI, API,
        library); raises ParameterError saying which value is wrong and what is allowed.
        Checks that need the mesh (``parts`` <= faces) are made where the mesh is known."""
        if self.partitioner not in ("graphcut", "metis"):
            raise ParameterError(
                f"unknown partitioner {self.partitioner!r}; use 'graphcut' or 'metis'"
            )
        if self.clusters is not None and (
            not _is_int(self.clusters) or not AUTO_CLUSTERS <= self.clusters <= MAX_CLUSTERS
        ):
            raise ParameterError(
                f"clusters must be an integer in 1..{MAX_CLUSTERS}, {AUTO_CLUSTERS} to choose it "
                f"by BIC, or None for the default ({DEFAULT_CLUSTERS}), got {self.clusters!r}"
            )
        if self.smoothing is not None and not (
            _is_number(self.smoothing)
            and math.isfinite(self.smoothing)
            and 0 <= self.smoothing <= MAX_SMOOTHING
        ):
            raise ParameterError(
                f"smoothing must be a finite number in [0, {MAX_SMOOTHING:g}] (or None for "
                f"{DEFAULT_SMOOTHING}), got {self.smoothing!r}"
            )
        if self.parts is not None and (not _is_int(self.parts) or not 1 <= self.parts <= MAX_PARTS):
            raise ParameterError(f"parts must be an integer in 1..{MAX_PARTS}, got {self.parts!r}")
        for name in ("refine", "boundary_smoothing", "crease_boundaries", "symmetry"):
            if not isinstance(getattr(self, name), bool | np.bool_):
                raise ParameterError(f"{name} must be true or false, got {getattr(self, name)!r}")
        check_seed(self.seed)
        if not _is_number(self.min_part_fraction) or not 0 <= self.min_part_fraction < 1:
            raise ParameterError(
                f"min_part_fraction must be in [0, 1), got {self.min_part_fraction!r}"
            )
        if not _is_int(self.refine_depth) or not 0 <= self.refine_depth <= MAX_REFINE_DEPTH:
            raise ParameterError(
                f"refine_depth must be an integer in 0..{MAX_REFINE_DEPTH}, "
                f"got {self.refine_depth!r}"
            )
        if self.reference_faces is not None and (
            not _is_int(self.reference_faces) or self.reference_faces < 1
        ):
            raise ParameterError(
                f"reference_faces must be an integer >= 1 (or None), got {self.reference_faces!r}"
            )

    @property
    def effective_smoothing(self) -> float:
        """``smoothing``, or ``DEFAULT_SMOOTHING`` where it is None."""
        return DEFAULT_SMOOTHING if self.smoothing is None else float(self.smoothing)

    def smoothing_for(self, face_count: int) -> float:
        """The smoothing lambda the graph cut uses on a mesh of ``face_count`` faces:
        ``effective_smoothing``, times ``sqrt(face_count / reference_faces)`` when
        ``reference_faces`` is set and exceeded (resolution normalisation)."""
        smoothing = self.effective_smoothing
        if self.reference_faces is None:
            return smoothing * 1.0
        scaled: float = smoothing * np.sqrt(max(face_count / self.reference_faces, 1.0))
        return scaled

    @classmethod
    def from_attributes(cls, source: object) -> SegmentParams:
        """Parameters from same-named attributes of ``source`` (CLI arguments, API requests).

        Attributes ``source`` lacks keep their defaults; others it has are ignored.
        """
        present = [field.name for field in fields(cls) if hasattr(source, field.name)]
        return cls(**{name: getattr(source, name) for name in present})


def check_seed(seed: object) -> int:
    """The seed as an int; ParameterError unless it is an integer in 0..MAX_SEED."""
    if not _is_int(seed) or not 0 <= seed <= MAX_SEED:  # type: ignore[operator]
        raise ParameterError(f"seed must be an integer in 0..{MAX_SEED}, got {seed!r}")
    checked: int = int(seed)  # type: ignore[call-overload]
    return checked


def _is_int(value: object) -> bool:
    return isinstance(value, int | np.integer) and not isinstance(value, bool)


def _is_number(value: object) -> bool:
    return isinstance(value, int | float | np.integer | np.floating) and not isinstance(value, bool)
