"""Request and response models of the REST API (documented, with examples)."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from fastapi import UploadFile
from pydantic import BaseModel, ConfigDict, Field

from neural_shdf.segment import SegmentParams
from neural_shdf.segment.editing import MAX_EDIT_FACES, MAX_EDIT_OPERATIONS
from neural_shdf.segment.params import (
    DEFAULT_CREASE_BOUNDARIES,
    MAX_CLUSTERS,
    MAX_PARTS,
    MAX_SEED,
    MAX_SMOOTHING,
)
from neural_shdf.unwrap import MAX_ATLAS_SIZE, MAX_PADDING, MIN_ATLAS_SIZE, UnwrapParams

#: A requested ShDF method; ``auto`` picks a producer per mesh.
ShdfMethodName = Literal["auto", "exact", "sampled", "neural"]
#: The ShDF producer that ran (``auto`` resolved).
ShdfProducerName = Literal["exact", "sampled", "neural"]
JobState = Literal["queued", "running", "succeeded", "failed"]
#: What a job computes: a ShDF, a UV atlas for ``unwrapped.glb``, ``unwrapped.obj``,
#: ``atlas.png`` or ``uvs``, or a part labeller (training).
JobKind = Literal["shdf", "unwrap", "obj", "atlas", "uvs", "labeler"]

MESH_ID_EXAMPLE = "3f1c0b6e2d4a8f7e9c1b2a3d4e5f60718293a4b5c6d7e8f9a0b1c2d3e4f5a6b7"
MESH_ID_PATTERN = "^[0-9a-f]{64}$"
JOB_ID_PATTERN = "^[0-9a-f]{32}$"
JOB_ID_EXAMPLE = "5d0f3c8a9b6e4f21a7c3d2e1f0a9b8c7"
LABELER_ID_PATTERN = "^[0-9a-f]{64}$"
LABELER_ID_EXAMPLE = "9c4e1f0b7a2d3e5f60718293a4b5c6d7e8f9a0b1c2d3e4f5a6b73f1c0b6e2d4a8f"


def documented_bounds(minimum: float, maximum: float) -> dict[str, float]:
    """JSON-schema bounds for clients and fuzzers. They are not enforced by pydantic:
    ``SegmentParams`` (and ``check_seed``) validate, once, for the CLI, API and library."""
    return {"minimum": minimum, "maximum": maximum}


SEED_BOUNDS = documented_bounds(0, MAX_SEED)


class ErrorDetail(BaseModel):
    """What went wrong, in a form a program and a person can both use."""

    code: str = Field(
        description="Stable machine-readable error code.", examples=["invalid_geometry"]
    )
    message: str = Field(
        description="What is wrong and what to do about it.",
        examples=["the mesh has 12 vertices with NaN coordinates; fix or remove them"],
    )
    detail: Any = Field(
        None,
        description="Structured extra information (e.g. validation problems).",
        examples=[None],
    )


class ErrorResponse(BaseModel):
    """The body of every error response."""

    error: ErrorDetail = Field(description="The error.")


class Health(BaseModel):
    """Liveness: the process answers."""

    status: Literal["ok"] = Field(
        description="Always `ok` when the service answers.", examples=["ok"]
    )


class Check(BaseModel):
    """One readiness check."""

    ok: bool = Field(description="Whether the check passed.", examples=[True])
    detail: str = Field(description="What was checked, or why it failed.", examples=["disk"])


class Readiness(BaseModel):
    """Readiness: the model is loaded and the cache is reachable."""

    status: Literal["ready", "degraded", "not_ready"] = Field(
        description="Overall state: `degraded` (still 200) while Redis is unreachable and "
        "the local disk cache serves instead.",
        examples=["ready"],
    )
    checks: dict[str, Check] = Field(
        description="Each check by name (`model`, `cache`).",
        examples=[
            {"model": {"ok": True, "detail": "emd.onnx"}, "cache": {"ok": True, "detail": "disk"}}
        ],
    )


class MeshDiagnosticsInfo(BaseModel):
    """What the mesh had and what was done about it before the ShDF and segmentation
    (the file itself is kept as uploaded)."""

    shells: int = Field(description="Connected pieces (faces linked by edges).", examples=[1])
    boundary_loops: int = Field(
        description="Open boundary loops (holes, missing bases, sheet rims).", examples=[0]
    )
    non_manifold_edges: int = Field(description="Edges shared by 3+ faces.", examples=[0])
    reoriented_faces: int = Field(
        description="Triangles whose winding the ShDF and segmentation use reversed, so that "
        "every shell faces out of its solid.",
        examples=[0],
    )
    degenerate_faces: int = Field(description="Triangles of zero area.", examples=[0])
    duplicate_faces: int = Field(
        description="Triangles on the same three vertices as an earlier one.", examples=[0]
    )
    stitched_shells: int = Field(
        default=0,
        description="Open shells joined to another along their boundaries for the "
        "segmentation's graphs (pieces of one surface split in the file).",
        examples=[0],
    )
    stitched_vertices: int = Field(
        default=0,
        description="Boundary vertices merged into one of another shell by that stitching.",
        examples=[0],
    )


class MeshInfo(BaseModel):
    """A stored mesh: its id (content hash of the canonical geometry) and its size.

    Shared by every client that uploads the same geometry: the id, the size, bounds and
    area, and all results computed from it (ShDF, segmentations, atlases). Per upload and
    never shown to another client: the file name, its format and the upload time."""

    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {
                    "mesh_id": MESH_ID_EXAMPLE,
                    "faces": 6,
                    "triangles": 12,
                    "vertices": 8,
                    "format": "obj",
                    "filename": "cube.obj",
                    "bounds": [[-0.5, -0.5, -0.5], [0.5, 0.5, 0.5]],
                    "surface_area": 6.0,
                    "diagnostics": {
                        "shells": 1,
                        "boundary_loops": 0,
                        "non_manifold_edges": 0,
                        "reoriented_faces": 0,
                        "degenerate_faces": 0,
                        "duplicate_faces": 0,
                        "stitched_shells": 0,
                        "stitched_vertices": 0,
                    },
                }
            ]
        }
    )

    mesh_id: str = Field(
        description="SHA-256 of the canonical geometry.", examples=[MESH_ID_EXAMPLE]
    )
    faces: int = Field(description="Faces of the input file (polygons).", examples=[6])
    triangles: int = Field(description="Triangles after triangulation.", examples=[12])
    vertices: int = Field(description="Vertices.", examples=[8])
    format: str | None = Field(
        None,
        description="Format of this upload's file (only in the upload's answer: null when "
        "the mesh is read back).",
        examples=["obj"],
    )
    filename: str | None = Field(
        None,
        description="Name of this upload's file, as sent (only in the upload's answer: a mesh "
        "is stored by its geometry, which several clients may upload under their own names, "
        "so none is kept with it).",
        examples=["cube.obj"],
    )
    uploaded_at: float | None = Field(
        None,
        description="Unix time of this upload (only in the upload's answer).",
        examples=[1763791200.0],
    )
    source_id: str | None = Field(
        None,
        description="Id of this upload's own file, kept with the mesh (OBJ, PLY, glTF/GLB "
        "and USD uploads; only in the upload's answer): pass it as `source` to `parts.glb` "
        "(the parts keep the file's normals, UVs, colours, materials and objects) or "
        "`parts.usda` (a USD file's own stage with a GeomSubset per part).",
        pattern=MESH_ID_PATTERN,
        examples=[MESH_ID_EXAMPLE],
    )
    bounds: list[list[float]] = Field(
        description="Axis-aligned bounding box `[[min x,y,z], [max x,y,z]]`.",
        examples=[[[-0.5, -0.5, -0.5], [0.5, 0.5, 0.5]]],
    )
    surface_area: float = Field(description="Total triangle area.", examples=[6.0])
    diagnostics: MeshDiagnosticsInfo | None = Field(
        None, description="What the mesh had (shells, holes, winding, degenerate faces)."
    )


class ShdfStatus(BaseModel):
    """Where the ShDF of a mesh stands after an upload."""

    method: ShdfProducerName = Field(
        description="ShDF producer that ran (auto resolved).", examples=["exact"]
    )
    seed: int = Field(description="Seed of the ShDF computation.", examples=[0])
    cached: bool = Field(description="True when it came from the cache.", examples=[False])
    seconds: float = Field(
        description="Time spent computing it now (0 when cached).", examples=[0.42]
    )


class UploadResult(BaseModel):
    """A mesh stored and its ShDF computed (synchronous answer)."""

    mesh: MeshInfo = Field(description="The stored mesh.")
    shdf: ShdfStatus = Field(description="The ShDF computed for it.")


class Job(BaseModel):
    """A long computation (ShDF of a large mesh); poll it until `succeeded` or `failed`."""

    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {
                    "job_id": JOB_ID_EXAMPLE,
                    "state": "running",
                    "progress": 0.4,
                    "mesh_id": MESH_ID_EXAMPLE,
                    "kind": "shdf",
                    "method": "exact",
                    "seed": 0,
                    "attempt": 1,
                    "created_at": 1763791200.0,
                    "updated_at": 1763791203.5,
                    "error": None,
                    "result_url": f"/v1/meshes/{MESH_ID_EXAMPLE}",
                }
            ]
        }
    )

    job_id: str = Field(description="Job id.", examples=[JOB_ID_EXAMPLE])
    state: JobState = Field(
        description="queued, running, succeeded or failed.", examples=["running"]
    )
    progress: float = Field(ge=0, le=1, description="Fraction done.", examples=[0.4])
    mesh_id: str = Field(description="The mesh the job computes.", examples=[MESH_ID_EXAMPLE])
    kind: JobKind = Field(
        "shdf",
        description="What the job computes: `shdf`, the atlas of `unwrap` (unwrapped.glb), "
        "`obj` (unwrapped.obj), `atlas` (atlas.png) or `uvs`, or a part `labeler` (training; "
        "`mesh_id` is its first mesh, and `result_url` the labeller once it succeeded).",
        examples=["shdf"],
    )
    method: ShdfMethodName = Field(
        description="ShDF producer that runs (`auto` is resolved per mesh when the job is "
        "created; a record written by an older version may still say `auto`).",
        examples=["exact"],
    )
    seed: int = Field(description="ShDF seed.", examples=[0])
    attempt: int = Field(
        1,
        ge=1,
        description="Run of the job: above 1 when it was re-run after its worker stopped.",
        examples=[1],
    )
    created_at: float = Field(description="Unix time the job was created.", examples=[1763791200.0])
    updated_at: float = Field(description="Unix time of the last update.", examples=[1763791203.5])
    error: ErrorDetail | None = Field(None, description="Why it failed (state `failed`).")
    result_url: str = Field(
        description="Where the result is once it succeeded.",
        examples=[f"/v1/meshes/{MESH_ID_EXAMPLE}"],
    )


class ShdfValues(BaseModel):
    """Per-face ShDF in the input file's face order (null for faces without triangles)."""

    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {
                    "mesh_id": MESH_ID_EXAMPLE,
                    "method": "exact",
                    "seed": 0,
                    "model_version": None,
                    "faces": 4,
                    "values": [0.12, 0.5, 0.98, None],
                }
            ]
        }
    )

    mesh_id: str = Field(description="Mesh id.", examples=[MESH_ID_EXAMPLE])
    method: ShdfProducerName = Field(
        description="ShDF producer that ran (auto resolved).", examples=["exact"]
    )
    seed: int = Field(description="ShDF seed.", examples=[0])
    model_version: str | None = Field(
        description="Version (hash) of the neural model; null unless `neural` ran.",
        examples=["a1b2c3d4e5f60718"],
    )
    faces: int = Field(description="Number of values (input faces).", examples=[4])
    values: list[float | None] = Field(
        description="ShDF in [0, 1] per input face.", examples=[[0.12, 0.5, 0.98, None]]
    )


