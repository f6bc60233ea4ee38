"""Numeric tolerances and defaults in one place."""

import math

#: Triangles with twice-area below this (relative to nothing: absolute) have no normal.
AREA_EPS = 1e-20

#: ShDF cone: CGAL's defaults (2/3 pi opening, 25 rays).
SHDF_CONE_ANGLE = 2.0 * math.pi / 3.0
SHDF_RAY_COUNT = 25

#: Default random seed of every stochastic step.
DEFAULT_SEED = 0
