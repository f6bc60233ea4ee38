"""Large numeric arrays of a ``.usda`` layer parsed by numpy-speed code, not usd-core's
text parser (about 25 MB/s; most of a big ``.usda`` is its points and indices).

``cut_arrays`` finds attribute defaults written as ``TYPE[] name = [...]`` (at the start
of a line, numeric element types, at least ``MIN_CUT_BYTES`` long) and parses each with
``_parse_literal``: a strict grammar, a subset of what usd-core accepts (``-``, digits,
an optional fraction and exponent, whitespace and commas; tuples of the type's width),
values computed as usd-core does (decimal to the nearest double, then cast to float for
float types). A literal that does not fit the grammar exactly (comments, ``nan``,
``None``, a trailing comma, a float in an int array, an int out of range) is left in
the text for usd-core. Each cut literal is replaced by a one-element marker array
(a number that appears nowhere else in the remaining text), so usd-core still parses
every prim, type, time sample and composition arc of the layer.

``restore_arrays`` then walks the parsed layer and puts each array back on the
attribute that holds its marker, before the stage is composed. It answers False unless
every marker is found exactly once, on the default value of an attribute of the type
that was assumed: the caller then reads the original text with usd-core alone. The
layer is then the one usd-core makes from the original text (``tests/exchange/
test_usda_arrays.py`` compares them whole).
"""

from __future__ import annotations

import re
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from neural_shdf.compiled import kernel
from neural_shdf.errors import MeshTooLargeError

#: Literals shorter than this are left to usd-core (restoring each costs a walk step).
MIN_CUT_BYTES = 1 << 16
#: Tokens per literal computed in Python (beyond Clinger's exact fast path) before the
#: literal is left to usd-core instead.
MAX_SLOW_TOKENS = 4096

#: Element types cut: name -> (kind: "f" float, "d" double, "i" int32; tuple width, or 0
#: for scalars; the Vt array type name).
ARRAY_TYPES: dict[str, tuple[str, int, str]] = {
    "int": ("i", 0, "IntArray"),
    "float": ("f", 0, "FloatArray"),
    "double": ("d", 0, "DoubleArray"),
    **{f"float{n}": ("f", n, f"Vec{n}fArray") for n in (2, 3, 4)},
    **{f"double{n}": ("d", n, f"Vec{n}dArray") for n in (2, 3, 4)},
    "texCoord2f": ("f", 2, "Vec2fArray"),
    "texCoord2d": ("d", 2, "Vec2dArray"),
    "texCoord3f": ("f", 3, "Vec3fArray"),
    "texCoord3d": ("d", 3, "Vec3dArray"),
    **{f"{role}3f": ("f", 3, "Vec3fArray") for role in ("point", "normal", "vector", "color")},
    **{f"{role}3d": ("d", 3, "Vec3dArray") for role in ("point", "normal", "vector", "color")},
    "color4f": ("f", 4, "Vec4fArray"),
    "color4d": ("d", 4, "Vec4dArray"),
}

_DECLARATION = re.compile(
    rb"^[ \t]*(?:(?:custom|uniform|varying)[ \t]+)*("
    + b"|".join(re.escape(name.encode()) for name in sorted(ARRAY_TYPES, key=len, reverse=True))
    + rb")\[\][ \t]+([A-Za-z_][A-Za-z0-9_:]*)[ \t]*=[ \t]*\[",
    re.MULTILINE,
)

#: Exact powers of ten as doubles (10**22 is the largest).
_POWERS = np.array([10.0**k for k in range(23)], dtype=np.float64)


