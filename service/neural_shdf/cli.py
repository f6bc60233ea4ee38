"""Command-line interface: ``neural-shdf shdf|segment|unwrap|batch|eval|serve|labeler``.

A stable contract for pipelines: per-face outputs have one line per face of the
input file, in the input file's order; errors go to stderr with a non-zero exit.
"""

from __future__ import annotations

import argparse
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from neural_shdf.constants import DEFAULT_MAX_FACES, DEFAULT_MAX_VERTICES
from neural_shdf.errors import ModelUnavailableError, NeuralShdfError, ParameterError
from neural_shdf.exchange.seg import write_labels, write_values
from neural_shdf.labeling.cli import add_labeler_parser, labeler_option, segment_with_labeler
from neural_shdf.mesh_io import detect_format, load_mesh, normalize_format
from neural_shdf.pipeline import SegmentParams, compute_shdf, segment
from neural_shdf.segment.params import AUTO_CLUSTERS, DEFAULT_CREASE_BOUNDARIES
from neural_shdf.segment.tree_document import write_part_tree

#: Exit codes: 0 ok, 1 unexpected failure, 2 bad input or usage, 3 model unavailable.
EXIT_BAD_INPUT = 2
EXIT_MODEL_UNAVAILABLE = 3
#: Resolution of the progress bars.
PROGRESS_STEPS = 1000


@contextmanager
def progress_bar(
    description: str, enabled: bool = True, *, delay_s: float = 1.0
) -> Iterator[Callable[[float], None]]:
    """A tqdm bar on stderr for work that lasts more than ``delay_s``, cleared when it ends.

    Only on a terminal: redirected to a file or a pipe, stderr gets no ``\r`` frames.
    The returned function takes the fraction done (from any thread; it never goes back).
    """
    from tqdm import tqdm  # lazy, like the writers below: start-up counts at 1M faces too

    bar = tqdm(
        total=PROGRESS_STEPS,
        desc=description,
        delay=delay_s,
        mininterval=0.2,
        disable=not (enabled and sys.stderr.isatty()),
        file=sys.stderr,
        leave=False,
        bar_format="{desc}: {percentage:3.0f}%|{bar}| {elapsed}<{remaining}",
    )
    done = 0
    lock = threading.Lock()

    def update(fraction: float) -> None:
        # tqdm.update (not refresh) honours the delay, and then close() clears the line.
        nonlocal done
        target = int(PROGRESS_STEPS * min(max(fraction, 0.0), 1.0))
        with lock:
            if target > done:
                bar.update(target - done)
                done = target

    try:
        yield update
    finally:
        bar.close()


def _load(args: argparse.Namespace):
    if not Path(args.mesh).is_file():
        raise FileNotFoundError(f"mesh file not found: {args.mesh}")
    return load_mesh(
        Path(args.mesh), args.format, max_faces=args.max_faces, max_vertices=args.max_vertices
    )


def _load_source(args: argparse.Namespace):
    """The mesh with the file's own attributes (``mesh_io.load_source``), for outputs
    written back into the artist's kind of file."""
    from neural_shdf.mesh_io import load_source

    if not Path(args.mesh).is_file():
        raise FileNotFoundError(f"mesh file not found: {args.mesh}")
    return load_source(
        Path(args.mesh), args.format, max_faces=args.max_faces, max_vertices=args.max_vertices
    )


def _shdf(mesh, args: argparse.Namespace) -> tuple[np.ndarray, str]:
    """The ShDF per triangle and a note naming the producer that ran (``auto`` resolved),
    for the command's summary line."""
    start = time.perf_counter()
    with progress_bar(f"{args.method} ShDF", enabled=not args.quiet) as progress:
        result = compute_shdf(
            mesh,
            method=args.method,
            seed=args.seed,
            progress=progress,
            model=args.model,
        )
    note = f"ShDF {result.method} ({args.method}) in {time.perf_counter() - start:.2f} s"
    return result.values, note


def cmd_shdf(args: argparse.Namespace) -> int:
    mesh = _load(args)
    values, note = _shdf(mesh, args)
    write_values(args.output, mesh.to_input_faces(values))
    if not args.quiet:
        print(f"{mesh.input_face_count} faces, {note}", file=sys.stderr)
        print(mesh.diagnostics.summary(), file=sys.stderr)
    return 0