class SegmentOptions(BaseModel):
    """Which ShDF to use and how to partition the mesh; omitted values are chosen automatically."""

    model_config = ConfigDict(extra="ignore")

    method: ShdfMethodName | None = Field(
        None,
        description="ShDF method (auto, exact, sampled, neural); default: the service's "
        "default (auto).",
        examples=["auto"],
    )
    partitioner: Literal["graphcut", "metis"] = Field(
        "graphcut",
        description="`graphcut` (alpha expansion) or `metis` (exactly `parts` parts).",
        examples=["graphcut"],
    )
    clusters: int | None = Field(
        None,
        json_schema_extra=documented_bounds(0, MAX_CLUSTERS),
        description=(
            "Gaussian mixture components (level of detail, not a part count); "
            "none: the default (9, tuned on the Princeton benchmark); 0: chosen per mesh by BIC."
        ),
        examples=[5],
    )
    smoothing: float | None = Field(
        None,
        json_schema_extra=documented_bounds(0, MAX_SMOOTHING),
        description="Smoothness weight lambda of the graph cut (whose parts are the part "
        "tree's leaves); default 0.06.",
        examples=[0.06],
    )
    parts: int | None = Field(
        None,
        json_schema_extra=documented_bounds(1, MAX_PARTS),
        description="Number of parts. `graphcut`: a cut of its part tree (at most its leaves; "
        "instant once the tree exists); `metis`: exactly this many (at most the mesh's face "
        "count). None: automatic.",
        examples=[6],
    )
    refine: bool = Field(False, description="Re-segment heterogeneous parts.", examples=[False])
    boundary_smoothing: bool = Field(
        False, description="Straighten part boundaries.", examples=[False]
    )
    crease_boundaries: bool = Field(
        DEFAULT_CREASE_BOUNDARIES,
        description="Move the graph cut's part boundaries onto nearby concave creases (a min "
        "cut in a band around each boundary), before the part tree is built, so every cut "
        "of `hierarchy` has them.",
        examples=[DEFAULT_CREASE_BOUNDARIES],
    )
    symmetry: bool = Field(
        False,
        description="Cut both sides of a mirror-symmetric shape alike: when a global "
        "reflective symmetry is found (a plane pairing at least 90% of the surface with "
        "mirror faces), each face's ShDF evidence is averaged with its mirror face's before "
        "the mixture. No symmetry found: the labels are those without it.",
        examples=[False],
    )
    seed: int = Field(
        0,
        json_schema_extra=SEED_BOUNDS,
        description="Seed of every random step: the ShDF's sampling (so the ShDF cached by "
        "an upload with the same `seed` is reused) and the segmentation.",
        examples=[0],
    )
    labels_format: Literal["json", "base64"] = Field(
        "json",
        description="`json`: labels as a list; `base64`: the labels as little-endian "
        "integers of the smallest width that holds them (`labels_dtype`), base64-encoded: "
        "1.33 bytes per face below 128 parts, decoded with one `numpy.frombuffer` call.",
        examples=["json"],
    )

    def segment_params(self) -> SegmentParams:
        """The library's parameters, validated there (ParameterError: a 422 that says why)."""
        return SegmentParams.from_attributes(self)