@kernel
def _parse_literal(  # noqa: C901, PLR0912, PLR0915 - one pass over the bytes
    text: NDArray[np.uint8],
    start: int,
    end: int,
    width: int,
    powers: NDArray[np.float64],
    values: NDArray[np.float64],
    slow: NDArray[np.int64],
) -> tuple[int, int]:
    """Parse ``text[start:end]`` (between the brackets) into ``values``: numbers
    ``-?digits(.digits*)?([eE][+-]?digits)?`` (``width`` 0) or ``(a, b, ...)`` tuples of
    ``width`` of them, comma separated, blanks anywhere between except a line break
    right before a comma (usd-core refuses that).

    Returns ``(value count, slow token count)``, or ``(-1, 0)`` when the literal is empty
    or does not fit the grammar (a trailing comma, a comment, ``nan``: usd-core reads
    those). A slow token's value is not exact by Clinger's fast path (more than 15
    digits, or a power of ten past 22): ``slow[3k:3k+3]`` holds its byte range and value
    index, for the caller to compute. Floats and doubles (``_parse_integers``: ints).
    One loop, no helper calls: several times faster in numba than the same grammar
    split into functions.
    """
    count = 0
    slow_count = 0
    depth = 0  # 1 inside a tuple
    in_tuple = 0  # numbers read in the current tuple
    expect_value = True  # else a separator (',' or ')') must come next
    line_break = False  # a line break since the last value or ')'
    position = start
    while position < end:
        c = text[position]
        if c == 32 or c == 9:
            position += 1
            continue
        if c == 10 or c == 13:
            line_break = True  # usd-core refuses one right before a ','
            position += 1
            continue
        if c == 40:  # '('
            if width == 0 or depth == 1 or not expect_value:
                return -1, 0
            depth = 1
            in_tuple = 0
            position += 1
            continue
        if c == 41:  # ')'
            if depth != 1 or expect_value or in_tuple != width:
                return -1, 0
            depth = 0
            line_break = False
            position += 1
            continue
        if c == 44:  # ','
            if expect_value or line_break or (depth == 1 and in_tuple >= width):
                return -1, 0
            expect_value = True
            position += 1
            continue
        if not expect_value or (width > 0 and depth == 0):
            return -1, 0
        # A number.
        token_start = position
        negative = c == 45  # '-'
        if negative:
            position += 1
        mantissa = 0
        digits = 0  # significant digits (leading zeros skipped)
        exponent = 0
        integer_digits = 0
        while position < end:
            d = int(text[position]) - 48
            if d < 0 or d > 9:
                break
            if digits > 0 or d != 0:
                digits += 1
                if digits <= 18:
                    mantissa = mantissa * 10 + d
                else:
                    exponent += 1
            integer_digits += 1
            position += 1
        if integer_digits == 0:
            return -1, 0
        if position < end and text[position] == 46:  # '.'
            position += 1
            while position < end:
                d = int(text[position]) - 48
                if d < 0 or d > 9:
                    break
                if digits > 0 or d != 0:
                    digits += 1
                    if digits <= 18:
                        mantissa = mantissa * 10 + d
                        exponent -= 1
                else:
                    exponent -= 1
                position += 1
        if position < end and (text[position] == 101 or text[position] == 69):  # e E
            position += 1
            exponent_negative = False
            if position < end and (text[position] == 43 or text[position] == 45):
                exponent_negative = text[position] == 45
                position += 1
            exponent_digits = 0
            written = 0
            while position < end:
                d = int(text[position]) - 48
                if d < 0 or d > 9:
                    break
                if exponent_digits < 6:
                    written = written * 10 + d
                exponent_digits += 1
                position += 1
            if exponent_digits == 0:
                return -1, 0
            exponent += -written if exponent_negative else written
        if digits > 15 or exponent > 22 or exponent < -22:
            if 3 * slow_count + 2 >= slow.shape[0]:
                return -1, 0
            slow[3 * slow_count] = token_start
            slow[3 * slow_count + 1] = position
            slow[3 * slow_count + 2] = count
            slow_count += 1
            values[count] = 0.0
        else:
            value = np.float64(mantissa)  # exact: at most 15 digits
            # One rounding of two exact operands: the correctly rounded double.
            value = value * powers[exponent] if exponent >= 0 else value / powers[-exponent]
            values[count] = -value if negative else value
        count += 1
        in_tuple += 1
        expect_value = False
        line_break = False
    if expect_value or depth != 0:
        return -1, 0  # empty, a trailing comma, or an unclosed tuple
    return count, slow_count


