"""Every key a result is stored under: one function per kind of result.

A key names the mesh (its content hash, the group that deleting the mesh removes) and
everything the result depends on besides it. The ShDF's key carries the package
version and ``constants.ALGORITHM_VERSION``, and every later result's key starts from
the ShDF's (``shdf_version``), so an upgrade that changes results never serves the old
ones. Service replicas and batch workers share entries through these keys: changing a
key's text orphans every stored entry of its kind (``tests/store/test_keys.py`` holds
the golden keys).
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict
from pathlib import Path
from typing import TYPE_CHECKING

from neural_shdf import __version__
from neural_shdf.constants import ALGORITHM_VERSION
from neural_shdf.errors import ModelUnavailableError, ParameterError
from neural_shdf.shdf.neural.inference import file_sha256
from neural_shdf.shdf.stage import ShdfParams, uses_model

if TYPE_CHECKING:
    from neural_shdf.segment import SegmentParams
    from neural_shdf.shdf.stage import RawMethod
    from neural_shdf.unwrap import UnwrapParams


# -- meshes ---------------------------------------------------------------------------


def mesh_key(mesh_id: str) -> str:
    """An uploaded mesh's geometry (``codec.mesh_arrays``)."""
    return f"{mesh_id}:mesh"


def meta_key(mesh_id: str) -> str:
    """An uploaded mesh's metadata (JSON); results are stored under it as their guard."""
    return f"{mesh_id}:meta"


def source_key(mesh_id: str, source_id: str) -> str:
    """An upload's own file (its bytes and format), for results written back into it."""
    return f"{mesh_id}:source:{source_id}"


def face_graph_key(mesh_id: str) -> str:
    """A mesh's face graph (process memory only: rebuilt faster than read back)."""
    return f"{mesh_id}:graph"


def crease_graph_key(mesh_id: str) -> str:
    """A mesh's crease-refinement graph (process memory only)."""
    return f"{mesh_id}:creases"


# -- the ShDF -------------------------------------------------------------------------


def model_version(path: Path) -> str | None:
    """Short hash of the model card (which holds the weights' checksum and feature version);
    of the weights when there is no card; None when the model is absent."""
    card = path.with_suffix(".json")
    if card.is_file():
        return hashlib.sha256(card.read_bytes()).hexdigest()[:16]
    if path.is_file():
        return file_sha256(path)[:16]
    return None


def shdf_params_digest(method: RawMethod, params: ShdfParams, model_sha256: str | None) -> str:
    """Stable digest of what a ShDF depends on besides the mesh: the resolved method,
    the model's checksum (neural only) and every parameter the method reads."""
    used = asdict(params)
    if method == "exact":
        for name in ("seed", "samples", "sample_sets"):
            used.pop(name)
    if method != "neural":
        used.pop("sample_sets", None)
    if method != "sampled":
        used.pop("max_samples")
    if method == "neural":
        if not model_sha256:
            raise ParameterError("a neural ShDF key needs the model's checksum")
        used["model"] = model_sha256
    used["method"] = method
    return hashlib.sha256(json.dumps(used, sort_keys=True).encode()).hexdigest()[:24]


def shdf_version(method: str, model_version: str | None, seed: int = 0) -> str:
    """What a cached ShDF depends on besides the mesh: the code and algorithm versions
    (``constants.ALGORITHM_VERSION``; every other result's key starts from this one, so
    it carries that version too), the method (resolved by callers that know the mesh),
    the model's version where the method can run the network (refused when there is
    none) and every ShDF parameter (``shdf_params_digest``)."""
    if uses_model(method) and not model_version:
        raise ModelUnavailableError(f"the ShDF method {method!r} needs a neural model; none found")
    model = model_version if uses_model(method) else None
    digest = shdf_params_digest(method, ShdfParams(seed=seed), model)  # type: ignore[arg-type]
    return f"{__version__}:a{ALGORITHM_VERSION}:{digest}"


def shdf_key(mesh_id: str, method: str, seed: int, model_version: str | None) -> str:
    """A mesh's per-triangle ShDF (``codec.shdf_arrays``); ``method`` is a resolved
    producer (not ``auto``)."""
    return f"{mesh_id}:shdf:{shdf_version(method, model_version, seed)}"


