"""The keys results are stored under: byte for byte those of entries already stored (a
changed key orphans every entry of its kind), and covering everything results depend on."""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict

import pytest

from neural_shdf import __version__
from neural_shdf.constants import ALGORITHM_VERSION
from neural_shdf.errors import ModelUnavailableError, ParameterError
from neural_shdf.segment import SegmentParams
from neural_shdf.shdf.stage import DEFAULT_SAMPLES, ShdfParams
from neural_shdf.store import keys
from neural_shdf.store.keys import shdf_params_digest
from neural_shdf.unwrap import UnwrapParams

MESH = "0" * 64


def test_keys_are_those_of_entries_already_stored():
    """Golden keys, written by the code before ``store`` existed (version 0.1.0,
    ALGORITHM_VERSION 1); only the package and algorithm versions may change in them, and
    the segmentation parameters' digest when a default changes (``reference_faces``'
    default became 60,000 with ALGORITHM_VERSION 4: 414bf0d6c3ff6c837360 and
    abf72f349aece7c1b1db before; the unwrap parameters' when ``straighten`` came and
    ``max_splits`` became 6, so no atlas of the older unwrap is served: 203b420a2ae496b19c77
    before, then 05554be3b0150226fa47 until ``ATLAS_VERSION`` 2 joined the digest)."""
    shdf = f"{__version__}:a{ALGORITHM_VERSION}:29858baf9f98992f4f770532"
    assert keys.shdf_version("exact", None, 0) == shdf
    assert keys.shdf_key(MESH, "exact", 0, None) == f"{MESH}:shdf:{shdf}"
    assert keys.shdf_key(MESH, "sampled", 3, None) == (
        f"{MESH}:shdf:{__version__}:a{ALGORITHM_VERSION}:d55a35c25421866f30f01df4"
    )
    assert keys.shdf_key(MESH, "neural", 0, "abcdef0123456789") == (
        f"{MESH}:shdf:{__version__}:a{ALGORITHM_VERSION}:93e1747d37f0efc39fbae398"
    )
    segmentation = keys.segmentation_key(MESH, shdf, SegmentParams())
    assert segmentation == f"{MESH}:seg:{__version__}:{shdf}:51765679819fcadec91c"
    metis = SegmentParams(smoothing=0.5, clusters=4, partitioner="metis")
    assert keys.segmentation_key(MESH, shdf, metis).endswith(f":{shdf}:b29cf18113fe3d7c8076")
    atlas = keys.atlas_key(segmentation, UnwrapParams())
    assert atlas == f"{segmentation}:uv:52f119a5fb576f584832"
    assert keys.atlas_png_key(atlas) == f"{atlas}:png"
    assert keys.segmentation_basis_key(MESH, shdf, 4, 0) == f"{MESH}:basis:{shdf}:4:0"
    assert (keys.mesh_key(MESH), keys.meta_key(MESH)) == (f"{MESH}:mesh", f"{MESH}:meta")
    assert (keys.face_graph_key(MESH), keys.crease_graph_key(MESH)) == (
        f"{MESH}:graph",
        f"{MESH}:creases",
    )
    assert keys.job_key("j1") == "job:j1"
    assert keys.lease_key(keys.lock_key(f"{MESH}:mesh")) == f"lease:lock:{MESH}:mesh"


def test_every_key_of_a_result_is_grouped_by_its_mesh():
    """Deleting a mesh deletes the group named by its id: every result key starts with it."""
    shdf = keys.shdf_version("exact", None, 0)
    segmentation = keys.segmentation_key(MESH, shdf, SegmentParams())
    for key in (
        keys.mesh_key(MESH),
        keys.meta_key(MESH),
        keys.shdf_key(MESH, "exact", 0, None),
        segmentation,
        keys.atlas_png_key(keys.atlas_key(segmentation, UnwrapParams())),
        keys.labeling_key(MESH, shdf, "f" * 64),
    ):
        assert key.startswith(f"{MESH}:")


