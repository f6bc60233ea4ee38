"""Array sizes declared in a USD crate (``.usdc``) file, read from its tables alone.

usd-core decompresses a crate array when its value is asked for, and compressed
integer arrays shrink thousands of times (20 million equal face sizes take 20 kB), so
a small upload could make the reader allocate gigabytes. Every array value's element
count is stored uncompressed in front of its data; this module finds them from the
FIELDS table (value representations, LZ4-compressed) and the time-sample tables they
point to, so the reader can refuse before usd-core builds any array. Layout: Pixar's
``pxr/usd/sdf/crateFile.cpp``.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator

from neural_shdf.errors import MeshParseError

_IDENT = b"PXR-USDC"
_IS_ARRAY = 1 << 63
_IS_INLINED = 1 << 62
_PAYLOAD = (1 << 48) - 1
_TYPE_TIME_SAMPLES = 46
#: Most value representations a FIELDS table may hold per byte of file (each is 8 bytes
#: before LZ4; a larger claim is a decompression bomb in the table itself).
_MAX_FIELDS_PER_BYTE = 64


def _bad(what: str) -> MeshParseError:
    return MeshParseError(f"the USD crate file is corrupt: {what}")


def _u64(data: bytes, offset: int) -> int:
    if offset < 0 or offset + 8 > len(data):
        raise _bad(f"a table at byte {offset} lies beyond the end of the file")
    value: int = struct.unpack_from("<Q", data, offset)[0]
    return value


def lz4_block(source: bytes, size: int) -> bytes:
    """Decompress one LZ4 block of at most ``size`` bytes (the format's reference rules)."""
    out = bytearray()
    i = 0
    while i < len(source):
        token = source[i]
        i += 1
        literal = token >> 4
        if literal == 15:
            while True:
                extra = source[i]
                i += 1
                literal += extra
                if extra != 255:
                    break
        out += source[i : i + literal]
        i += literal
        if i >= len(source):
            break
        offset = source[i] | source[i + 1] << 8
        i += 2
        match = (token & 15) + 4
        if token & 15 == 15:
            while True:
                extra = source[i]
                i += 1
                match += extra
                if extra != 255:
                    break
        if offset == 0 or offset > len(out) or len(out) + match > size:
            raise _bad("its compressed table is invalid")
        start = len(out) - offset
        if match <= offset:
            out += out[start : start + match]
        else:  # overlapping copy: the repeated pattern
            pattern = bytes(out[start:])
            out += (pattern * (match // offset + 1))[:match]
        if len(out) > size:
            raise _bad("its compressed table is larger than declared")
    return bytes(out)


def _fast_decompress(source: bytes, size: int) -> bytes:
    """usd-core's TfFastCompression: a chunk count byte, then LZ4 block(s)."""
    if not source:
        raise _bad("an empty compressed table")
    chunks = source[0]
    if chunks == 0:
        return lz4_block(source[1:], size)
    parts: list[bytes] = []
    at = 1
    for _ in range(chunks):
        length = struct.unpack_from("<i", source, at)[0]
        parts.append(lz4_block(source[at + 4 : at + 4 + length], size - sum(map(len, parts))))
        at += 4 + length
    return b"".join(parts)


def _value_reps(data: bytes) -> tuple[tuple[int, ...], list[int]]:
    """(version, every value representation in the FIELDS table)."""
    if len(data) < 24 or not data.startswith(_IDENT):
        raise _bad("no crate header")
    version = tuple(data[8:11])
    toc = _u64(data, 16)
    sections = _u64(data, toc)
    if sections > 64:
        raise _bad(f"{sections} sections")
    fields_start = None
    for k in range(sections):
        at = toc + 8 + 32 * k
        name = data[at : at + 16].split(b"\0", 1)[0]
        if name == b"FIELDS":
            fields_start = _u64(data, at + 16)
    if fields_start is None:
        return version, []
    if version < (0, 4, 0):
        raise _bad(f"crate version {'.'.join(map(str, version))} is too old; re-save it")
    count = _u64(data, fields_start)
    if count > _MAX_FIELDS_PER_BYTE * len(data):
        raise _bad(f"its FIELDS table claims {count} fields")
    tokens_size = _u64(data, fields_start + 8)
    reps_at = fields_start + 16 + tokens_size
    reps_size = _u64(data, reps_at)
    compressed = data[reps_at + 8 : reps_at + 8 + reps_size]
    raw = _fast_decompress(compressed, 8 * count)
    if len(raw) != 8 * count:
        raise _bad("its FIELDS table is truncated")
    return version, list(struct.unpack(f"<{count}Q", raw))


def _array_size(data: bytes, rep: int, version: tuple[int, ...]) -> int:
    offset = rep & _PAYLOAD
    if offset == 0:
        return 0
    if version < (0, 5, 0):
        offset += 4  # a rank, no longer written
    if version < (0, 7, 0):
        if offset + 4 > len(data):
            raise _bad(f"an array at byte {offset} lies beyond the end of the file")
        size: int = struct.unpack_from("<I", data, offset)[0]
        return size
    return _u64(data, offset)


def _time_sample_reps(data: bytes, rep: int) -> list[int]:
    """The value representations of a time-samples value (one per sample)."""
    at = rep & _PAYLOAD
    at += struct.unpack_from("<q", data, at)[0] if at + 8 <= len(data) else 0
    at += 8  # past the times' value representation
    if at + 8 > len(data):
        raise _bad("a time-samples table lies beyond the end of the file")
    at += struct.unpack_from("<q", data, at)[0]
    count = _u64(data, at)
    if at + 8 + 8 * count > len(data):
        raise _bad("a time-samples table lies beyond the end of the file")
    return list(struct.unpack_from(f"<{count}Q", data, at + 8))


def crate_array_sizes(data: bytes) -> Iterator[int]:
    """Element count of every array value of a crate file (defaults and time samples)."""
    version, reps = _value_reps(data)
    for rep in reps:
        if rep & _IS_INLINED:
            continue
        if rep & _IS_ARRAY:
            yield _array_size(data, rep, version)
        elif (rep >> 48) & 0xFF == _TYPE_TIME_SAMPLES:
            for sample in _time_sample_reps(data, rep):
                if sample & _IS_ARRAY and not sample & _IS_INLINED:
                    yield _array_size(data, sample, version)


__all__ = ["crate_array_sizes", "lz4_block"]