class LabeledSegmentOptions(SegmentOptions):
    """Segmentation options, or named parts by a stored labeller (`labeler_id`)."""

    labeler_id: str | None = Field(
        None,
        pattern=LABELER_ID_PATTERN,
        description="A stored part labeller (`POST /v1/labelers`): the labels are then its "
        "named parts, in the training labels' own integers, with `label_names` and a "
        "`confidence` per face, from the mesh's cached ShDF (`method`, `seed`); the "
        "partitioning options are not used.",
        examples=[LABELER_ID_EXAMPLE],
    )


class UnwrapOptions(SegmentOptions):
    """The segmentation to unwrap by, and how to chart and pack its parts."""

    atlas_size: int = Field(
        1024,
        json_schema_extra=documented_bounds(MIN_ATLAS_SIZE, MAX_ATLAS_SIZE),
        description="Side of the square atlas in texels.",
        examples=[1024],
    )
    padding: int = Field(
        2,
        json_schema_extra=documented_bounds(0, MAX_PADDING),
        description="Texels left free around every chart.",
        examples=[2],
    )
    max_stretch: float = Field(
        1.1,
        json_schema_extra={"minimum": 1.0},
        description="Largest L2 stretch (1 = none) of a part kept as one chart; above it "
        "the part is cut further, then halved, then charted by xatlas.",
        examples=[1.1],
    )

    def unwrap_params(self) -> UnwrapParams:
        """The library's parameters, validated there (ParameterError: a 422 that says why)."""
        return UnwrapParams(
            atlas_size=self.atlas_size, padding=self.padding, max_stretch=self.max_stretch
        )