def symmetry_summary(reflection: object) -> str:
    """One line on the mirror plane ``--symmetry`` found (a ``Reflection``), or that none was."""
    if reflection is None:
        return "symmetry: no reflective symmetry found (labels as without --symmetry)"
    normal = ", ".join(f"{v:.3f}" for v in reflection.normal)  # type: ignore[attr-defined]
    matched = reflection.matched_area  # type: ignore[attr-defined]
    return f"symmetry: mirror plane normal ({normal}), {matched:.0%} of the surface paired"


def cmd_segment(args: argparse.Namespace) -> int:
    params = SegmentParams.from_attributes(args)
    if args.tree and params.partitioner != "graphcut":
        raise ParameterError("--tree needs the graphcut partitioner (metis makes no part tree)")
    if args.usd and Path(args.usd).suffix.lower() not in (".usda", ".usdc", ".usd", ".usdz"):
        raise ParameterError(f"--usd must end in .usda, .usdc, .usd or .usdz, got {args.usd!r}")
    labeler = None
    if args.labeler or args.confidence:
        labeler = labeler_option(args)  # its file and flags checked before any work
    source = _load_source(args) if args.parts_glb else None
    mesh = source.mesh if source is not None else _load(args)
    shdf, note = _shdf(mesh, args)
    if labeler is not None:
        return segment_with_labeler(args, mesh, shdf, labeler)
    start = time.perf_counter()
    result = segment(mesh, shdf, params)
    labels = result.labels
    face_labels, face_leaves = result.input_face_parts(mesh)
    write_labels(args.output, face_labels)
    if args.tree:
        write_part_tree(args.tree, result.tree, face_leaves, result.part_count)
    if args.colored or args.parts_glb:
        from neural_shdf.exchange.gltf_writer import colored_glb, parts_glb
    if args.colored:
        Path(args.colored).write_bytes(colored_glb(mesh, labels))
    if args.parts_glb:
        attributes = source.attributes if source is not None else None
        Path(args.parts_glb).write_bytes(parts_glb(mesh, labels, attributes=attributes))
    if args.usd:
        _write_usd(args, mesh, face_labels)
    if not args.quiet:
        parts = len(np.unique(labels))
        elapsed = time.perf_counter() - start
        print(
            f"{parts} parts, {mesh.input_face_count} faces, {note}, segmented in {elapsed:.2f} s",
            file=sys.stderr,
        )
        print(mesh.diagnostics.summary(), file=sys.stderr)
        if params.symmetry:
            print(symmetry_summary(result.reflection), file=sys.stderr)
    return 0


def _write_usd(args: argparse.Namespace, mesh, face_labels: np.ndarray) -> None:
    """The parts as USD: a USD input's own stage with subsets, else a new stage of its faces."""
    from neural_shdf.exchange.usd import USD_EXTENSIONS, write_mesh_parts_usd, write_usd_parts

    file_type = normalize_format(args.format) if args.format else detect_format(args.mesh)
    if file_type in USD_EXTENSIONS:
        write_usd_parts(args.mesh, face_labels, args.usd, input_format=file_type)
    else:
        write_mesh_parts_usd(mesh, face_labels, args.usd)


def cmd_unwrap(args: argparse.Namespace) -> int:
    from neural_shdf.exchange.gltf_writer import unwrapped_glb
    from neural_shdf.exchange.obj_writer import write_obj_with_uvs
    from neural_shdf.unwrap import UnwrapParams, atlas_layout_png, unwrap

    output = Path(args.output)
    if output.suffix.lower() not in (".glb", ".obj"):
        raise ParameterError(f"-o must end in .glb or .obj, got {output.name!r}")
    params = SegmentParams.from_attributes(args)
    unwrap_params = UnwrapParams(
        atlas_size=args.atlas_size, padding=args.padding, max_stretch=args.max_stretch
    )
    mesh = _load(args)
    shdf, _ = _shdf(mesh, args)
    start = time.perf_counter()
    labels = segment(mesh, shdf, params).labels
    atlas = unwrap(mesh, labels, unwrap_params)
    layout = atlas_layout_png(atlas, size=args.atlas_size)
    split = 0
    if output.suffix.lower() == ".glb":
        output.write_bytes(unwrapped_glb(mesh, atlas, texture_png=layout))
    else:
        split = write_obj_with_uvs(output, mesh, atlas)
    if args.atlas_png:
        Path(args.atlas_png).write_bytes(layout)
    if args.labels:
        write_labels(args.labels, mesh.labels_to_input_faces(labels))
    if not args.quiet:
        elapsed = time.perf_counter() - start
        parts = len(np.unique(labels))
        note = f"; {split} polygons split by a chart boundary written as triangles" if split else ""
        print(
            f"{parts} parts, {atlas.chart_count} charts, atlas {atlas.width}x{atlas.height} "
            f"({atlas.utilization:.0%} used), unwrapped in {elapsed:.2f} s{note}",
            file=sys.stderr,
        )
    return 0


