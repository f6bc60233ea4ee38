"""Exports: palette, coloured GLB without blending across parts, per-part GLB, label files,
unwrapped GLB."""

import colorsys
import io
import json
import struct
import subprocess
from pathlib import Path

import numpy as np
import pytest
import trimesh

from neural_shdf.errors import ParameterError
from neural_shdf.export import (
    UNLABELED_COLOR,
    colored_glb,
    display_geometry,
    linear_color_bytes,
    part_color_hex,
    part_colors,
    part_name,
    parts_glb,
    read_labels,
    read_values,
    split_by_part,
    srgb_to_linear,
    write_labels,
    write_values,
)
from neural_shdf.mesh import TriangleMesh
from neural_shdf.mesh_io import load_mesh


def _labels_by_height(mesh, n_parts=3):
    """Part per triangle from the centroid's z: parts are connected bands sharing vertices."""
    z = mesh.vertices[mesh.faces].mean(axis=1)[:, 2]
    edges = np.quantile(z, np.linspace(0, 1, n_parts + 1)[1:-1])
    return np.searchsorted(edges, z).astype(np.int64)


def test_palette_is_deterministic_distinct_and_opaque():
    colors = part_colors(60)
    assert colors.shape == (60, 4) and colors.dtype == np.uint8
    np.testing.assert_array_equal(colors, part_colors(60))
    np.testing.assert_array_equal(part_colors(5), colors[:5])
    assert len(np.unique(colors[:, :3], axis=0)) == 60
    assert (colors[:, 3] == 255).all()
    assert part_colors(0).shape == (0, 4)