class UvLayout(BaseModel):
    """UVs of every corner of every input face, in the input file's face order and each
    polygon's own corner order (``unwrapped.glb``'s atlas, for clients that keep their
    own mesh, such as the Blender add-on)."""

    mesh_id: str = Field(description="Mesh id.", examples=[MESH_ID_EXAMPLE])
    faces: int = Field(description="Input faces.", examples=[2])
    corners: int = Field(
        description="Corners of all input faces (the sum of `corner_counts`).", examples=[6]
    )
    corner_counts_base64: str = Field(
        description="Corners of each input face as base64 little-endian int32 (0: a face "
        "without triangles, which has no UVs).",
        examples=["AwAAAAMAAAA="],
    )
    uvs_base64: str = Field(
        description="`corners` (u, v) pairs as base64 little-endian float32, face after face, "
        "each face's corners in the file's order; in [0, 1], v up (OBJ's and Blender's "
        "convention).",
        examples=["AAAAAAAAAAAAAIA/AAAAAAAAAAAAAIA/AACAPwAAAAAAAIA/AACAPwAAAAAAAIA/"],
    )
    chart_base64: str = Field(
        description="The chart of each input face (its first triangle's) as base64 "
        "little-endian int32; -1: none.",
        examples=["AAAAAAAAAAA="],
    )
    chart_part: list[int] = Field(description="The part of each chart.", examples=[[0]])
    width: int = Field(description="Packed atlas width in texels.", examples=[1024])
    height: int = Field(description="Packed atlas height in texels.", examples=[1024])
    utilization: float = Field(description="Fraction of the atlas covered.", examples=[0.62])
    split_faces: int = Field(
        description="Input faces a chart boundary runs through: their triangles disagree "
        "on a shared corner's UV, and the corners here are the outer ones of the fan.",
        examples=[0],
    )