@kernel
def _parse_integers(
    text: NDArray[np.uint8], start: int, end: int, values: NDArray[np.int32]
) -> int:
    """``_parse_literal`` of int32 scalars (most of a mesh's text: its indices), in a
    tighter loop: ``-?digits`` comma separated. Returns the count, or -1."""
    count = 0
    position = start
    while True:
        while position < end:
            c = text[position]
            if c != 32 and c != 9 and c != 10 and c != 13:
                break
            position += 1
        if position >= end:
            return -1  # empty, or a trailing comma
        negative = text[position] == 45  # '-'
        if negative:
            position += 1
        number = 0
        digits = 0  # significant digits
        seen = 0
        while position < end:
            d = int(text[position]) - 48
            if d < 0 or d > 9:
                break
            if digits > 0 or d != 0:
                digits += 1
                if digits > 10:
                    return -1
                number = number * 10 + d
            seen += 1
            position += 1
        if seen == 0:
            return -1
        if negative:
            number = -number
        if number < -2147483648 or number > 2147483647:
            return -1
        values[count] = number
        count += 1
        line_break = False
        while position < end:
            c = text[position]
            if c == 10 or c == 13:
                line_break = True
            elif c != 32 and c != 9:
                break
            position += 1
        if position >= end:
            return count
        if text[position] != 44 or line_break:  # ','; no line break right before it
            return -1
        position += 1


@dataclass(frozen=True)
class CutArray:
    """One literal taken out of the text: its marker and values (as usd-core makes them)."""

    marker: int
    type_name: str
    name: str
    values: NDArray[Any]


@dataclass(frozen=True)
class CutLayer:
    """The text with its large numeric literals replaced by markers, and those literals."""

    text: bytes
    arrays: tuple[CutArray, ...]


def _values(
    data: bytes, buffer: NDArray[np.uint8], start: int, end: int, type_name: str, capacity: int
) -> NDArray[Any] | None:
    """The values of ``data[start:end]`` as usd-core gives them for ``type_name``
    (``capacity``: at least their count), or None when the literal does not fit the
    grammar (module docstring)."""
    kind, width, _ = ARRAY_TYPES[type_name]
    if kind == "i":
        integers = np.empty(capacity, dtype=np.int32)
        found = _parse_integers(buffer, start, end, integers)
        return None if found < 0 else integers[:found]
    values = np.empty(capacity, dtype=np.float64)
    slow = np.empty(3 * MAX_SLOW_TOKENS, dtype=np.int64)
    count, slow_count = _parse_literal(buffer, start, end, width, _POWERS, values, slow)
    if count < 0 or (width and count % width):
        return None
    values = values[:count]
    for k in range(slow_count):  # correctly rounded to a double, as usd-core parses
        token = data[int(slow[3 * k]) : int(slow[3 * k + 1])]
        values[int(slow[3 * k + 2])] = float(token)
    if kind == "f":
        with np.errstate(over="ignore"):
            return values.astype(np.float32)  # the double cast, as usd-core casts it
    return values