def cmd_eval(args: argparse.Namespace) -> int:
    from neural_shdf.evaluate.benchmark import format_table, run_eval

    bench_dir = Path(args.bench_dir)
    if not (bench_dir / "off").is_dir() or not (bench_dir / "seg").is_dir():
        raise FileNotFoundError(
            f"{bench_dir} is not a benchmark folder: it needs off/ and seg/ subfolders"
        )
    with progress_bar("models", enabled=not args.quiet) as progress:
        table = run_eval(
            bench_dir,
            methods=args.methods,
            limit=args.limit,
            cache_dir=args.cache_dir,
            jobs=args.jobs,
            progress=lambda done, total: progress(done / max(total, 1)),
        )
    print(format_table(table))
    return 0


def cmd_serve(args: argparse.Namespace) -> int:
    # Lazy: FastAPI, uvicorn and the stores would slow every other command's start-up.
    from neural_shdf.api.serve import run

    run(host=args.host, port=args.port, workers=args.workers)
    return 0


def _clusters(text: str) -> int:
    if text == "auto":
        return AUTO_CLUSTERS
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer or 'auto', got {text!r}") from None


def _add_mesh_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("mesh", help="input mesh: OBJ, GLB/glTF, OFF, PLY, STL or USD")
    parser.add_argument("--format", help="file type when the extension does not say it")
    parser.add_argument(
        "--method",
        choices=["auto", "exact", "sampled", "neural"],
        default="auto",
        help="ShDF producer: auto (default: the fastest that meets the fidelity "
        "target, per mesh), exact (every face's rays, CGAL's), sampled "
        "(rays at surface samples) or neural (the network)",
    )
    parser.add_argument("--model", help="ONNX model for --method neural (default: installed)")
    parser.add_argument("--seed", type=int, default=0, help="seed of every random step")
    parser.add_argument(
        "--max-faces",
        type=int,
        default=DEFAULT_MAX_FACES,
        help="refuse meshes with more triangles, counting glTF instances "
        f"(default {DEFAULT_MAX_FACES}, as the service)",
    )
    parser.add_argument(
        "--max-vertices",
        type=int,
        default=DEFAULT_MAX_VERTICES,
        help=f"refuse meshes with more vertices (default {DEFAULT_MAX_VERTICES})",
    )
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress bar or summary")


def _add_segment_options(parser: argparse.ArgumentParser) -> None:
    """The segmentation parameters (``SegmentParams`` fields), shared by segment and batch."""
    parser.add_argument("--partitioner", choices=["graphcut", "metis"], default="graphcut")
    parser.add_argument(
        "--clusters",
        type=_clusters,
        help="mixture components k, a level of detail (default 9), "
        "or 'auto' to choose k per mesh by BIC",
    )
    parser.add_argument("--smoothing", type=float, help="graph-cut smoothness lambda")
    parser.add_argument(
        "--parts",
        type=int,
        help="number of parts: a cut of the graph cut's part tree (at most its "
        "leaves), or exactly this many with metis (default: automatic)",
    )
    parser.add_argument("--refine", action="store_true", help="recursively refine parts")
    parser.add_argument(
        "--boundary-smoothing",
        action="store_true",
        help="alpha-expansion pass that smooths part boundaries",
    )
    parser.add_argument(
        "--crease-boundaries",
        action=argparse.BooleanOptionalAction,
        default=DEFAULT_CREASE_BOUNDARIES,
        help="move the graph cut's part boundaries onto nearby concave creases "
        "(a min cut in a band around each boundary; default: on)",
    )
    parser.add_argument(
        "--symmetry",
        action="store_true",
        help="cut both sides of a mirror-symmetric shape alike (when a global reflective "
        "symmetry is found; default: off)",
    )