def test_palette_beyond_the_base_colours_is_golden_angle_hsv():
    colors = part_colors(500)
    golden = (np.sqrt(5.0) - 1.0) / 2.0
    for i in (12, 13, 14, 100, 499):
        k = i - 12
        rgb = colorsys.hsv_to_rgb((0.13 + k * golden) % 1.0, (0.55, 0.8, 0.4)[k % 3],
                                  (0.9, 0.7, 0.8)[(k // 3) % 3])  # fmt: skip
        np.testing.assert_array_equal(colors[i, :3], np.round(np.array(rgb) * 255))


def test_split_by_part_never_shares_a_vertex(sphere_mesh):
    labels = _labels_by_height(sphere_mesh)
    vertices, faces, vertex_label = split_by_part(sphere_mesh, labels)
    np.testing.assert_array_equal(vertex_label[faces], np.repeat(labels[:, None], 3, axis=1))
    np.testing.assert_allclose(vertices[faces], sphere_mesh.vertices[sphere_mesh.faces])


def test_colored_glb_faces_have_their_part_colour(sphere_mesh):
    labels = _labels_by_height(sphere_mesh)
    labels[0] = -1  # an unlabelled triangle gets the neutral colour
    data = colored_glb(sphere_mesh, labels)
    # Our reader: the same triangles in the same order.
    back = load_mesh(data, "glb")
    np.testing.assert_allclose(
        back.vertices[back.faces], sphere_mesh.vertices[sphere_mesh.faces], atol=1e-6
    )
    # trimesh's reader: every corner of every face carries its part's colour.
    scene = trimesh.load(trimesh.util.wrap_as_stream(data), file_type="glb", process=False)
    (geometry,) = scene.geometry.values()
    corner_colors = geometry.visual.vertex_colors[geometry.faces]
    expected = np.where(labels[:, None] >= 0, part_colors(3)[labels.clip(0)], UNLABELED_COLOR)
    expected = linear_color_bytes(expected)  # glTF's COLOR_0 is linear
    np.testing.assert_array_equal(corner_colors, np.repeat(expected[:, None], 3, axis=1))


def test_srgb_to_linear_is_the_srgb_transfer_function():
    np.testing.assert_allclose(srgb_to_linear([0.0, 0.04045, 0.5, 1.0]),
                               [0.0, 0.04045 / 12.92, 0.214041, 1.0], atol=1e-6)  # fmt: skip
    # Orange #e69f00 (part 0): what a linear format must hold so that it shows as #e69f00.
    np.testing.assert_array_equal(linear_color_bytes([230, 159, 0, 255]), [202, 88, 0, 255])
    assert (np.diff(linear_color_bytes(np.arange(256, dtype=np.uint8))) >= 0).all()


def test_colored_glb_custom_rgb_colors(box_mesh):
    labels = np.repeat([0, 1], 6)
    data = colored_glb(box_mesh, labels, colors=np.array([[255, 0, 0], [0, 0, 255]], np.uint8))
    # Pure primaries are the same in sRGB and linear.
    scene = trimesh.load(trimesh.util.wrap_as_stream(data), file_type="glb", process=False)
    (geometry,) = scene.geometry.values()
    colors = geometry.visual.vertex_colors[geometry.faces[:, 0]]
    np.testing.assert_array_equal(colors[:6], [[255, 0, 0, 255]] * 6)
    np.testing.assert_array_equal(colors[6:], [[0, 0, 255, 255]] * 6)


def test_parts_glb_round_trips_parts_and_triangle_counts(sphere_mesh):
    labels = _labels_by_height(sphere_mesh, 4)
    data = parts_glb(sphere_mesh, labels)
    scene = trimesh.load(trimesh.util.wrap_as_stream(data), file_type="glb", process=False)
    counts = {name: len(g.faces) for name, g in scene.geometry.items()}
    assert counts == {part_name(p): int((labels == p).sum()) for p in range(4)}
    assert sorted(scene.graph.nodes_geometry) == [f"part_{p:03d}" for p in range(4)]
    # Flattened by our reader: parts in label order, each part's triangles in mesh order.
    back = load_mesh(data, "glb")
    order = np.argsort(labels, kind="stable")
    np.testing.assert_allclose(
        back.vertices[back.faces], sphere_mesh.vertices[sphere_mesh.faces[order]], atol=1e-6
    )


def test_parts_glb_writes_ten_thousand_parts():
    sphere = trimesh.creation.icosphere(subdivisions=5)
    mesh = TriangleMesh(np.asarray(sphere.vertices), np.asarray(sphere.faces)[:20_000])
    labels = np.arange(mesh.face_count)[::-1] // 2  # parts in reverse face order
    data = parts_glb(mesh, labels)
    length = struct.unpack_from("<I", data, 12)[0]
    document = json.loads(data[20 : 20 + length])
    assert len(document["nodes"]) == len(document["meshes"]) == 10_000
    assert document["nodes"][9_999] == {"name": "part_9999", "mesh": 9_999}
    scene = trimesh.load(trimesh.util.wrap_as_stream(data), file_type="glb", process=False)
    assert len(scene.geometry) == 10_000
    assert all(len(g.faces) == 2 for g in scene.geometry.values())
    part = scene.geometry["part_1234"]
    faces = mesh.faces[np.sort(np.flatnonzero(labels == 1234))]
    np.testing.assert_allclose(part.vertices[part.faces], mesh.vertices[faces], atol=1e-6)
    np.testing.assert_array_equal(
        part.visual.vertex_colors, np.tile(linear_color_bytes(part_colors(1235))[-1], (4, 1))
    )
    back = load_mesh(data, "glb")
    order = np.argsort(labels, kind="stable")
    np.testing.assert_allclose(
        back.vertices[back.faces], mesh.vertices[mesh.faces[order]], atol=1e-6
    )


def test_parts_glb_of_no_faces_is_an_empty_scene():
    mesh = TriangleMesh(np.eye(3), np.zeros((0, 3), dtype=np.int64))
    scene = trimesh.load(
        trimesh.util.wrap_as_stream(parts_glb(mesh, np.zeros(0, dtype=np.int64))),
        file_type="glb",
    )
    assert len(scene.geometry) == 0


def test_labels_must_be_one_integer_per_triangle(box_mesh):
    with pytest.raises(ParameterError, match="one integer label per triangle"):
        colored_glb(box_mesh, np.zeros(5, dtype=int))
    with pytest.raises(ParameterError, match="face_origin"):
        parts_glb(box_mesh, np.zeros(12))


def test_label_file_round_trip(tmp_path):
    labels = np.array([0, 3, 3, -1, 12])
    path = tmp_path / "mesh.seg"
    write_labels(path, labels)
    assert path.read_text() == "0\n3\n3\n-1\n12\n"
    np.testing.assert_array_equal(read_labels(path), labels)


def test_bad_label_file_names_the_line(tmp_path):
    path = tmp_path / "bad.seg"
    path.write_text("1\n2\nthree\n")
    with pytest.raises(ParameterError, match="line 3"):
        read_labels(path)


def test_values_round_trip_to_float32_precision(tmp_path):
    values = np.random.default_rng(0).random(100) * 10.0 ** np.arange(-30, 70)
    path = tmp_path / "mesh.sdf"
    write_values(path, values)
    np.testing.assert_allclose(read_values(path), values, rtol=1e-8)
    assert len(path.read_text().splitlines()) == 100
    # Float32 values survive exactly (9 significant digits is enough for float32).
    single = values[:60].astype(np.float32)
    write_values(path, single)
    np.testing.assert_array_equal(read_values(path).astype(np.float32), single)


def test_read_values_reads_cgal_sdf_files(shared_data):
    path = shared_data / "psb-dev" / "cgal" / "1.sdf"
    if not path.is_file():
        pytest.skip(f"{path} is absent")
    values = read_values(path)
    assert len(values) == 9408 and values.min() >= 0 and values.max() <= 1


def test_unwrapped_glb_round_trips_faces_order_and_uvs():
    from neural_shdf.export import unwrapped_glb
    from neural_shdf.unwrap import atlas_layout_image, png_bytes, unwrap

    sphere = trimesh.creation.icosphere(subdivisions=2)
    mesh = TriangleMesh(sphere.vertices, sphere.faces)
    labels = (sphere.triangles_center[:, 2] > 0).astype(np.int64)
    atlas = unwrap(mesh, labels)
    data = unwrapped_glb(mesh, atlas, texture_png=png_bytes(atlas_layout_image(atlas, size=128)))
    loaded = trimesh.load(io.BytesIO(data), file_type="glb", force="mesh", process=False)
    assert len(loaded.faces) == mesh.face_count
    assert np.allclose(loaded.vertices[loaded.faces], mesh.vertices[mesh.faces], atol=1e-6)
    corner_uvs = loaded.visual.uv[loaded.faces]
    assert np.allclose(corner_uvs, atlas.corner_uvs, atol=1e-6)
    assert loaded.visual.material.baseColorTexture.size == (128, 128)


def test_part_color_hex_spells_the_palette():
    hexes = part_color_hex(20)
    assert hexes[0] == "#e69f00"
    rgb = [[int(h[i : i + 2], 16) for i in (1, 3, 5)] for h in hexes]
    np.testing.assert_array_equal(rgb, part_colors(20)[:, :3])


def test_display_geometry_layout_round_trips_the_triangles_and_face_map():
    vertices = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1]], float)
    obj = "".join(f"v {x} {y} {z}\n" for x, y, z in vertices) + "f 1 2 3 4\nf 1 2\nf 1 2 5\n"
    mesh = load_mesh(obj.encode(), "obj")
    blob = display_geometry(mesh)
    magic, version, v, t, f = np.frombuffer(blob[:4], "S4")[0], *np.frombuffer(blob[4:20], "<u4")
    assert (magic, version, v, t, f) == (b"NSHG", 1, 5, 3, 3)
    positions = np.frombuffer(blob, "<f4", 3 * v, 20).reshape(-1, 3)
    triangles = np.frombuffer(blob, "<u4", 3 * t, 20 + 12 * v).reshape(-1, 3)
    origin = np.frombuffer(blob, "<u4", t, 20 + 12 * v + 12 * t)
    assert len(blob) == 20 + 12 * v + 12 * t + 4 * t
    np.testing.assert_array_equal(positions, vertices.astype(np.float32))
    np.testing.assert_array_equal(triangles, [[0, 1, 2], [0, 2, 3], [0, 1, 4]])
    np.testing.assert_array_equal(origin, [0, 0, 2])  # the 2-vertex face has no triangle