FACE_INDEX = {"minimum": 0}
FACE_LIST = {"minItems": 1, "maxItems": MAX_EDIT_FACES}


class GrowEdit(BaseModel):
    """The part-tree node of the cut that holds `face` becomes its parent; parts wholly
    inside the parent join it. No-op at the root."""

    model_config = ConfigDict(extra="forbid")
    op: Literal["grow"] = Field(description="Operation.", examples=["grow"])
    face: int = Field(
        json_schema_extra=FACE_INDEX, description="A face of the part.", examples=[120]
    )


class ShrinkEdit(BaseModel):
    """The part-tree node of the cut that holds `face` is replaced by its two children
    (the one holding `face` stays in its part). No-op at a leaf."""

    model_config = ConfigDict(extra="forbid")
    op: Literal["shrink"] = Field(description="Operation.", examples=["shrink"])
    face: int = Field(
        json_schema_extra=FACE_INDEX, description="A face of the part.", examples=[120]
    )


class MergeEdit(BaseModel):
    """The parts holding `faces` become one part."""

    model_config = ConfigDict(extra="forbid")
    op: Literal["merge"] = Field(description="Operation.", examples=["merge"])
    faces: list[int] = Field(
        json_schema_extra=FACE_LIST, description="Input faces.", examples=[[120, 4031]]
    )


class PaintEdit(BaseModel):
    """`faces` join the part holding `to_face`."""

    model_config = ConfigDict(extra="forbid")
    op: Literal["paint"] = Field(description="Operation.", examples=["paint"])
    faces: list[int] = Field(
        json_schema_extra=FACE_LIST, description="Input faces to move.", examples=[[7, 8, 9]]
    )
    to_face: int = Field(
        json_schema_extra=FACE_INDEX, description="A face of the part to join.", examples=[4031]
    )


class SplitEdit(BaseModel):
    """The part holding `face` is cut in two halves of similar face count with the shortest
    boundary (METIS bisection); the half holding `face` stays, the other is a new part."""

    model_config = ConfigDict(extra="forbid")
    op: Literal["split"] = Field(description="Operation.", examples=["split"])
    face: int = Field(
        json_schema_extra=FACE_INDEX, description="A face of the part.", examples=[120]
    )


