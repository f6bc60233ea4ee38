"""Command-line interface: ``neural-shdf shdf|segment|eval|serve``.

A stable contract for pipelines: per-face outputs have one line per face of the
input file, in the input file's order; errors go to stderr with a non-zero exit.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from neural_shdf.errors import NeuralShdfError

#: Exit codes: 0 ok, 1 unexpected failure, 2 bad input or usage, 3 model unavailable.
EXIT_BAD_INPUT = 2
EXIT_MODEL_UNAVAILABLE = 3


@contextmanager
def progress_bar(description: str, enabled: bool = True) -> Iterator[Callable[[float], None]]:
    """A tqdm bar on stderr that appears only for work lasting more than a second."""
    from tqdm import tqdm

    bar = tqdm(
        total=1000,
        desc=description,
        delay=1.0,
        disable=not enabled,
        file=sys.stderr,
        leave=False,
        bar_format="{desc}: {percentage:3.0f}%|{bar}| {elapsed}<{remaining}",
    )

    def update(fraction: float) -> None:
        bar.n = int(1000 * min(max(fraction, 0.0), 1.0))
        bar.refresh()

    try:
        yield update
    finally:
        bar.close()


def _load(path: str, file_type: str | None):
    from neural_shdf.mesh_io import load_mesh

    if not Path(path).is_file():
        raise FileNotFoundError(f"mesh file not found: {path}")
    return load_mesh(Path(path), file_type)


def _shdf(mesh, method: str, seed: int, graph, quiet: bool) -> np.ndarray:
    from neural_shdf.pipeline import compute_shdf

    with progress_bar(f"{method} ShDF", enabled=not quiet) as progress:
        return compute_shdf(mesh, method=method, seed=seed, graph=graph, progress=progress)


def cmd_shdf(args: argparse.Namespace) -> int:
    from neural_shdf.export import write_values
    from neural_shdf.pipeline import mesh_face_graph

    mesh = _load(args.mesh, args.format)
    values = _shdf(mesh, args.method, args.seed, mesh_face_graph(mesh), args.quiet)
    _, areas = mesh.normals_and_areas
    write_values(args.output, mesh.to_input_faces(values, weights=areas + 1e-300))
    return 0


def cmd_segment(args: argparse.Namespace) -> int:
    from neural_shdf.errors import ParameterError
    from neural_shdf.export import colored_glb, parts_glb, write_labels, write_part_tree
    from neural_shdf.pipeline import input_face_labels, mesh_face_graph, segment_mesh_with_details
    from neural_shdf.segment import SegmentParams

    params = SegmentParams.from_attributes(args)
    if args.tree and params.partitioner != "graphcut":
        raise ParameterError("--tree needs the graphcut partitioner (metis makes no part tree)")
    mesh = _load(args.mesh, args.format)
    graph = mesh_face_graph(mesh)
    shdf = _shdf(mesh, args.method, args.seed, graph, args.quiet)
    start = time.perf_counter()
    result = segment_mesh_with_details(mesh, shdf, params, graph=graph)
    labels = result.labels
    face_labels, face_leaves = input_face_labels(mesh, result)
    write_labels(args.output, face_labels)
    if args.tree:
        write_part_tree(args.tree, result.tree, face_leaves, result.part_count)
    if args.colored:
        Path(args.colored).write_bytes(colored_glb(mesh, labels))
    if args.parts_glb:
        Path(args.parts_glb).write_bytes(parts_glb(mesh, labels))
    if not args.quiet:
        parts = len(np.unique(labels))
        elapsed = time.perf_counter() - start
        print(f"{parts} parts, {mesh.input_face_count} faces, segmented in {elapsed:.2f} s",
              file=sys.stderr)
    return 0


def cmd_eval(args: argparse.Namespace) -> int:
    from neural_shdf.evaluate.benchmark import format_table, run_eval

    bench_dir = Path(args.bench_dir)
    if not (bench_dir / "off").is_dir() or not (bench_dir / "seg").is_dir():
        raise FileNotFoundError(
            f"{bench_dir} is not a benchmark folder: it needs off/ and seg/ subfolders"
        )
    with progress_bar("models", enabled=not args.quiet) as progress:
        table = run_eval(bench_dir, methods=args.methods, limit=args.limit,
                         cache_dir=args.cache_dir, jobs=args.jobs,
                         progress=lambda done, total: progress(done / max(total, 1)))
    print(format_table(table))
    return 0


def cmd_serve(args: argparse.Namespace) -> int:
    from neural_shdf.api.serve import run

    run(host=args.host, port=args.port, workers=args.workers)
    return 0


def _clusters(text: str) -> int:
    from neural_shdf.segment.params import AUTO_CLUSTERS

    if text == "auto":
        return AUTO_CLUSTERS
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer or 'auto', got {text!r}") from None


def _add_mesh_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("mesh", help="input mesh: OBJ, GLB/glTF, OFF, PLY or STL")
    parser.add_argument("--format", help="file type when the extension does not say it")
    parser.add_argument("--method", choices=["neural", "exact"], default="neural",
                        help="ShDF from the neural network (default, fast) or exact ray casting")
    parser.add_argument("--seed", type=int, default=0, help="seed of every random step")
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress bar or summary")


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
    segment.add_argument("--partitioner", choices=["graphcut", "metis"], default="graphcut")
    segment.add_argument("--clusters", type=_clusters,
                         help="mixture components k, a level of detail (default 9), "
                              "or 'auto' to choose k per mesh by BIC")
    segment.add_argument("--smoothing", type=float, help="graph-cut smoothness lambda")
    segment.add_argument("--parts", type=int,
                         help="number of parts: a cut of the graph cut's part tree (at most its "
                              "leaves), or exactly this many with metis (default: automatic)")
    segment.add_argument("--refine", action="store_true", help="recursively refine parts")
    segment.add_argument("--boundary-smoothing", action="store_true",
                         help="alpha-expansion pass that smooths part boundaries")
    segment.add_argument("--colored", metavar="OUT.glb", help="write a GLB coloured by part")
    segment.add_argument("--tree", metavar="OUT.json",
                         help="write the part tree (graphcut): leaf per input face, parent of "
                              "each node, merge costs; any part count is a cut of it")
    segment.add_argument("--parts-glb", metavar="OUT.glb",
                         help="write a GLB with one mesh node per part")
    segment.set_defaults(run=cmd_segment)

    evaluate = commands.add_parser("eval", help="Princeton Segmentation Benchmark metrics")
    evaluate.add_argument("bench_dir", help="folder with off/, seg/ (and cgal/) subfolders")
    evaluate.add_argument("--methods", nargs="+", default=["exact-graphcut"],
                          help="methods to evaluate (e.g. cgal exact-graphcut exact-metis)")
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
    from neural_shdf.errors import ModelUnavailableError

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
