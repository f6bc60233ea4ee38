"""GLB writers: coloured GLB without blending across parts, one node per part, unwrapped GLB;
every file passes the Khronos validator and reads back face for face."""

import io
import json
import struct
import subprocess
from pathlib import Path

import numpy as np
import pytest
import trimesh

from neural_shdf.errors import ParameterError
from neural_shdf.exchange.gltf_writer import colored_glb, part_name, parts_glb, split_by_part
from neural_shdf.mesh import TriangleMesh
from neural_shdf.mesh_io import load_mesh
from neural_shdf.palette import UNLABELED_COLOR, linear_color_bytes, part_colors


def _labels_by_height(mesh, n_parts=3):
    """Part per triangle from the centroid's z: parts are connected bands sharing vertices."""
    z = mesh.vertices[mesh.faces].mean(axis=1)[:, 2]
    edges = np.quantile(z, np.linspace(0, 1, n_parts + 1)[1:-1])
    return np.searchsorted(edges, z).astype(np.int64)


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


def test_unwrapped_glb_round_trips_faces_order_and_uvs():
    from neural_shdf.exchange.gltf_writer import unwrapped_glb
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


NODE_TOOLS = Path(__file__).resolve().parents[1] / "node"


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
    from neural_shdf.exchange.gltf_writer import unwrapped_glb
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


def test_parts_glb_names_nodes_and_meshes_by_the_given_names(sphere_mesh):
    labels = _labels_by_height(sphere_mesh, 3) * 2 + 1  # label values 1, 3, 5
    names = {1: "left arm", 3: 'say "hi"\\', 7: "unused"}
    data = parts_glb(sphere_mesh, labels, names=names)
    length = struct.unpack_from("<I", data, 12)[0]
    document = json.loads(data[20 : 20 + length])
    expected = ["left arm", 'say "hi"\\', part_name(5)]  # 5 has no name: part_name
    assert [node["name"] for node in document["nodes"]] == expected
    assert [mesh["name"] for mesh in document["meshes"]] == expected
    assert load_mesh(data, "glb").face_count == sphere_mesh.face_count


def _corner_values(source, name):
    """Per triangle corner values of an attribute (``uvs`` as a list of sets)."""
    attributes = source.attributes
    if name == "uvs":
        return [uv[attributes.corners] for uv in attributes.uvs]
    return getattr(attributes, name)[attributes.corners]


def test_parts_keep_the_files_normals_uvs_colours_materials_and_objects(tmp_path):
    """A scene of two nodes (one mirrored), two primitives with normals, tangents, two UV
    sets, colours and a textured material: parts.glb keeps all of it on every part,
    under one node per object, and passes the Khronos validator without a warning."""
    from neural_shdf.mesh_io import load_source

    from .scene_helpers import parts_order, textured_scene_glb

    source = load_source(textured_scene_glb(), "glb")
    mesh = source.mesh
    labels = _labels_by_height(mesh, 3)
    data = parts_glb(mesh, labels, attributes=source.attributes)
    issues = _khronos_issues(tmp_path, {"scene-parts.glb": data})["scene-parts.glb"]
    assert issues["numErrors"] == 0 and issues["numWarnings"] == 0, issues["messages"]

    back = load_source(data, "glb")
    order = parts_order(source, labels)
    assert back.mesh.face_count == mesh.face_count
    np.testing.assert_allclose(
        back.mesh.vertices[back.mesh.faces], mesh.vertices[mesh.faces][order], atol=1e-5
    )
    for name in ("normals", "tangents", "colors"):
        np.testing.assert_array_equal(
            _corner_values(back, name), _corner_values(source, name)[order], err_msg=name
        )
    back_uvs, source_uvs = _corner_values(back, "uvs"), _corner_values(source, "uvs")
    assert len(back_uvs) == len(source_uvs) == 2
    for ours, theirs in zip(back_uvs, source_uvs, strict=True):
        np.testing.assert_array_equal(ours, theirs[order])
    groups, back_groups = source.attributes.groups, back.attributes.groups
    material = [groups[g].material for g in source.attributes.face_group[order]]
    assert [back_groups[g].material for g in back.attributes.face_group] == material

    document = json.loads(data[20 : 20 + struct.unpack_from("<I", data, 12)[0]])
    assert [m["name"] for m in document["materials"]] == ["Painted", "Plain"]
    assert document["images"][0]["mimeType"] == "image/png"
    roots = [document["nodes"][n] for n in document["scenes"][0]["nodes"]]
    assert [node["name"] for node in roots] == ["Body", "Mirror"]
    group_object = np.array([g.object for g in groups])[source.attributes.face_group]
    for index, root in enumerate(roots):  # a child node per part, in label order
        children = [document["nodes"][c]["name"] for c in root["children"]]
        assert children == [part_name(p) for p in np.unique(labels[group_object == index])]
    # Part colours only where the file has no material or colours of its own: nowhere.
    for mesh_entry in document["meshes"]:
        for primitive in mesh_entry["primitives"]:
            assert ("COLOR_0" in primitive["attributes"]) == (primitive["material"] == 0)


