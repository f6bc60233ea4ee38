"""Entries' framing and encodings: any damage is detected, arrays never pickled."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from neural_shdf.mesh import TriangleMesh
from neural_shdf.store.codec import (
    CorruptEntryError,
    decode_arrays,
    encode_arrays,
    mesh_arrays,
    mesh_from_arrays,
    seal,
    seal_arrays,
    shdf_arrays,
    shdf_from_arrays,
    unseal,
)


@given(st.binary(max_size=512))
@settings(max_examples=50, deadline=None)
def test_seal_round_trip_and_any_change_is_detected(payload):
    blob = seal(payload)
    assert unseal(blob) == payload
    for index in {0, len(blob) // 2, len(blob) - 1}:
        damaged = bytearray(blob)
        damaged[index] ^= 0x01
        with pytest.raises(CorruptEntryError):
            unseal(bytes(damaged))
    with pytest.raises(CorruptEntryError):
        unseal(blob[:-1] if payload else blob[:10])


def test_arrays_round_trip_without_pickles():
    arrays = {"a": np.arange(5.0), "b": np.array(3), "c": np.zeros((2, 3), np.int32)}
    decoded = decode_arrays(encode_arrays(arrays))
    for name, value in arrays.items():
        np.testing.assert_array_equal(decoded[name], value)
        assert decoded[name].dtype == value.dtype
    with pytest.raises(CorruptEntryError):
        decode_arrays(b"PK\x03\x04 not really a zip")


def test_meshes_and_shdf_round_trip_through_a_sealed_entry():
    # A quad (two triangles) and an input face that produced none: all of it kept.
    vertices = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    mesh = TriangleMesh(vertices, faces, np.array([0, 0]), input_face_count=2)
    stored = mesh_from_arrays(decode_arrays(unseal(seal(encode_arrays(mesh_arrays(mesh))))))
    np.testing.assert_array_equal(stored.vertices, mesh.vertices)
    np.testing.assert_array_equal(stored.faces, mesh.faces)
    np.testing.assert_array_equal(stored.face_origin, mesh.face_origin)
    assert stored.input_face_count == 2
    values = np.linspace(0.0, 1.0, 2)
    decoded = shdf_from_arrays(decode_arrays(encode_arrays(shdf_arrays(values))))
    assert decoded.tobytes() == values.tobytes()
    with pytest.raises(KeyError):
        shdf_from_arrays(mesh_arrays(mesh))  # another kind's entry: not a ShDF


def test_seal_arrays_verifies_and_decodes_like_seal_of_encode_arrays(box_mesh):
    arrays = mesh_arrays(box_mesh)
    sealed = seal_arrays(arrays)
    for blob in (sealed, seal(encode_arrays(arrays))):
        stored = mesh_from_arrays(decode_arrays(unseal(blob)))
        np.testing.assert_array_equal(stored.faces, box_mesh.faces)
        np.testing.assert_array_equal(stored.vertices, box_mesh.vertices)
    damaged = bytearray(sealed)
    damaged[-100] ^= 1
    with pytest.raises(CorruptEntryError):
        unseal(bytes(damaged))