def cmd_batch(args: argparse.Namespace) -> int:
    # Lazy: the stores (diskcache, redis) would slow every other command's start-up.
    from neural_shdf.batch import MANIFEST_NAME, run_batch, summary

    if args.shdf_only and args.formats and set(args.formats) - {"shdf"}:
        raise ParameterError("--shdf-only writes only the ShDF; drop the other --formats")
    outputs = ["shdf"] if args.shdf_only else (args.formats or ["seg"])
    rows = run_batch(
        args.inputs,
        args.output,
        method=args.method,
        seed=args.seed,
        params=SegmentParams.from_attributes(args),
        outputs=outputs,
        file_type=args.format,
        max_faces=args.max_faces,
        max_vertices=args.max_vertices,
        cache=args.cache,
        workers=args.workers,
        scheduler=args.scheduler,
        progress=not args.quiet,
        labeler=args.labeler,
    )
    counts = summary(rows)
    if not args.quiet:
        print(
            f"{counts['ok']} done, {counts['skipped']} already done, {counts['failed']} failed; "
            f"manifest: {Path(args.output) / MANIFEST_NAME}",
            file=sys.stderr,
        )
    return EXIT_BAD_INPUT if counts["failed"] else 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="neural-shdf", description=__doc__.splitlines()[0])
    commands = parser.add_subparsers(dest="command", required=True)

    shdf = commands.add_parser("shdf", help="per-face ShDF in [0,1], one float per line")
    _add_mesh_arguments(shdf)
    shdf.add_argument("-o", "--output", required=True, help="output text file")
    shdf.set_defaults(run=cmd_shdf)

    segment = commands.add_parser("segment", help="per-face part labels, one integer per line")
    _add_mesh_arguments(segment)
    segment.add_argument("-o", "--output", required=True, help="output .seg file")
    _add_segment_options(segment)
    segment.add_argument("--colored", metavar="OUT.glb", help="write a GLB coloured by part")
    segment.add_argument(
        "--tree",
        metavar="OUT.json",
        help="write the part tree (graphcut): leaf per input face, parent of "
        "each node, merge costs; any part count is a cut of it",
    )
    segment.add_argument(
        "--parts-glb",
        metavar="OUT.glb",
        help="write a GLB with one mesh node per part, keeping the file's normals, UVs, "
        "colours, materials and scene objects",
    )
    segment.add_argument(
        "--usd",
        metavar="OUT.usda",
        help="write the parts as USD (.usda/.usdc/.usdz): a USD input's own "
        "stage with one GeomSubset per part (family 'part') and a display "
        "colour per face on every mesh prim; other inputs: a new stage "
        "whose faces are the input faces",
    )
    segment.add_argument(
        "--labeler",
        metavar="FILE",
        help="named parts: label every face with a trained labeller (neural-shdf labeler "
        "train); the output holds the training labels' own integers",
    )
    segment.add_argument(
        "--confidence", metavar="OUT.txt", help="with --labeler: confidence per face"
    )
    segment.set_defaults(run=cmd_segment)

    add_labeler_parser(commands)

    batch = commands.add_parser(
        "batch",
        help="segment many meshes (files, folders, manifests); resumable, parallel",
        description="Per asset: OUT_DIR/<name>.seg (and/or .shdf, .colored.glb, .parts.glb, "
        ".parts.usda) "
        "and a row of OUT_DIR/manifest.csv. A re-run skips finished assets. "
        "Exit code 2 when any asset failed (its row says why).",
    )
    batch.add_argument(
        "inputs",
        nargs="+",
        metavar="INPUT",
        help="mesh file, folder (searched recursively) or manifest "
        "(.txt/.lst: one path per line; .csv: a 'path' column)",
    )
    batch.add_argument("-o", "--output", required=True, metavar="OUT_DIR", help="output folder")
    batch.add_argument("--format", help="file type when the extensions do not say it")
    batch.add_argument(
        "--method",
        choices=["auto", "exact", "sampled", "neural"],
        default="auto",
        help="ShDF producer (see `neural-shdf shdf --help`)",
    )
    batch.add_argument("--seed", type=int, default=0, help="seed of every random step")
    _add_segment_options(batch)
    batch.add_argument(
        "--shdf-only", action="store_true", help="write only the per-face ShDF (no segmentation)"
    )
    batch.add_argument(
        "--formats",
        nargs="+",
        choices=["seg", "shdf", "colored", "parts", "confidence", "usd"],
        help="outputs per asset (default: seg): labels, ShDF values, "
        "GLB coloured by part, GLB with one node per part (keeping the file's UVs, normals, "
        "materials and objects), confidence per face (--labeler), USD (.parts.usda: a USD "
        "input's own stage with a GeomSubset per part)",
    )
    batch.add_argument(
        "--labeler",
        metavar="FILE",
        help="named parts by a part labeller (labeler train): .seg holds the training "
        "labels' own integers, .confidence the confidence per face, parts GLB nodes the "
        "label names; label_names.json in the output folder",
    )
    batch.add_argument("--workers", type=int, help="local worker processes (default: one per core)")
    batch.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="run on a Dask distributed cluster (tcp://host:port); needs the "
        "'distributed' extra and the same paths on every worker",
    )
    batch.add_argument(
        "--cache",
        metavar="URL_OR_DIR",
        help="ShDF cache shared with the service: redis://host:port/db or a folder",
    )
    batch.add_argument(
        "--max-faces",
        type=int,
        default=DEFAULT_MAX_FACES,
        help="assets with more triangles fail without being computed",
    )
    batch.add_argument(
        "--max-vertices",
        type=int,
        default=DEFAULT_MAX_VERTICES,
        help="assets with more vertices (glTF instances counted) fail",
    )
    batch.add_argument("-q", "--quiet", action="store_true", help="no progress bar or summary")
    batch.set_defaults(run=cmd_batch)

    unwrap = commands.add_parser(
        "unwrap", help="UVs charted part by part, packed into one atlas (GLB or OBJ with vt)"
    )
    _add_mesh_arguments(unwrap)
    unwrap.add_argument(
        "-o",
        "--output",
        required=True,
        help="OUT.glb (UVs + atlas preview texture) or OUT.obj (v/vt per corner)",
    )
    _add_segment_options(unwrap)
    unwrap.add_argument("--atlas-size", type=int, default=1024, help="atlas side in texels")
    unwrap.add_argument("--padding", type=int, default=2, help="texels between charts")
    unwrap.add_argument(
        "--max-stretch",
        type=float,
        default=1.1,
        help="largest L2 stretch of a part kept as one chart (1 = no stretch)",
    )
    unwrap.add_argument(
        "--atlas-png",
        metavar="OUT.png",
        help="write the atlas layout (charts coloured by part, outlined)",
    )
    unwrap.add_argument("--labels", metavar="OUT.seg", help="also write the part labels")
    unwrap.set_defaults(run=cmd_unwrap)

    evaluate = commands.add_parser("eval", help="Princeton Segmentation Benchmark metrics")
    evaluate.add_argument("bench_dir", help="folder with off/, seg/ (and cgal/) subfolders")
    evaluate.add_argument(
        "--methods",
        nargs="+",
        default=["exact-graphcut"],
        help="methods to evaluate (e.g. cgal exact-graphcut exact-metis)",
    )
    evaluate.add_argument("--limit", type=int, help="evaluate only the first N models")
    evaluate.add_argument("--cache-dir", help="where computed ShDF values are cached")
    evaluate.add_argument("--jobs", type=int, default=1, help="worker processes (at most 2)")
    evaluate.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    evaluate.set_defaults(run=cmd_eval)

    serve = commands.add_parser("serve", help="run the REST service")
    serve.add_argument("--host", help="bind address (default from settings: 127.0.0.1)")
    serve.add_argument("--port", type=int, help="port (default from settings: 8000)")
    serve.add_argument("--workers", type=int, help="uvicorn worker processes")
    serve.set_defaults(run=cmd_serve)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``neural-shdf`` console script."""
    args = build_parser().parse_args(argv)
    try:
        return int(args.run(args) or 0)
    except ModelUnavailableError as error:
        print(f"neural-shdf: {error}", file=sys.stderr)
        return EXIT_MODEL_UNAVAILABLE
    except (NeuralShdfError, FileNotFoundError, IsADirectoryError) as error:
        print(f"neural-shdf: error: {error}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