NODE_TOOLS = Path(__file__).resolve().parent / "node"


def _khronos_issues(tmp_path, documents: dict[str, bytes]) -> dict[str, dict]:
    """The Khronos glTF validator's issues of each document (``bash scripts/test`` installs
    it under tests/node)."""
    assert (NODE_TOOLS / "node_modules" / "gltf-validator").is_dir(), (
        "the glTF validator is not installed: run `bash scripts/test` (npm ci in tests/node)"
    )
    paths = []
    for name, data in documents.items():
        paths.append(tmp_path / name)
        paths[-1].write_bytes(data)
    run = subprocess.run(
        ["node", str(NODE_TOOLS / "validate_gltf.js"), *map(str, paths)],
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    )
    return {Path(report["file"]).name: report["issues"] for report in json.loads(run.stdout)}


def test_every_glb_we_write_passes_the_khronos_validator(tmp_path, sphere_mesh):
    from neural_shdf.export import unwrapped_glb
    from neural_shdf.unwrap import atlas_layout_png, unwrap

    labels = _labels_by_height(sphere_mesh, 4)
    atlas = unwrap(sphere_mesh, labels)
    documents = {
        "segmented.glb": colored_glb(sphere_mesh, labels),
        "parts.glb": parts_glb(sphere_mesh, labels),
        "parts-with-unlabeled.glb": parts_glb(sphere_mesh, np.where(labels == 2, -1, labels)),
        "unwrapped.glb": unwrapped_glb(
            sphere_mesh, atlas, texture_png=atlas_layout_png(atlas, size=64)
        ),
    }
    issues = _khronos_issues(tmp_path, documents)
    assert set(issues) == set(documents)
    for name, found in issues.items():
        errors = [m for m in found["messages"] if m["severity"] == 0]
        warnings = [m for m in found["messages"] if m["severity"] == 1]
        assert found["numErrors"] == 0 and not errors, (name, errors)
        assert found["numWarnings"] == 0, (name, warnings)


def test_glbs_we_write_read_back_with_every_face_in_place(sphere_mesh):
    """Our own reader takes our GLBs back: segmented.glb in the mesh's order, parts.glb
    part by part in label order, each part in the mesh's order."""
    labels = _labels_by_height(sphere_mesh, 3)
    expected = sphere_mesh.vertices[sphere_mesh.faces]
    in_part_order = expected[np.argsort(labels, kind="stable")]
    for data, triangles in (
        (colored_glb(sphere_mesh, labels), expected),
        (parts_glb(sphere_mesh, labels), in_part_order),
    ):
        loaded = load_mesh(data, "glb")
        np.testing.assert_allclose(loaded.vertices[loaded.faces], triangles, atol=1e-6)