EditOperation = Annotated[
    GrowEdit | ShrinkEdit | MergeEdit | PaintEdit | SplitEdit, Field(discriminator="op")
]


class SegmentRequest(LabeledSegmentOptions):
    """Segment a stored mesh from its cached ShDF (optionally edited by hand: `edits`)."""

    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={
            "examples": [{"mesh_id": MESH_ID_EXAMPLE, "clusters": 5, "smoothing": 0.12}]
        },
    )

    mesh_id: str = Field(
        pattern=MESH_ID_PATTERN,
        description="Id returned by the upload (64 hex digits).",
        examples=[MESH_ID_EXAMPLE],
    )
    edits: list[EditOperation] | None = Field(
        None,
        json_schema_extra={"maxItems": MAX_EDIT_OPERATIONS},
        description="Part edits, applied in order to the part tree's cut at `parts` "
        "(see docs/part-editing.md). They name input faces, not tree nodes, so the same "
        "document applies after a re-segmentation with other options. `grow` and "
        f"`shrink` need the part tree (`graphcut`); `metis` takes `merge` and `paint`. "
        f"At most {MAX_EDIT_OPERATIONS} operations and {MAX_EDIT_FACES} faces in all. "
        "The response's labels and parts are the edited ones (numbered by each part's "
        "smallest face); its `hierarchy` is the unedited tree, with `parts` the cut the "
        "edits started from.",
        examples=[
            [
                {"op": "grow", "face": 120},
                {"op": "merge", "faces": [120, 4031]},
                {"op": "paint", "faces": [7, 8, 9], "to_face": 4031},
            ]
        ],
    )


class SegmentFileForm(LabeledSegmentOptions):
    """Multipart form of a one-shot segmentation: the mesh file and the options."""

    file: UploadFile = Field(
        description="OBJ, GLB/glTF (embedded buffers), OFF, PLY, STL or USD (.usd, .usda, "
        ".usdc, .usdz; one file or package)."
    )
    file_type: str | None = Field(
        None, description="Format; default: the file extension.", examples=["obj"]
    )


class PartSummary(BaseModel):
    """One part of a segmentation."""

    label: int = Field(description="Part label.", examples=[0])
    faces: int = Field(description="Input faces in the part.", examples=[1200])
    area: float = Field(description="Surface area of the part.", examples=[0.37])
    mean_shdf: float = Field(description="Area-weighted mean ShDF of the part.", examples=[0.42])
    color: str = Field(
        description="Display colour `#rrggbb`, the same as in the coloured GLB.",
        examples=["#e69f00"],
    )
    name: str | None = Field(
        None,
        description="The label's name (with `labeler_id`); null for unnamed parts.",
        examples=["head"],
    )


class Timings(BaseModel):
    """Where the time went, in milliseconds."""

    shdf_ms: float = Field(description="ShDF computation now (0 when cached).", examples=[0.0])
    segment_ms: float = Field(
        description="Partitioning (0 when the result was cached).", examples=[85.2]
    )
    total_ms: float = Field(description="Whole request.", examples=[90.1])
    shdf_cached: bool = Field(description="The ShDF came from the cache.", examples=[True])
    segmentation_cached: bool = Field(
        description="The whole segmentation came from the cache.", examples=[False]
    )


