"""The panel's settings (saved with the scene) and the running task's state (not saved)."""

from __future__ import annotations

import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, StringProperty

#: Custom properties an object keeps about its last segmentation.
MESH_ID_KEY = "neural_shdf_mesh_id"
DIGEST_KEY = "neural_shdf_digest"
SERVER_KEY = "neural_shdf_server"
PARTS_KEY = "neural_shdf_part_count"
#: Named parts: the labeller's id and its names by integer (JSON), kept on the object.
LABELER_KEY = "neural_shdf_labeler"
LABEL_NAMES_KEY = "neural_shdf_label_names"
#: The segmentation options of the last run (JSON) and the hand-edit document (JSON list).
OPTIONS_KEY = "neural_shdf_options"
EDITS_KEY = "neural_shdf_edits"


class NeuralShdfSettings(bpy.types.PropertyGroup):
    """Where the service is and how to segment."""

    server_url: StringProperty(  # type: ignore[valid-type]
        name="Server",
        description="Base URL of the neural-shdf service (neural-shdf serve)",
        default="http://127.0.0.1:8000",
    )
    method: EnumProperty(  # type: ignore[valid-type]
        name="Method",
        description="How the Shape Diameter Function is computed",
        items=[
            ("default", "Service Default", "The method the service uses when none is named"),
            ("auto", "Auto", "The fastest method that meets the fidelity target, per mesh"),
            ("exact", "Exact", "Ray-cast reference"),
            ("sampled", "Sampled", "Rays cast at surface samples only (fast on large meshes)"),
            ("neural", "Neural", "Predicted by the graph network"),
        ],
        default="default",
    )
    partitioner: EnumProperty(  # type: ignore[valid-type]
        name="Partitioner",
        items=[
            ("graphcut", "Graph cut", "Parts along the shape's thickness changes"),
            ("metis", "METIS", "Balanced parts, exactly as many as asked"),
        ],
        default="graphcut",
    )
    clusters: IntProperty(  # type: ignore[valid-type]
        name="Clusters",
        description="Gaussian mixture components (level of detail); 0: chosen per mesh",
        default=9,
        min=0,
        max=32,
    )
    smoothing: FloatProperty(  # type: ignore[valid-type]
        name="Smoothing",
        description="Smoothness weight of the graph cut (higher: fewer, smoother parts)",
        default=0.06,
        min=0.0,
        max=100.0,
        soft_max=2.0,
    )
    use_parts: BoolProperty(  # type: ignore[valid-type]
        name="Part Count",
        description="Ask for a number of parts (off: the service chooses it)",
        default=False,
    )
    parts: IntProperty(  # type: ignore[valid-type]
        name="Parts",
        description="Number of parts: a cut of the part tree (graph cut; instant on a re-run) "
        "or exactly this many (METIS)",
        default=4,
        min=1,
        max=10000,
        soft_max=64,
    )
    assign_materials: BoolProperty(  # type: ignore[valid-type]
        name="Material per Part",
        description="Show one material per part (added after the object's own materials, "
        "which stay; each polygon's own material returns when segmenting with this off)",
        default=False,
    )
    split_parts: BoolProperty(  # type: ignore[valid-type]
        name="Split into Objects",
        description="Also make one object per part (in a new collection; the source is hidden)",
        default=False,
    )
    labeler_file: StringProperty(  # type: ignore[valid-type]
        name="Labeller",
        description="A part labeller file (.npz, from 'neural-shdf labeler train' or Learn "
        "from Selected): parts are then its named labels. Empty: segment",
        default="",
        subtype="FILE_PATH",
    )
    label_attribute: StringProperty(  # type: ignore[valid-type]
        name="Label Attribute",
        description="Integer face attribute holding each polygon's label: written with a "
        "labeller, read by Learn from Selected",
        default="neural_shdf_label",
    )
    label_names: StringProperty(  # type: ignore[valid-type]
        name="Label Names",
        description="Learn from Selected: names of the labels, comma-separated, one per "
        "distinct label in increasing order (empty: the labels as text)",
        default="",
    )
    learn_output: StringProperty(  # type: ignore[valid-type]
        name="Save Labeller As",
        description="Where Learn from Selected saves the labeller it trained (it then "
        "becomes the panel's labeller)",
        default="//labeler.npz",
        subtype="FILE_PATH",
    )

    def options(self) -> dict[str, object]:
        """The request's segmentation options."""
        options: dict[str, object] = {
            "partitioner": self.partitioner,
            "clusters": self.clusters,
            "smoothing": round(self.smoothing, 6),
        }
        if self.method != "default":
            options["method"] = self.method
        if self.use_parts:
            options["parts"] = self.parts
        return options


class NeuralShdfState(bpy.types.PropertyGroup):
    """Progress of the running segmentation, shown by the panel."""

    running: BoolProperty(default=False)  # type: ignore[valid-type]
    progress: FloatProperty(default=0.0, min=0.0, max=1.0, subtype="FACTOR")  # type: ignore[valid-type]
    status: StringProperty(default="")  # type: ignore[valid-type]


CLASSES = (NeuralShdfSettings, NeuralShdfState)


def register() -> None:
    bpy.types.Scene.neural_shdf = bpy.props.PointerProperty(type=NeuralShdfSettings)
    bpy.types.WindowManager.neural_shdf_state = bpy.props.PointerProperty(type=NeuralShdfState)


def unregister() -> None:
    del bpy.types.WindowManager.neural_shdf_state
    del bpy.types.Scene.neural_shdf