def test_a_labellers_entries_are_grouped_by_its_id_and_its_labels_by_mesh_and_labeller():
    labeler = "f" * 64
    group = keys.labeler_group(labeler)
    assert group == f"labeler:{labeler}"
    for key in (keys.labeler_file_key(labeler), keys.labeler_meta_key(labeler)):
        assert key.startswith(f"{group}:")
    assert not keys.labeler_index_key().startswith(group)
    shdf = keys.shdf_version("exact", None, 0)
    assert keys.labeling_key(MESH, shdf, labeler) == f"{MESH}:labels:{__version__}:{shdf}:{labeler}"
    assert keys.labeling_key(MESH, shdf, labeler) != keys.labeling_key(MESH, shdf, "e" * 64)


def test_a_neural_key_needs_the_model_version():
    with pytest.raises(ModelUnavailableError, match="neural model"):
        keys.shdf_version("neural", None, 0)
    assert keys.shdf_version("exact", None, 0) == keys.shdf_version("exact", "ab" * 8, 0)


def test_shdf_digest_covers_method_model_and_every_parameter() -> None:
    base = ShdfParams()
    digests = {
        shdf_params_digest("exact", base, None),
        shdf_params_digest("sampled", base, None),
        shdf_params_digest("neural", base, "a" * 64),
        shdf_params_digest("neural", base, "b" * 64),
        shdf_params_digest("exact", ShdfParams(ray_count=16), None),
        shdf_params_digest("exact", ShdfParams(window_size=3), None),
        shdf_params_digest("sampled", ShdfParams(samples=1024), None),
        shdf_params_digest("sampled", ShdfParams(seed=1), None),
        shdf_params_digest("neural", ShdfParams(sample_sets=3), "a" * 64),
        shdf_params_digest("sampled", ShdfParams(max_samples=8192), None),
    }
    assert len(digests) == 10
    # Parameters a producer never reads do not split its cache.
    exact = shdf_params_digest("exact", base, None)
    assert shdf_params_digest("exact", ShdfParams(seed=5, samples=64), None) == exact
    fixed = ShdfParams(max_samples=DEFAULT_SAMPLES)
    neural = shdf_params_digest("neural", base, "a" * 64)
    assert shdf_params_digest("neural", fixed, "a" * 64) == neural
    with pytest.raises(ParameterError, match="checksum"):
        shdf_params_digest("neural", base, None)


def test_segmentation_keys_cover_every_parameter():
    shdf = keys.shdf_version("exact", None, 0)
    variants = [
        SegmentParams(),
        SegmentParams(smoothing=0.5),
        SegmentParams(clusters=3),
        SegmentParams(parts=4),
        SegmentParams(partitioner="metis", clusters=3),
        SegmentParams(seed=1),
        SegmentParams(refine=True),
    ]
    assert len({keys.segmentation_key(MESH, shdf, params) for params in variants}) == len(variants)
    other_shdf = keys.shdf_version("sampled", None, 0)
    assert keys.segmentation_key(MESH, shdf, SegmentParams()) != keys.segmentation_key(
        MESH, other_shdf, SegmentParams()
    )


def test_symmetric_segmentations_are_keyed_by_the_options_version():
    """``symmetry`` on is keyed by ``SYMMETRY_VERSION``: results of the option's version 1
    (evidence averaged only), stored under its ``true``, are never served as version 2's."""
    shdf = keys.shdf_version("exact", None, 0)
    symmetric = SegmentParams(symmetry=True)
    version_1 = hashlib.sha256(json.dumps(asdict(symmetric), sort_keys=True).encode()).hexdigest()[
        :20
    ]
    assert keys.SYMMETRY_VERSION == 2
    key = keys.segmentation_key(MESH, shdf, symmetric)
    assert not key.endswith(version_1)
    assert key != keys.segmentation_key(MESH, shdf, SegmentParams())