class PartHierarchy(BaseModel):
    """The graph cut's part tree: any part count is a cut of it, computed by the client.

    Leaves are nodes `0..L-1` (the finest parts, numbered by their lowest face); merge
    `i` (cheapest first) joined two nodes into node `L + i`; the root is `2L - 2`.

    To get `N` parts (1 <= N <= L) with no request: for each leaf, climb while its
    parent's id is below `2L - N` (stop at the root, parent -1); the node reached is
    its part. Number the parts by their smallest leaf (that gives this response's own
    `labels` for `N = parts`), then `label[face] = part[leaf_labels[face]]` (-1 stays
    -1). Cuts are nested: each part at N + 1 lies inside one part at N.
    """

    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {
                    "leaf_count": 3,
                    "parts": 2,
                    "automatic_parts": 2,
                    "leaf_labels": [0, 0, 1, 2],
                    "leaf_labels_base64": None,
                    "leaf_labels_dtype": None,
                    "parent": [3, 3, 4, 4, -1],
                    "merge_cost": [0.0012, 0.31],
                    "merge_height": [0.0012, 0.31],
                }
            ]
        }
    )

    leaf_count: int = Field(description="Leaves L (the most parts a cut can give).", examples=[3])
    parts: int = Field(description="The part count `labels` was cut at.", examples=[2])
    automatic_parts: int = Field(
        description="The count chosen when `parts` is not given (where merge costs jump).",
        examples=[2],
    )
    leaf_labels: list[int] | None = Field(
        description="Leaf per input face (-1: face without triangles); null with "
        "`labels_format=base64`.",
        examples=[[0, 0, 1, 2]],
    )
    leaf_labels_base64: str | None = Field(
        None,
        description="Leaf labels as base64 little-endian integers (`labels_format=base64`).",
        examples=[None],
    )
    leaf_labels_dtype: Literal["int8", "int16", "int32"] | None = Field(
        None, description="Integer type of `leaf_labels_base64`.", examples=[None]
    )
    parent: list[int] = Field(
        description="Parent node of each of the 2L - 1 nodes; -1 for the root.",
        examples=[[3, 3, 4, 4, -1]],
    )
    merge_cost: list[float] = Field(
        description="Cost of merge i (made node L + i), L - 1 values in merge order.",
        examples=[[0.0012, 0.31]],
    )
    merge_height: list[float] = Field(
        description="Running maximum of `merge_cost` (monotone: a dendrogram's heights).",
        examples=[[0.0012, 0.31]],
    )


class Segmentation(BaseModel):
    """Per-face part labels in the input file's face order, with a summary per part."""

    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {
                    "mesh_id": MESH_ID_EXAMPLE,
                    "method": "exact",
                    "faces": 4,
                    "part_count": 2,
                    "labels": [0, 0, 1, 1],
                    "labels_base64": None,
                    "labels_dtype": None,
                    "hierarchy": None,
                    "parts": [
                        {
                            "label": 0,
                            "faces": 2,
                            "area": 1.0,
                            "mean_shdf": 0.2,
                            "color": "#e69f00",
                        },
                        {
                            "label": 1,
                            "faces": 2,
                            "area": 1.0,
                            "mean_shdf": 0.8,
                            "color": "#56b4e9",
                        },
                    ],
                    "timings": {
                        "shdf_ms": 0.0,
                        "segment_ms": 12.5,
                        "total_ms": 14.0,
                        "shdf_cached": True,
                        "segmentation_cached": False,
                    },
                }
            ]
        }
    )

    mesh_id: str = Field(description="Mesh id.", examples=[MESH_ID_EXAMPLE])
    method: ShdfProducerName = Field(
        description="ShDF producer that ran (auto resolved).", examples=["exact"]
    )
    faces: int = Field(description="Input faces (length of the labels).", examples=[4])
    part_count: int = Field(description="Number of parts.", examples=[2])
    labels: list[int] | None = Field(
        description="Part label per input face (-1: face without triangles); null when "
        "`labels_format` is `base64`.",
        examples=[[0, 0, 1, 1]],
    )
    labels_base64: str | None = Field(
        None,
        description="Labels as base64 little-endian integers (with `labels_format=base64`).",
        examples=["AAABAQ=="],
    )
    labels_dtype: Literal["int8", "int16", "int32"] | None = Field(
        None,
        description="Integer type of `labels_base64` (little-endian).",
        examples=["int8"],
    )
    parts: list[PartSummary] = Field(
        description="Summary per part, by label.",
        examples=[[{"label": 0, "faces": 2, "area": 1.0, "mean_shdf": 0.2, "color": "#e69f00"}]],
    )
    hierarchy: PartHierarchy | None = Field(
        None,
        description="The part tree (`graphcut`; null for `metis`): re-cut it locally for "
        "any part count.",
    )
    timings: Timings = Field(description="Timings.")
    source_id: str | None = Field(
        None,
        description="Only in `/v1/segment/file`'s answer (and its `X-Source-Id` header, "
        "also of a 202): the id of the uploaded file, kept with the mesh as an upload's "
        "`mesh.source_id` is (OBJ, PLY, glTF/GLB and USD; absent for other formats). "
        "Pass it as `source` to `parts.glb` or `parts.usda`.",
        pattern=MESH_ID_PATTERN,
        examples=[None],
    )
    labeler_id: str | None = Field(
        None,
        description="The labeller that named the parts; null for a segmentation.",
        examples=[None],
    )
    label_names: list[str] | None = Field(
        None,
        description="With `labeler_id`: the labeller's label names, one per value of "
        "`label_values` (the labels may use fewer).",
        examples=[None],
    )
    label_values: list[int] | None = Field(
        None,
        description="With `labeler_id`: the labeller's label integers, as in `labels`.",
        examples=[None],
    )
    confidence: list[float | None] | None = Field(
        None,
        description="With `labeler_id`: probability of each face's label (null: face "
        "without triangles); null with `labels_format=base64`.",
        examples=[None],
    )
    confidence_base64: str | None = Field(
        None,
        description="With `labeler_id` and `labels_format=base64`: the confidence as "
        "base64 little-endian float32 (NaN: face without triangles).",
        examples=[None],
    )


