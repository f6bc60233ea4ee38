"""Longest GIL holds of the service's stages: what stalls the event loop.

The service runs CPU work in threads beside its event loop; Python switches threads every
few milliseconds, except while one C call (``np.array`` over a list, ``str.splitlines``, a
garbage collection) holds the GIL. This runs each stage in a worker thread while a watcher
thread wakes every millisecond: a wake-up later than planned is a stall, and the worker's
stack right after it names the call that held the GIL. Each stage runs ``--repeat`` times and
the smallest worst stall is reported (other processes on a busy machine add noise; a real
GIL hold shows up every time). Start-up objects are frozen out of the garbage collector's
sight first, as ``serve`` does (``--no-freeze``: not).

Stages: the OBJ reader on one triangle x50,000 and on 100,000 shells (400k faces), the
part tree on those shells, and a 60k-face dumbbell's ShDF, segmentation and unwrap (in the
service the unwrap itself runs in a worker process), atlas PNG and unwrapped GLB.

    python benchmarks/gil_stalls.py [--repeat 3] [--only SUBSTRING]
"""

from __future__ import annotations

import argparse
import gc
import sys
import threading
import time
import traceback
from collections.abc import Callable
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from hostile_corpus import LEGIT, dumbbell_obj, repeated_triangle, separate_shells  # noqa: E402

from neural_shdf.exchange.gltf_writer import unwrapped_glb as write_unwrapped_glb  # noqa: E402
from neural_shdf.mesh_io import load_mesh  # noqa: E402
from neural_shdf.pipeline import compute_shdf, segment  # noqa: E402
from neural_shdf.unwrap import atlas_layout_png, unwrap  # noqa: E402

TICK_S = 0.001


def worst_stall(work: Callable[[], object]) -> tuple[float, str]:
    """Run ``work`` in a thread; the longest late wake-up of a watcher (s) and where the
    worker was right after it."""
    done = threading.Event()

    def run() -> None:
        try:
            work()
        finally:
            done.set()

    worker = threading.Thread(target=run, daemon=True)
    worst, where = 0.0, ""
    worker.start()
    last = time.perf_counter()
    while not done.is_set():
        time.sleep(TICK_S)
        now = time.perf_counter()
        gap = now - last - TICK_S
        if gap > worst:
            worst = gap
            frame = sys._current_frames().get(worker.ident or -1)
            stack = traceback.extract_stack(frame)[-3:] if frame is not None else []
            where = " <- ".join(
                f"{Path(entry.filename).name}:{entry.lineno} {entry.line}"
                for entry in reversed(stack)
            )
        last = now
    worker.join()
    return worst, where


def stages() -> dict[str, Callable[[], object]]:
    triangles = repeated_triangle()
    shells = separate_shells(100_000)
    shells_mesh = load_mesh(shells, "obj")

    def part_tree() -> object:
        shdf = compute_shdf(shells_mesh, method="sampled").values
        return segment(shells_mesh, shdf)

    dumbbell_mesh = load_mesh(dumbbell_obj(60_000), "obj")
    atlas_parts: dict[str, object] = {}

    def segment_dumbbell() -> object:
        atlas_parts["labels"] = segment(dumbbell_mesh, compute_shdf(dumbbell_mesh).values).labels
        return atlas_parts["labels"]

    def atlas_of_dumbbell() -> object:
        atlas_parts["atlas"] = unwrap(dumbbell_mesh, atlas_parts["labels"])
        return atlas_parts["atlas"]

    def atlas_png() -> object:
        atlas_parts["png"] = atlas_layout_png(atlas_parts["atlas"])
        return atlas_parts["png"]

    def unwrapped_glb() -> object:
        return write_unwrapped_glb(
            dumbbell_mesh, atlas_parts["atlas"], texture_png=atlas_parts["png"]
        )

    def segment_scan() -> object:
        scan = load_mesh(LEGIT)
        return segment(scan, compute_shdf(scan).values)

    return {
        "read OBJ: one triangle x50,000": lambda: load_mesh(triangles, "obj"),
        "read OBJ: 100,000 shells": lambda: load_mesh(shells, "obj"),
        "segment: 100,000 shells": part_tree,
        "ShDF and segment: 60k dumbbell": segment_dumbbell,
        "unwrap (serve: worker process)": atlas_of_dumbbell,
        "atlas PNG: 60k dumbbell": atlas_png,
        **({"read, ShDF, segment: 462k scan": segment_scan} if LEGIT.exists() else {}),
        "unwrapped GLB: 60k dumbbell": unwrapped_glb,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--only", default="")
    parser.add_argument(
        "--no-freeze", action="store_true", help="keep start-up objects in the collector's sight"
    )
    args = parser.parse_args()
    work_by_stage = stages()
    if not args.no_freeze:  # as the service does after its warm-up
        gc.collect()
        gc.freeze()
    for name, work in work_by_stage.items():
        if args.only not in name:
            continue
        runs = [worst_stall(work) for _ in range(args.repeat)]
        stall, where = min(runs)
        print(f"{name:<36} worst stall {stall * 1e3:6.0f} ms  at {where}", flush=True)


if __name__ == "__main__":
    main()