# -- segmentations and what is made from them ----------------------------------------


#: Version of what ``symmetry`` does to the labels (in its results' keys): 1, the ShDF
#: evidence averaged across the plane; 2, also the cuts made mirror images.
SYMMETRY_VERSION = 2


def segment_params_digest(params: SegmentParams) -> str:
    """Stable hash of the segmentation parameters (a key's parameter part). ``symmetry``
    off is left out, so the keys of results made before the option existed still hold;
    on, it is the option's version (``SYMMETRY_VERSION``): results of an earlier version
    of the option are never served for it."""
    used: dict[str, object] = asdict(params)
    if used["symmetry"]:
        used["symmetry"] = SYMMETRY_VERSION
    else:
        del used["symmetry"]
    return hashlib.sha256(json.dumps(used, sort_keys=True).encode()).hexdigest()[:20]


def segmentation_key(mesh_id: str, shdf_version: str, params: SegmentParams) -> str:
    """A segmentation: the mesh, the code version, the ShDF it starts from
    (``shdf_version``) and its parameters."""
    return f"{mesh_id}:seg:{__version__}:{shdf_version}:{segment_params_digest(params)}"


def segmentation_basis_key(
    mesh_id: str, shdf_version: str, clusters: int | None, seed: int, symmetry: bool = False
) -> str:
    """What a graph-cut segmentation keeps per mesh, ShDF, clusters, seed and symmetry, so
    that a new smoothing or part count only re-cuts (process memory only)."""
    return f"{mesh_id}:basis:{shdf_version}:{clusters}:{seed}" + (":sym" if symmetry else "")


#: Version of the unwrap's output (in atlas keys, beside the unwrap parameters), raised when
#: the same parameters give other UVs: 2, every corner mapped through its chart's packing
#: (the atlases of 1 could hold a dense scan's thin triangles flipped across the atlas).
ATLAS_VERSION = 2


def atlas_key(segmentation_key: str, unwrap: UnwrapParams) -> str:
    """A UV atlas by part: its segmentation's key plus the unwrap parameters and
    ``ATLAS_VERSION``."""
    used: dict[str, object] = {**asdict(unwrap), "atlas_version": ATLAS_VERSION}
    digest = hashlib.sha256(json.dumps(used, sort_keys=True).encode())
    return f"{segmentation_key}:uv:{digest.hexdigest()[:20]}"


def atlas_png_key(atlas_key: str) -> str:
    """The PNG picture of an atlas's layout."""
    return f"{atlas_key}:png"


# -- part labellers (named parts) ----------------------------------------------------


def labeler_group(labeler_id: str) -> str:
    """The group of a stored labeller's entries (deleting the labeller removes it)."""
    return f"labeler:{labeler_id}"


def labeler_file_key(labeler_id: str) -> str:
    """A stored labeller's file (``labeling.save_labeler``'s bytes, as one uint8 array)."""
    return f"{labeler_group(labeler_id)}:file"


def labeler_meta_key(labeler_id: str) -> str:
    """A stored labeller's description (JSON: names, labels, training summary, size)."""
    return f"{labeler_group(labeler_id)}:meta"


def labeler_index_key() -> str:
    """The ids of the stored labellers (JSON list), for listing them."""
    return "labelers:index"


def labeling_key(mesh_id: str, shdf_version: str, labeler_id: str) -> str:
    """A mesh's labels by a labeller: the mesh, the ShDF they start from and the labeller
    (content-addressed, so its id covers its trees, names and feature version)."""
    return f"{mesh_id}:labels:{__version__}:{shdf_version}:{labeler_id}"


# -- bookkeeping ----------------------------------------------------------------------


def job_key(job_id: str) -> str:
    """A job's record (JSON)."""
    return f"job:{job_id}"


def lock_key(key: str) -> str:
    """The lock that computing the result under ``key`` holds (a lease)."""
    return f"lock:{key}"


def lease_key(key: str) -> str:
    """Where a backend stores the lease named ``key``."""
    return f"lease:{key}"
