"""Stored part labellers: validate an uploaded file, store it under its content id, list,
load and delete them (over the shared cache, like meshes, so they survive restarts)."""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from neural_shdf.api.errors import ApiError, not_found
from neural_shdf.api.metrics import Metrics
from neural_shdf.api.settings import Settings
from neural_shdf.errors import ParameterError
from neural_shdf.labeling.labeler import check_compatible
from neural_shdf.labeling.model import Labeler, LabelerFileError, labeler_id, load_labeler
from neural_shdf.store.cache import ResultCache
from neural_shdf.store.keys import (
    labeler_file_key,
    labeler_group,
    labeler_index_key,
    labeler_meta_key,
)

#: The group of the index entry (never deleted with a labeller).
INDEX_GROUP = "labelers"


def labeler_missing(identifier: str) -> ApiError:
    """The 404 of a labeller that is not stored, saying what to do."""
    error = not_found("labeler", identifier)
    error.message += " (never uploaded, deleted or evicted from the cache: upload it again)"
    return error


def describe(labeler: Labeler, identifier: str, size: int) -> dict[str, Any]:
    """What the API tells about a labeller (``schemas.LabelerInfo``)."""
    training = labeler.metadata.get("training", {})
    return {
        "labeler_id": identifier,
        "label_names": list(labeler.label_names),
        "label_values": [int(v) for v in labeler.label_values],
        "feature_version": int(labeler.metadata.get("feature_version", 0)),
        "smoothing": float(labeler.metadata.get("smoothing", 0.0)),
        "training_meshes": int(training.get("meshes", 0)),
        "size_bytes": size,
        "stored_at": time.time(),
    }


class LabelerStore:
    """Labeller files over the shared cache (memory first), by content id."""

    def __init__(self, settings: Settings, cache: ResultCache, metrics: Metrics) -> None:
        self.settings = settings
        self.cache = cache
        self.metrics = metrics

    def parse(self, data: bytes) -> Labeler:
        """The labeller in an uploaded file, checked before use: size, format, version,
        checksum, tree structure (``load_labeler``, no pickle) and feature version."""
        if len(data) > self.settings.max_labeler_bytes:
            raise ApiError(
                413,
                "payload_too_large",
                f"the labeller file has {len(data)} bytes, more than the limit of "
                f"{self.settings.max_labeler_bytes}",
                {"max_labeler_bytes": self.settings.max_labeler_bytes},
            )
        labeler = load_labeler(data)
        try:
            check_compatible(labeler)
        except ParameterError as error:
            raise LabelerFileError(str(error)) from error
        return labeler

    def store(self, data: bytes, labeler: Labeler) -> dict[str, Any]:
        """Store a parsed labeller (if new) and list it; its description."""
        identifier = labeler_id(labeler)
        meta = self.cache.get_json(labeler_meta_key(identifier))
        if meta is None or self.cache.backend.exists(labeler_file_key(identifier)) is False:
            meta = describe(labeler, identifier, len(data))
            group = labeler_group(identifier)
            # keep_local: like an uploaded mesh, only the client could restore it.
            array = np.frombuffer(data, dtype=np.uint8)
            self.cache.put_arrays(
                labeler_file_key(identifier), {"bytes": array}, group=group, keep_local=True
            )
            self.cache.put_json(labeler_meta_key(identifier), meta, group=group, keep_local=True)
        self.cache.remember(labeler_file_key(identifier), labeler)
        self._update_index(lambda ids: ids if identifier in ids else [*ids, identifier])
        return meta

    def _update_index(self, change: Any) -> list[str]:
        """Rewrite the index of ids under its lock (concurrent uploads and deletes)."""
        key = labeler_index_key()
        with self.cache.lock(key, self.settings.lock_timeout_s):
            ids = self.cache.get_json(key) or []
            updated = change(list(ids))
            if updated != ids:
                self.cache.put_json(key, updated, group=INDEX_GROUP, keep_local=True)
            return updated

    def meta(self, identifier: str) -> dict[str, Any]:
        """A stored labeller's description; 404 when it is not stored."""
        meta = self.cache.get_json(labeler_meta_key(identifier))
        if meta is None or self.cache.backend.exists(labeler_file_key(identifier)) is False:
            raise labeler_missing(identifier)
        return meta

    def list(self, offset: int = 0, limit: int | None = None) -> tuple[list[dict[str, Any]], int]:
        """(descriptions of the stored labellers ``offset`` to ``offset + limit`` oldest
        first, how many are indexed); only the page's entries are read, and ids whose
        entries are gone (evicted, say) are left out of it."""
        ids = self.cache.get_json(labeler_index_key()) or []
        page = ids[offset:] if limit is None else ids[offset : offset + limit]
        found = [self.cache.get_json(labeler_meta_key(i)) for i in page]
        return [meta for meta in found if meta is not None], len(ids)

    def file(self, identifier: str) -> bytes:
        """A stored labeller's file as uploaded; 404 when it is not stored."""
        arrays = self.cache.get_arrays(labeler_file_key(identifier))
        if arrays is None or "bytes" not in arrays:
            raise labeler_missing(identifier)
        return arrays["bytes"].tobytes()

    def load(self, identifier: str) -> Labeler:
        """A stored labeller (memory first, unless deleted meanwhile); 404 when absent."""
        key = labeler_file_key(identifier)
        labeler = self.cache.recall(key)
        if (
            labeler is not None
            and self.cache.backend.exists(labeler_meta_key(identifier)) is not False
        ):
            return labeler
        labeler = load_labeler(self.file(identifier))  # checked again: the store may be shared
        self.cache.remember(key, labeler)
        return labeler

    def delete(self, identifier: str) -> None:
        """Delete a labeller; 404 when there was nothing. Labels made with it stay
        cached under the meshes but are never served once it is gone."""
        existed = self.cache.get_json(labeler_meta_key(identifier)) is not None
        removed = self.cache.delete_group(labeler_group(identifier)) > 0
        self._update_index(lambda ids: [i for i in ids if i != identifier])
        if not (removed or existed):
            raise labeler_missing(identifier)