def cut_arrays(
    data: bytes, min_bytes: int = MIN_CUT_BYTES, *, max_elements: int | None = None
) -> CutLayer | None:
    """The layer's text with its large numeric attribute defaults replaced by markers
    (module docstring); None when there is none to cut. MeshTooLargeError when a literal
    holds more than ``max_elements`` elements (counted from its commas, before any array
    is made: the bound ``usd.check_crate_arrays`` puts on a crate's arrays)."""
    found: list[tuple[int, int, str, str]] = []  # (after '[', at ']', type, name)
    position = 0
    while (match := _DECLARATION.search(data, position)) is not None:
        opening = match.end()
        closing = data.find(b"]", opening)
        if closing < 0:
            break
        if closing - opening >= min_bytes:
            found.append((opening, closing, match[1].decode(), match[2].decode()))
        position = closing + 1
    if not found:
        return None
    buffer = np.frombuffer(data, dtype=np.uint8)
    # Values are at most the commas + 1: the arrays' sizes, and the limits' check.
    capacities = [int(np.count_nonzero(buffer[a:b] == 44)) + 1 for a, b, _, _ in found]
    if max_elements is not None:
        for (_, _, type_name, name), values in zip(found, capacities, strict=True):
            elements = values // max(ARRAY_TYPES[type_name][1], 1)
            if elements > max_elements:
                raise MeshTooLargeError(
                    f"the USD attribute {name!r} holds about {elements} values, more than "
                    f"a mesh within the limits holds ({max_elements}); simplify "
                    "(decimate) it before uploading",
                    limit="max_faces",
                    found=elements,
                    maximum=max_elements,
                )
    # The literals in parallel (the kernel releases the GIL).
    with ThreadPoolExecutor(max_workers=2) as pool:
        parsed = list(
            pool.map(
                lambda item, size: _values(data, buffer, item[0], item[1], item[2], size),
                found,
                capacities,
            )
        )
    kept = [
        (item, values) for item, values in zip(found, parsed, strict=True) if values is not None
    ]
    if not kept:
        return None
    pieces: list[bytes] = []
    previous = 0
    for (opening, closing, _, _), _values_found in kept:
        pieces.append(data[previous : opening - 1])
        previous = closing + 1
    pieces.append(data[previous:])
    rest = b"".join(pieces)
    markers: list[int] = []
    candidate = 9_000_001  # below 2**24: exact in every element type cut
    while len(markers) < len(kept):
        if str(candidate).encode() not in rest:
            markers.append(candidate)
        candidate += 1
    text: list[bytes] = []
    arrays = []
    for piece, ((_, _, type_name, name), array_values), marker in zip(
        pieces, kept, markers, strict=False
    ):
        width = ARRAY_TYPES[type_name][1]
        number = str(marker).encode()
        literal = (
            b"[" + number + b"]" if width == 0 else b"[(" + b", ".join([number] * width) + b")]"
        )
        text += [piece, literal]
        arrays.append(CutArray(marker, type_name, name, array_values))
    text.append(pieces[-1])
    return CutLayer(b"".join(text), tuple(arrays))


def restore_arrays(layer: Any, cut: CutLayer) -> bool:
    """Put each cut array back on the attribute of ``layer`` (parsed from ``cut.text``)
    that holds its marker as its default value. False, with nothing changed, unless
    every marker is found exactly once on an attribute of the type it was cut from."""
    from pxr import Sdf, Vt

    wanted = {array.marker: array for array in cut.arrays}
    names = {array.name for array in cut.arrays}
    paths: list[Any] = []

    def visit(path: Any) -> None:
        if path.IsPropertyPath() and path.name in names:
            paths.append(path)

    layer.Traverse(Sdf.Path.absoluteRootPath, visit)
    found: dict[int, Any] = {}
    for path in paths:
        spec = layer.GetAttributeAtPath(path)
        if not spec or not spec.HasDefaultValue():
            continue
        value = spec.default
        if not hasattr(value, "__len__") or len(value) != 1:
            continue
        element = np.asarray(value, dtype=np.float64).reshape(-1)
        marker = int(element[0])
        if marker not in wanted or not (element == marker).all():
            continue
        if marker in found or str(spec.typeName) != wanted[marker].type_name + "[]":
            return False
        found[marker] = spec
    if len(found) != len(wanted):
        return False
    for marker, spec in found.items():
        array = wanted[marker]
        _, width, vt_name = ARRAY_TYPES[array.type_name]
        values = array.values.reshape(-1, width) if width else array.values
        spec.default = getattr(Vt, vt_name).FromNumpy(np.ascontiguousarray(values))
    return True


def warm_up() -> None:
    """Build (or load from its cache) the kernel, as ``pipeline.warm_up`` does for all."""
    literal = b"(1.5, -2e3, 0.1234567890123456789)"
    _values(literal, np.frombuffer(literal, dtype=np.uint8), 0, len(literal), "point3f", 3)
    _values(b"1, -2", np.frombuffer(b"1, -2", dtype=np.uint8), 0, 5, "int", 2)