def test_parts_names_hook_names_the_given_parts(sphere_mesh):
    labels = _labels_by_height(sphere_mesh, 3)
    data = parts_glb(sphere_mesh, labels, names={1: "handle"})
    document = json.loads(data[20 : 20 + struct.unpack_from("<I", data, 12)[0]])
    assert [node["name"] for node in document["nodes"]] == ["part_000", "handle", "part_002"]


def test_parts_of_an_obj_keep_its_uvs_normals_and_material_names(tmp_path):
    from neural_shdf.mesh_io import load_source

    sphere = trimesh.creation.icosphere(subdivisions=2)
    uv = (sphere.vertices[:, :2] + 1) / 2
    lines = [f"v {x} {y} {z}" for x, y, z in sphere.vertices]
    lines += [f"vt {u} {v}" for u, v in uv]
    lines += [f"vn {x} {y} {z}" for x, y, z in sphere.vertex_normals]
    for index, (a, b, c) in enumerate(sphere.faces + 1):
        if index in (0, 200):
            lines.append("usemtl " + ("skin" if index == 0 else "cloth"))
        lines.append(f"f {a}/{a}/{a} {b}/{b}/{b} {c}/{c}/{c}")
    source = load_source("\n".join(lines).encode(), "obj")
    labels = _labels_by_height(source.mesh, 4)
    data = parts_glb(source.mesh, labels, attributes=source.attributes)
    issues = _khronos_issues(tmp_path, {"obj-parts.glb": data})["obj-parts.glb"]
    assert issues["numErrors"] == 0 and issues["numWarnings"] == 0, issues["messages"]
    back = load_source(data, "glb")
    order = np.lexsort((source.attributes.face_group, labels))
    (back_uv,) = _corner_values(back, "uvs")
    np.testing.assert_allclose(back_uv[..., 1], 1 - uv[sphere.faces[order]][..., 1], atol=1e-7)
    np.testing.assert_allclose(
        _corner_values(back, "normals"), sphere.vertex_normals[sphere.faces[order]], atol=1e-6
    )
    document = json.loads(data[20 : 20 + struct.unpack_from("<I", data, 12)[0]])
    assert [m["name"] for m in document["materials"]] == ["skin", "cloth"]
    # Named materials without definitions (no .mtl read): the part colours show.
    assert all("COLOR_0" in p["attributes"] for m in document["meshes"] for p in m["primitives"])


def test_parts_of_an_object_scaled_to_nothing_keep_their_world_positions():
    """A node with a zero scale cannot be inverted: its parts keep world positions under a
    node without a transform, and the file reads back face for face."""
    from neural_shdf.mesh_io import load_source

    from .scene_helpers import textured_scene_glb

    data = textured_scene_glb()
    document = json.loads(data[20 : 20 + struct.unpack_from("<I", data, 12)[0]])
    source = load_source(data, "glb")
    flat = load_source(
        data.replace(b'"scale": [-1.0, 1.0, 1.0]', b'"scale": [ 0.0, 1.0, 1.0]'), "glb"
    )
    assert document["nodes"][1]["scale"] == [-1.0, 1.0, 1.0]
    assert flat.mesh.face_count == source.mesh.face_count
    labels = _labels_by_height(flat.mesh, 2)
    back = load_mesh(parts_glb(flat.mesh, labels, attributes=flat.attributes), "glb")
    assert back.face_count == flat.mesh.face_count
    assert np.isclose(back.normals_and_areas[1].sum(), flat.mesh.normals_and_areas[1].sum())


def test_a_primitive_with_a_normal_of_no_direction_loses_its_normals_and_tangents(tmp_path):
    """glTF allows only unit normals and no TANGENT without a NORMAL: a primitive with a
    zero normal keeps its UVs but neither; the other primitive keeps all of its own."""
    from neural_shdf.mesh_io import load_source

    from .scene_helpers import GltfBuilder

    builder = GltfBuilder()
    square = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], np.float32)
    primitives = []
    for shift, broken in ((0.0, False), (2.0, True)):
        normals = np.tile([0, 0, 1], (4, 1)).astype(np.float32)
        if broken:
            normals[2] = 0
        attributes = {
            "POSITION": builder.accessor(
                (square + [shift, 0, 0]).astype(np.float32), "VEC3", minmax=True
            ),
            "NORMAL": builder.accessor(normals, "VEC3"),
            "TANGENT": builder.accessor(np.tile([1, 0, 0, 1], (4, 1)).astype(np.float32), "VEC4"),
            "TEXCOORD_0": builder.accessor(square[:, :2].copy(), "VEC2"),
        }
        indices = builder.accessor(np.array([0, 1, 2, 0, 2, 3], np.uint32), "SCALAR")
        primitives.append({"attributes": attributes, "indices": indices})
    builder.doc["meshes"] = [{"primitives": primitives}]
    builder.doc["nodes"] = [{"mesh": 0}]
    source = load_source(builder.glb(), "glb")
    kept, dropped = source.attributes.groups
    assert (kept.normals, kept.tangents, kept.uv_sets) == (True, True, 1)
    assert (dropped.normals, dropped.tangents, dropped.uv_sets) == (False, False, 1)
    data = parts_glb(source.mesh, np.zeros(4, np.int64), attributes=source.attributes)
    issues = _khronos_issues(tmp_path, {"normals.glb": data})["normals.glb"]
    assert issues["numErrors"] == 0 and issues["numWarnings"] == 0, issues["messages"]
