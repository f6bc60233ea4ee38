"""Numeric tolerances and defaults in one place."""

import math

#: Triangles whose twice-area is at most this fraction of the squared diagonal of the
#: triangles' bounding box have no normal (``geometry.zero_area_limit``): relative, so a
#: mesh in nanometres or in kilometres has the same degenerate faces.
AREA_EPS = 1e-20
#: Largest coordinate magnitude accepted: squared lengths must stay finite in float32
#: (the ray tracer and the network's sample graph), whose largest value is 3.4e38.
MAX_COORDINATE = 1e18

#: ShDF cone: CGAL's defaults (2/3 pi opening, 25 rays).
SHDF_CONE_ANGLE = 2.0 * math.pi / 3.0
SHDF_RAY_COUNT = 25

#: Default random seed of every stochastic step.
DEFAULT_SEED = 0

#: Size limits of the service and the CLI (``load_mesh`` itself has none unless given):
#: triangles after triangulation and glTF instancing, and vertices (3 per triangle is
#: a triangle soup, the most a sane mesh needs).
DEFAULT_MAX_FACES = 2_000_000
DEFAULT_MAX_VERTICES = 6_000_000

#: Meshes above this many triangles are fine tessellations: the segmentation's graph cut
#: is normalised to this many faces (``SegmentParams.reference_faces``: its energy counts
#: data per face and smoothness per edge, so the face count is what it normalises) and
#: judges creases per unit length (``segment.basis``: wherever some edges are short).
#: Below it (every psb-dev mesh and its production variants but ``refined``) neither
#: applies.
FINE_TESSELLATION_FACES = 60_000

#: Version of the algorithms' results (ShDF, segmentation, atlas): part of the cache key of
#: every computed result, so an upgrade that changes results never serves ones cached by
#: the code before (the package version alone did not change between such commits). Bump
#: it whenever a result changes; tests/test_constants.py keeps the golden result of each
#: version and fails when the result changes under the same version.
ALGORITHM_VERSION = 26