class LabelerInfo(BaseModel):
    """A stored part labeller: what it labels, and with what."""

    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {
                    "labeler_id": LABELER_ID_EXAMPLE,
                    "label_names": ["torso", "head", "arm"],
                    "label_values": [1, 2, 3],
                    "feature_version": 3,
                    "smoothing": 0.003,
                    "training_meshes": 12,
                    "size_bytes": 183204,
                    "stored_at": 1763791200.0,
                }
            ]
        }
    )

    labeler_id: str = Field(
        description="Content id of the labeller (64 hex digits): the same labeller "
        "uploaded twice has one id.",
        examples=[LABELER_ID_EXAMPLE],
    )
    label_names: list[str] = Field(
        description="Name of each label, in `label_values` order.",
        examples=[["torso", "head", "arm"]],
    )
    label_values: list[int] = Field(
        description="The training labels' integers (what labels per face hold).",
        examples=[[1, 2, 3]],
    )
    feature_version: int = Field(description="Version of its node features.", examples=[3])
    smoothing: float = Field(description="Graph-cut smoothing of its labels.", examples=[0.003])
    training_meshes: int = Field(description="Meshes it was trained on.", examples=[12])
    size_bytes: int = Field(description="Size of its file.", examples=[183204])
    stored_at: float = Field(description="Unix time it was first stored.", examples=[1763791200.0])


class LabelerList(BaseModel):
    """The stored part labellers, oldest first."""

    labelers: list[LabelerInfo] = Field(description="Stored labellers of this page.", examples=[[]])
    total: int = Field(description="Labellers stored in all.", examples=[0])
    next_offset: int | None = Field(
        description="`offset` of the next page; null after the last page.", examples=[None]
    )


class LabelerTrainForm(BaseModel):
    """Multipart form of a labeller training: stored meshes and a label per input face."""

    model_config = ConfigDict(extra="forbid")

    mesh_ids: str = Field(
        description="Ids of stored meshes (`POST /v1/meshes`), comma-separated.",
        examples=[f"{MESH_ID_EXAMPLE},{MESH_ID_EXAMPLE[::-1]}"],
    )
    labels: UploadFile = Field(
        description="One label per input face of each mesh, in the file's face order, the "
        "meshes in `mesh_ids` order, as little-endian int32 (4 bytes per face)."
    )
    names: str | None = Field(
        None,
        description="Label names, comma-separated, one per distinct label in increasing "
        "label order; default: the labels as text.",
        examples=["torso,head,arm"],
    )
    method: ShdfMethodName | None = Field(
        None,
        description="ShDF method of the training meshes (their cached ShDF is reused); "
        "default: the service's.",
        examples=["auto"],
    )
    seed: int = Field(0, json_schema_extra=SEED_BOUNDS, description="ShDF seed.", examples=[0])
    smoothing: float | None = Field(
        None,
        json_schema_extra=documented_bounds(0, MAX_SMOOTHING),
        description="Graph-cut smoothing of the labels; default: the library's (0.003).",
        examples=[0.003],
    )
