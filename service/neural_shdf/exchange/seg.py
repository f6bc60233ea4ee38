"""Per-face text files: ``.seg`` labels (one integer per line, the Princeton benchmark's
format) and value files such as ``.sdf`` (one number per line)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from neural_shdf.errors import ParameterError


def write_labels(path: str | Path, labels: NDArray[Any]) -> None:
    """Write a .seg file: one integer label per line."""
    labels = np.asarray(labels)
    if labels.ndim != 1 or labels.dtype.kind not in "iub":
        raise ParameterError("labels must be a 1-D integer array")
    # Each label formatted once (bools as 0/1), then looked up per face: formatting numpy
    # scalars one by one took most of a second at 1M faces.
    low, high = (int(labels.min()), int(labels.max())) if len(labels) else (0, -1)
    if low >= -(2**62) and high < 2**62 and high - low <= len(labels):
        # Part labels: a small range, a table over it (no sort).
        lines = [f"{value}\n" for value in range(low, high + 1)]
        index = labels.astype(np.int64) - low
    else:
        distinct, index = np.unique(labels, return_inverse=True)
        lines = [f"{int(value)}\n" for value in distinct.tolist()]
    Path(path).write_text("".join(map(lines.__getitem__, index.ravel().tolist())))


def _read_column(path: str | Path, parse: type, what: str) -> list[Any]:
    """One value per line, blank lines ignored; a bad line raises ParameterError naming it."""
    values = []
    for number, line in enumerate(Path(path).read_text().splitlines(), start=1):
        text = line.strip()
        if not text:
            continue
        try:
            values.append(parse(text))
        except ValueError:
            name = Path(path).name
            raise ParameterError(f"{name} line {number}: {text!r} is not {what}") from None
    return values


def read_labels(path: str | Path) -> NDArray[np.int64]:
    """Read a .seg file (one integer per line; blank lines ignored)."""
    return np.array(_read_column(path, int, "an integer label"), dtype=np.int64)


def write_values(path: str | Path, values: NDArray[Any], *, fmt: str = "%.9g") -> None:
    """Write one float per line (default 9 significant digits: float32-exact)."""
    values = np.asarray(values, dtype=np.float64)
    if values.ndim != 1:
        raise ParameterError("values must be a 1-D array")
    Path(path).write_text("".join(fmt % v + "\n" for v in values))


def read_values(path: str | Path) -> NDArray[np.float64]:
    """Read one float per line (e.g. a .sdf file; blank lines ignored)."""
    return np.array(_read_column(path, float, "a number"), dtype=np.float64)
