"""One decorator for the project's numba kernels.

Kernels release the GIL (callers run them in Python threads over blocks of
work) and are cached on disk beside the module, or in numba's user cache; where
neither folder is writable (a read-only install) they compile once per process.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, TypeVar, cast, overload

import numba

Function = TypeVar("Function", bound=Callable[..., Any])


@overload
def kernel(function: Function, *, inline: bool = False) -> Function: ...


@overload
def kernel(function: None = None, *, inline: bool = False) -> Callable[[Function], Function]: ...


def kernel(
    function: Function | None = None, *, inline: bool = False
) -> Function | Callable[[Function], Function]:
    """``numba.njit(nogil=True, cache=True)``, without the cache where none can be written.

    ``inline=True`` inlines the kernel into the kernels that call it.
    """

    def compile_(target: Function) -> Function:
        options: dict[str, Any] = {"nogil": True, **({"inline": "always"} if inline else {})}
        try:
            return cast(Function, numba.njit(cache=True, **options)(target))
        except RuntimeError:  # no writable cache folder: compile per process
            return cast(Function, numba.njit(**options)(target))

    return compile_ if function is None else compile_(function)
