"""How entries are framed and encoded: ``MAGIC + sha256(payload) + payload``, arrays as
an uncompressed .npz (no pickles), meshes and ShDF values as named arrays.

A blob whose checksum does not verify (corrupt, truncated, written by something else)
raises CorruptEntryError: the cache drops it and recomputes, never serves it.
"""

from __future__ import annotations

import hashlib
import io
from typing import Any

import numpy as np
from numpy.typing import NDArray

from neural_shdf.mesh import TriangleMesh

MAGIC = b"NSHDF1\n"
_DIGEST_SIZE = 32


class CorruptEntryError(ValueError):
    """A cache entry failed its checksum or could not be decoded."""


def seal(payload: bytes) -> bytes:
    """Frame ``payload`` with its checksum."""
    return MAGIC + hashlib.sha256(payload).digest() + payload


def seal_arrays(arrays: dict[str, NDArray[Any]]) -> bytes:
    """``seal(encode_arrays(arrays))`` written in one buffer: the .npz goes after room for the
    frame and the checksum is hashed from a view, so a large mesh is copied once, not three
    times (each copy of a million-face mesh holds the GIL beside the service's event loop)."""
    head = len(MAGIC) + _DIGEST_SIZE
    buffer = io.BytesIO()
    buffer.write(MAGIC + bytes(_DIGEST_SIZE))
    named: dict[str, Any] = {name: np.asarray(value) for name, value in arrays.items()}
    np.savez(buffer, **named)  # zip offsets relative to its start: the payload stands alone
    with buffer.getbuffer() as view:
        view[len(MAGIC) : head] = hashlib.sha256(view[head:]).digest()
    return buffer.getvalue()


def unseal(blob: bytes) -> bytes:
    """The payload of a sealed blob; CorruptEntryError when it does not verify."""
    head = len(MAGIC) + _DIGEST_SIZE
    if not isinstance(blob, bytes | bytearray | memoryview) or len(blob) < head:
        raise CorruptEntryError("entry too short")
    blob = bytes(blob)
    if blob[: len(MAGIC)] != MAGIC:
        raise CorruptEntryError("bad magic")
    payload = blob[head:]
    if hashlib.sha256(payload).digest() != blob[len(MAGIC) : head]:
        raise CorruptEntryError("checksum mismatch")
    return payload


def encode_arrays(arrays: dict[str, NDArray[Any]]) -> bytes:
    """Arrays as an uncompressed .npz (no pickles)."""
    buffer = io.BytesIO()
    named: dict[str, Any] = {name: np.asarray(value) for name, value in arrays.items()}
    np.savez(buffer, **named)
    return buffer.getvalue()


def decode_arrays(payload: bytes) -> dict[str, NDArray[Any]]:
    try:
        with np.load(io.BytesIO(payload), allow_pickle=False) as npz:
            return {name: npz[name] for name in npz.files}
    except Exception as exc:  # noqa: BLE001 - any decoding failure means a corrupt entry
        raise CorruptEntryError(f"undecodable arrays: {exc}") from exc


def mesh_arrays(mesh: TriangleMesh) -> dict[str, NDArray[Any]]:
    """A mesh as the arrays it is stored as (its input face order kept)."""
    return {
        "vertices": mesh.vertices,
        "faces": mesh.faces,
        "face_origin": mesh.face_origin,
        "input_face_count": np.array(mesh.input_face_count),
    }


def mesh_from_arrays(arrays: dict[str, NDArray[Any]]) -> TriangleMesh:
    """The mesh ``mesh_arrays`` stored."""
    return TriangleMesh(
        arrays["vertices"],
        arrays["faces"],
        arrays["face_origin"],
        int(arrays["input_face_count"]),
    )


def shdf_arrays(values: NDArray[Any]) -> dict[str, NDArray[Any]]:
    """A per-triangle ShDF as the arrays it is stored as."""
    return {"shdf": values}


def shdf_from_arrays(arrays: dict[str, NDArray[Any]]) -> NDArray[Any]:
    """The ShDF ``shdf_arrays`` stored (KeyError when the entry holds none)."""
    return arrays["shdf"]
