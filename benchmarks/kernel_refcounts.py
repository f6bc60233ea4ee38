"""Reference counting left inside the loops of the compiled kernels, from their LLVM IR.

numba keeps an array alive across a call by incrementing and decrementing its reference
count (two atomic operations); where its pruning cannot prove them useless they stay in
the loop that makes the call or takes the view, and a loop of cheap steps runs several
times slower. Which source form keeps them is not predictable (a union-find join that
returned the root it had just stored was 4x slower in ``stitching._vertex_shells``' loop;
the nearest-point insertion without its result, 3x slower): this screen reads the
optimised IR of every kernel the pipeline compiles and counts the ``NRT_incref`` /
``NRT_decref`` calls that lie on a cycle of its control-flow graph. A count says where to
look (a rare branch in a loop counts too); whether it costs anything is for a timing of
that loop, before and after, to say.

The kernels are compiled afresh in a temporary numba cache (numba shows no IR for cached
code), by ``pipeline.warm_up`` with every ShDF method and segmentations of a sphere, of
30 copies of it side by side and of an open pair of shells: a few minutes on 2 cores.

    python benchmarks/kernel_refcounts.py [--all]
"""

from __future__ import annotations

import argparse
import atexit
import os
import re
import shutil
import sys
import tempfile

_CACHE = tempfile.mkdtemp(prefix="kernel-refcounts-")
atexit.register(shutil.rmtree, _CACHE, ignore_errors=True)
os.environ["NUMBA_CACHE_DIR"] = _CACHE  # before numba is imported: fresh compiles, IR kept

import importlib  # noqa: E402
import pkgutil  # noqa: E402

import numba  # noqa: E402
import numpy as np  # noqa: E402
import trimesh  # noqa: E402

import neural_shdf  # noqa: E402
from neural_shdf.mesh import TriangleMesh  # noqa: E402
from neural_shdf.pipeline import compute_shdf, segment, warm_up  # noqa: E402

LABEL = re.compile(r"^([A-Za-z0-9_.$\-]+):")
TARGET = re.compile(r"label %([A-Za-z0-9_.$\-]+)")


def functions(ir: str) -> dict[str, list[str]]:
    """The lines of each function defined in an LLVM module's text."""
    found: dict[str, list[str]] = {}
    name = None
    for line in ir.splitlines():
        if line.startswith("define "):
            match = re.search(r"@([^(]+)\(", line)
            name = match.group(1) if match else line
            found[name] = []
        elif name is not None:
            if line.startswith("}"):
                name = None
            else:
                found[name].append(line)
    return found


def calls_in_loops(body: list[str]) -> tuple[int, int]:
    """(increfs, decrefs) called in blocks on a cycle of the function's control flow."""
    blocks: dict[str, list[str]] = {"entry": []}
    current = "entry"
    for line in body:
        match = LABEL.match(line)
        if match:
            current = match.group(1)
            blocks[current] = []
        else:
            blocks[current].append(line)
    successors = {
        block: {target for line in lines for target in TARGET.findall(line)} & blocks.keys()
        for block, lines in blocks.items()
    }
    in_loop = set()
    for block in blocks:  # on a cycle: reachable from one of its own successors
        seen, stack = set(), list(successors[block])
        while stack:
            node = stack.pop()
            if node == block:
                in_loop.add(block)
                break
            if node not in seen:
                seen.add(node)
                stack.extend(successors[node])
    lines = [line for block in in_loop for line in blocks[block] if "call" in line]
    return (
        sum("@NRT_incref" in line for line in lines),
        sum("@NRT_decref" in line for line in lines),
    )


def exercise() -> None:
    """Compile what the pipeline runs: every ShDF method, both partitioners, many shells,
    open shells."""
    warm_up()
    sphere = trimesh.creation.icosphere(subdivisions=3)
    vertices, faces = np.asarray(sphere.vertices), np.asarray(sphere.faces)
    copies = 30
    meshes = [
        TriangleMesh(vertices, faces),
        TriangleMesh(
            np.vstack([vertices + [3.0 * k, 0.0, 0.0] for k in range(copies)]),
            np.vstack([faces + k * len(vertices) for k in range(copies)]),
        ),
    ]
    upper = vertices[faces[:, 0], 2] > 0.1
    meshes.append(
        TriangleMesh(
            np.vstack([vertices, vertices + [0.0, 0.0, 0.5]]),
            np.vstack([faces[upper], faces[~upper] + len(vertices)]),
        )
    )
    for mesh in meshes:
        segment(mesh, compute_shdf(mesh))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--all", action="store_true", help="also list kernels with none")
    args = parser.parse_args()
    exercise()
    print(f"{'kernel':60s} {'incref':>6s} {'decref':>6s}  (calls on a control-flow cycle)")
    for info in pkgutil.walk_packages(neural_shdf.__path__, "neural_shdf."):
        try:
            module = importlib.import_module(info.name)
        except Exception:  # noqa: BLE001 - optional extras (bpy, pxr) are not installed
            continue
        for name, value in sorted(vars(module).items()):
            if not isinstance(value, numba.core.registry.CPUDispatcher):
                continue
            if value.__module__ != info.name or not value.signatures:
                continue
            ir = value.inspect_llvm(value.signatures[0])
            increfs = decrefs = 0
            for function, body in functions(ir).items():
                if not function.startswith("NRT_"):
                    inc, dec = calls_in_loops(body)
                    increfs, decrefs = increfs + inc, decrefs + dec
            if increfs or decrefs or args.all:
                print(f"{info.name + '.' + name:60s} {increfs:6d} {decrefs:6d}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
