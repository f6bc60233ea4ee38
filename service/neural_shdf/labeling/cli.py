"""The labeller's commands: ``neural-shdf labeler train`` and ``neural-shdf segment --labeler``.

``cli.py`` registers them (``add_labeler_parser``) and hands ``segment --labeler`` over
(``segment_with_labeler``).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from neural_shdf.errors import ParameterError
from neural_shdf.labeling._library import (
    SUPPORTED_FORMATS,
    compute_shdf,
    load_mesh,
    read_labels,
    write_labels,
    write_values,
)
from neural_shdf.labeling.labeler import DEFAULT_SMOOTHING, label_mesh, train_labeler
from neural_shdf.labeling.model import Labeler, load_labeler, save_labeler

if TYPE_CHECKING:
    from neural_shdf.mesh import TriangleMesh


def add_labeler_parser(commands: argparse._SubParsersAction) -> None:
    """``labeler train MESH_DIR LABEL_DIR -o FILE [--names a,b,...]``."""
    labeler = commands.add_parser("labeler", help="named parts: train a part labeller")
    actions = labeler.add_subparsers(dest="labeler_command", required=True)
    train = actions.add_parser(
        "train",
        help="train a labeller from meshes and their labels (LABEL_DIR/{mesh stem}.txt: "
        "one integer label per input face, in the file's face order)",
    )
    train.add_argument("mesh_dir", help="folder of meshes (OBJ, OFF, PLY, STL, GLB/glTF, USD)")
    train.add_argument("label_dir", help="folder of {mesh stem}.txt label files")
    train.add_argument("-o", "--output", required=True, help="labeller file to write (.npz)")
    train.add_argument(
        "--names",
        help="label names, comma-separated, one per distinct label in increasing label "
        "order (default: the labels as text)",
    )
    train.add_argument(
        "--method",
        choices=["auto", "exact", "sampled", "neural"],
        default="auto",
        help="ShDF producer for the training meshes (default auto)",
    )
    train.add_argument("--smoothing", type=float, help="graph-cut smoothing of the labels")
    train.add_argument("-q", "--quiet", action="store_true", help="no progress or summary")
    train.set_defaults(run=cmd_labeler_train)


def _names(text: str | None) -> list[str] | None:
    if text is None:
        return None
    names = [name.strip() for name in text.split(",")]
    if not all(names):
        raise ParameterError(f"--names has an empty name: {text!r}")
    return names


def training_pairs(mesh_dir: Path, label_dir: Path) -> tuple[list[Path], list[Path]]:
    """(meshes, their label files) for every mesh in ``mesh_dir`` with ``{stem}.txt`` in
    ``label_dir``, by name; meshes without labels are skipped (reported by the caller)."""
    for folder in (mesh_dir, label_dir):
        if not folder.is_dir():
            raise FileNotFoundError(f"folder not found: {folder}")
    extensions = {"." + name for name in SUPPORTED_FORMATS}
    meshes = sorted(p for p in mesh_dir.iterdir() if p.is_file() and p.suffix.lower() in extensions)
    paired = [p for p in meshes if (label_dir / f"{p.stem}.txt").is_file()]
    if not paired:
        raise ParameterError(
            f"no mesh in {mesh_dir} has a label file {label_dir}/{{mesh stem}}.txt "
            f"({len(meshes)} meshes found)"
        )
    return paired, [label_dir / f"{p.stem}.txt" for p in paired]


def cmd_labeler_train(args: argparse.Namespace) -> int:
    start = time.perf_counter()
    meshes_paths, label_paths = training_pairs(Path(args.mesh_dir), Path(args.label_dir))
    meshes, labels, shdf = [], [], []
    for mesh_path, label_path in zip(meshes_paths, label_paths, strict=True):
        mesh = load_mesh(mesh_path)
        face_labels = read_labels(label_path)
        if len(face_labels) != mesh.input_face_count:
            raise ParameterError(
                f"{label_path} has {len(face_labels)} labels but {mesh_path.name} has "
                f"{mesh.input_face_count} faces: give one label per face, in the file's order"
            )
        meshes.append(mesh)
        labels.append(face_labels)
        shdf.append(compute_shdf(mesh, method=args.method).values)
    smoothing = DEFAULT_SMOOTHING if args.smoothing is None else args.smoothing
    labeler = train_labeler(meshes, labels, _names(args.names), shdf=shdf, smoothing=smoothing)
    save_labeler(labeler, args.output)
    if not args.quiet:
        skipped = len([p for p in Path(args.mesh_dir).iterdir() if p.is_file()]) - len(meshes)
        pairs = zip(labeler.label_values, labeler.label_names, strict=True)
        names = ", ".join(f"{value}={name}" for value, name in pairs)
        print(
            f"labeller of {len(meshes)} meshes ({skipped} other files skipped), labels {names}, "
            f"trained in {time.perf_counter() - start:.1f} s -> {args.output}",
            file=sys.stderr,
        )
    return 0


def labeler_option(args: argparse.Namespace) -> Labeler:
    """The labeller of ``segment --labeler FILE``, loaded and its flags checked before the
    mesh is read or its ShDF computed (a bad file is reported at once)."""
    others = [
        f"--{name.replace('_', '-')}"
        for name in ("tree", "colored", "parts_glb", "usd")
        if getattr(args, name, None)
    ]
    if not args.labeler:
        raise ParameterError("--confidence needs --labeler")
    if others:
        raise ParameterError(f"{', '.join(others)} cannot be combined with --labeler yet")
    return load_labeler(args.labeler)


def segment_with_labeler(
    args: argparse.Namespace, mesh: TriangleMesh, shdf: np.ndarray, labeler: Labeler
) -> int:
    """``segment --labeler FILE``: one label per input face (the training labels' own
    integers) to ``args.output``; ``args.confidence``: the confidence per face too."""
    start = time.perf_counter()
    labels, confidence = label_mesh(mesh, labeler, shdf=shdf)
    write_labels(args.output, labels)
    if args.confidence:
        write_values(args.confidence, confidence)
    if not args.quiet:
        used = np.unique(labels[labels >= 0])
        names = dict(zip(labeler.label_values.tolist(), labeler.label_names, strict=True))
        print(
            f"{len(used)} labels ({', '.join(names[int(v)] for v in used)}), "
            f"{mesh.input_face_count} faces, labelled in {time.perf_counter() - start:.2f} s",
            file=sys.stderr,
        )
    return 0
