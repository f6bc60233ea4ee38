"""ShDF post-processing: hole filling, bilateral smoothing, normalisation as CGAL defines them."""

import math
from collections import deque

import numpy as np
import pytest
import trimesh

from neural_shdf.errors import ParameterError
from neural_shdf.geometry import build_face_graph, face_centroids, face_normals
from neural_shdf.mesh import TriangleMesh
from neural_shdf.orientation import open_boundary_faces
from neural_shdf.shdf.postprocess import (
    EXACT_WINDOW_MAX,
    bilateral_smooth,
    bilateral_window,
    faces_away_from,
    fill_missing,
    linear_normalize,
    log_normalize,
    mesh_ring_length,
    patch_bilateral,
    postprocess_shdf,
    ring_length,
    sorted_adjacency,
)


def neighbours_of(graph):
    table = [[] for _ in range(graph.face_count)]
    for a, b in graph.pairs.tolist():
        table[a].append(b)
        table[b].append(a)
    return table


def slow_bilateral(values, graph, window):
    """Face by face, as the definition reads: breadth-first rings, Gaussian weights."""
    table = neighbours_of(graph)
    out = []
    for face in range(graph.face_count):
        ring = {face: 0}
        queue = deque([face])
        while queue:
            current = queue.popleft()
            if ring[current] == window:
                continue
            for other in table[current]:
                if other not in ring:
                    ring[other] = ring[current] + 1
                    queue.append(other)
        centre = values[face]
        deviation = math.sqrt(sum((values[f] - centre) ** 2 for f in ring) / len(ring))
        if deviation == 0:
            out.append(centre)
            continue
        total = norm = 0.0
        for f, level in ring.items():
            w = math.exp(-0.5 * (level / (window / 2)) ** 2) * math.exp(
                -0.5 * ((values[f] - centre) / (1.5 * deviation)) ** 2
            )
            total += w * values[f]
            norm += w
        out.append(total / norm)
    return np.array(out)


@pytest.fixture(scope="module")
def sphere_graph():
    sphere = trimesh.creation.icosphere(subdivisions=2)
    return build_face_graph(sphere.vertices, sphere.faces)


@pytest.mark.parametrize("compiled", [True, False])
@pytest.mark.parametrize("window", [1, 2, 3])
def test_bilateral_matches_the_face_by_face_definition(sphere_graph, window, compiled):
    values = np.random.default_rng(window).random(sphere_graph.face_count)
    fast = bilateral_smooth(values, sphere_graph, window_size=window, compiled=compiled)
    np.testing.assert_allclose(fast, slow_bilateral(values, sphere_graph, window), rtol=1e-12)


def test_bilateral_keeps_constant_values_and_reduces_noise(sphere_graph):
    constant = np.full(sphere_graph.face_count, 0.7)
    np.testing.assert_array_equal(bilateral_smooth(constant, sphere_graph, window_size=2), 0.7)
    noisy = 1.0 + 0.1 * np.random.default_rng(0).standard_normal(sphere_graph.face_count)
    smoothed = bilateral_smooth(noisy, sphere_graph, window_size=2)
    assert smoothed.std() < 0.6 * noisy.std()
    with pytest.raises(ParameterError):
        bilateral_smooth(noisy, sphere_graph, window_size=-1)


def test_bilateral_threads_do_not_change_the_result(sphere_graph):
    values = np.random.default_rng(7).random(sphere_graph.face_count)
    one = bilateral_smooth(values, sphere_graph, window_size=3, threads=1)
    np.testing.assert_array_equal(
        bilateral_smooth(values, sphere_graph, window_size=3, threads=3), one
    )


def test_bilateral_works_in_small_chunks(sphere_graph, monkeypatch):
    import neural_shdf.shdf.postprocess as postprocess

    values = np.random.default_rng(5).random(sphere_graph.face_count)
    whole = bilateral_smooth(values, sphere_graph, window_size=2, compiled=False)
    monkeypatch.setattr(postprocess, "PAIRS_PER_CHUNK", 10)
    chunked = bilateral_smooth(values, sphere_graph, window_size=2, compiled=False)
    np.testing.assert_array_equal(chunked, whole)


def _fill_missing_reference(values: np.ndarray, graph) -> np.ndarray:  # noqa: ANN001
    """Ring by ring over the full adjacency: each ring of missing faces next to valued ones
    takes the mean of its valued neighbours, from the values before the ring."""
    out = values.copy()
    adjacency = graph.csr()
    smallest = float(np.nanmin(out))
    while True:
        ring = {}
        for face in np.flatnonzero(np.isnan(out)):
            near = out[adjacency.indices[adjacency.indptr[face] : adjacency.indptr[face + 1]]]
            near = near[~np.isnan(near)]
            if len(near):
                ring[face] = float(np.mean(near))
        if not ring:
            break
        for face, value in ring.items():
            out[face] = value
    out[np.isnan(out)] = smallest
    return out


def test_fill_missing_matches_the_ring_by_ring_fill(sphere_graph):
    rng = np.random.default_rng(8)
    for share in (0.01, 0.3, 0.9):
        raw = rng.random(sphere_graph.face_count)
        raw[rng.random(len(raw)) < share] = np.nan
        np.testing.assert_allclose(
            fill_missing(raw, sphere_graph), _fill_missing_reference(raw, sphere_graph), rtol=1e-12
        )


def _strip():
    """A strip of faces 0-1-2-3-4 plus an isolated face 5."""
    vertices = np.array(
        [
            [0, 0, 0],
            [1, 0, 0],
            [0, 1, 0],
            [1, 1, 0],
            [0, 2, 0],
            [1, 2, 0],
            [0, 3, 0],
            [5, 5, 5],
            [6, 5, 5],
            [5, 6, 5],
        ],
        dtype=float,
    )
    faces = np.array([[0, 1, 2], [1, 3, 2], [2, 3, 4], [3, 5, 4], [4, 5, 6], [7, 8, 9]])
    return vertices, faces


def test_fill_missing_goes_ring_by_ring_then_the_minimum():
    vertices, faces = _strip()
    graph = build_face_graph(vertices, faces)
    raw = np.array([2.0, np.nan, np.nan, 6.0, np.nan, np.nan])
    filled = fill_missing(raw, graph)
    # First ring: face 1 sees 0 (2.0), face 2 sees 3 (6.0), face 4 sees 3 (6.0); face 5 has
    # no neighbour: the smallest measured value 2.0.
    np.testing.assert_array_equal(filled, [2.0, 2.0, 6.0, 6.0, 6.0, 2.0])
    np.testing.assert_array_equal(fill_missing(np.full(6, np.nan), graph), 0.0)


def test_fill_missing_does_not_depend_on_the_order_of_the_faces():
    """CGAL's fill in face order gave another value to face 2 when the faces came
    reordered (a face filled earlier counted for the later ones)."""
    vertices, faces = _strip()
    raw = np.array([2.0, np.nan, np.nan, 6.0, np.nan, np.nan])
    filled = fill_missing(raw, build_face_graph(vertices, faces))
    order = np.array([5, 4, 3, 2, 1, 0])
    again = fill_missing(raw[order], build_face_graph(vertices, faces[order]))
    np.testing.assert_array_equal(again, filled[order])


def test_bilateral_window_follows_the_face_count():
    assert [bilateral_window(n) for n in (0, 1999, 2000, 7999, 8000, 18000)] == [1, 1, 2, 2, 3, 4]


def test_normalisations():
    values = np.array([3.0, 5.0, 4.0])
    np.testing.assert_allclose(linear_normalize(values), [0.0, 1.0, 0.5])
    np.testing.assert_array_equal(linear_normalize(np.full(3, 2.0)), 0.0)
    x = np.linspace(0, 1, 11)
    np.testing.assert_allclose(log_normalize(x), np.log(5 * x + 1) / np.log(6))
    assert log_normalize(np.array([0.0, 1.0])).tolist() == [0.0, 1.0]
    with pytest.raises(ParameterError):
        log_normalize(x, alpha=0)


def test_postprocess_gives_unit_range_and_checks_sizes(sphere_graph):
    raw = np.random.default_rng(1).random(sphere_graph.face_count) + 2.0
    raw[::7] = np.nan
    values = postprocess_shdf(raw, sphere_graph)
    assert np.isfinite(values).all()
    assert values.min() == 0.0 and values.max() == 1.0
    # The face graph's size has to match.
    with pytest.raises(ParameterError):
        postprocess_shdf(raw[:-1], sphere_graph)
    # Scale invariance: raw values in other units give the same result.
    np.testing.assert_allclose(postprocess_shdf(raw * 1000, sphere_graph), values, atol=1e-12)


def capsule_field() -> tuple[trimesh.Trimesh, np.ndarray]:
    """A subdivided capsule (~33k faces) and a noisy field with a sharp step along it."""
    mesh = trimesh.creation.capsule(height=4.0, radius=0.5, count=[64, 64])
    mesh = mesh.subdivide()
    rng = np.random.default_rng(3)
    centroids = mesh.triangles_center
    values = np.where(centroids[:, 2] > 0.3, 2.0, 1.0) + 0.3 * centroids[:, 0]
    return mesh, values + rng.normal(0.0, 0.15, len(values))


def test_patch_filter_follows_the_face_by_face_filter_on_wide_windows():
    mesh, values = capsule_field()
    graph = build_face_graph(mesh.vertices, mesh.faces)
    centroids = mesh.triangles_center
    exact = bilateral_smooth(values, graph, window_size=12)
    patches = patch_bilateral(values, graph, centroids, window_size=12)
    assert np.corrcoef(exact, patches)[0, 1] > 0.99
    assert np.abs(exact - patches).mean() < 0.03 * np.ptp(exact)
    assert np.abs(patches - values).mean() > 0.5 * np.abs(exact - values).mean()  # it smooths
    np.testing.assert_array_equal(
        patch_bilateral(values, graph, centroids, window_size=12, threads=1), patches
    )


def test_narrow_windows_stay_face_by_face_with_centroids():
    mesh, values = capsule_field()
    graph = build_face_graph(mesh.vertices, mesh.faces)
    plain = postprocess_shdf(values, graph, window_size=EXACT_WINDOW_MAX)
    with_centroids = postprocess_shdf(
        values, graph, window_size=EXACT_WINDOW_MAX, centroids=mesh.triangles_center
    )
    np.testing.assert_array_equal(plain, with_centroids)
    wide = postprocess_shdf(
        values, graph, window_size=EXACT_WINDOW_MAX + 4, centroids=mesh.triangles_center
    )
    np.testing.assert_array_equal(
        wide,
        linear_normalize(
            patch_bilateral(values, graph, mesh.triangles_center, window_size=EXACT_WINDOW_MAX + 4)
        ),
    )


def test_ring_length_measures_the_spacing_of_rings():
    mesh, _ = capsule_field()
    graph = build_face_graph(mesh.vertices, mesh.faces)
    centroids = mesh.triangles_center
    pairs = graph.pairs
    spacing = np.linalg.norm(centroids[pairs[:, 0]] - centroids[pairs[:, 1]], axis=1).mean()
    assert ring_length(graph, centroids) == pytest.approx(0.82 * spacing)


def test_post_processing_reports_progress_in_steps():
    """The bilateral filter is up to a third of an exact run: it reports as blocks finish."""
    sphere = trimesh.creation.icosphere(subdivisions=4)
    graph = TriangleMesh(sphere.vertices, sphere.faces).face_graph
    raw = np.random.default_rng(0).uniform(0.5, 1.5, len(sphere.faces))
    seen: list[float] = []
    values = postprocess_shdf(raw, graph, window_size=3, progress=seen.append)
    np.testing.assert_array_equal(values, postprocess_shdf(raw, graph, window_size=3))
    assert seen == sorted(seen) and seen[-1] == 1.0 and len(set(seen)) >= 10


def test_ring_length_from_the_mesh_reads_only_the_pairs_it_needs() -> None:
    mesh = trimesh.creation.icosphere(subdivisions=3)
    normals, _ = face_normals(mesh.vertices, mesh.faces)
    graph = build_face_graph(mesh.vertices, mesh.faces, normals)
    expected = ring_length(graph, face_centroids(mesh.vertices, mesh.faces))
    assert expected > 0
    assert mesh_ring_length(graph, mesh.vertices, mesh.faces) == expected


def test_sorted_adjacency_is_the_graphs_csr() -> None:
    mesh = trimesh.creation.icosphere(subdivisions=3)
    order = np.random.default_rng(2).permutation(len(mesh.faces))  # faces out of order
    normals, _ = face_normals(mesh.vertices, mesh.faces[order])
    graph = build_face_graph(mesh.vertices, mesh.faces[order], normals)
    indptr, indices = sorted_adjacency(graph)
    expected = graph.csr()
    np.testing.assert_array_equal(indptr, expected.indptr)
    np.testing.assert_array_equal(indices, expected.indices)


def test_normalisation_leaves_out_faces_near_open_rims() -> None:
    """The min and max come from faces farther than the window from a hole's rim: an odd
    value on a rim face no longer squeezes the others, and is clipped to [0, 1]."""
    ball = trimesh.creation.icosphere(subdivisions=3)
    centroids = np.asarray(ball.triangles_center)
    kept = np.flatnonzero(centroids[:, 2] < 0.9)  # a hole at the top
    mesh = TriangleMesh(np.asarray(ball.vertices), np.asarray(ball.faces)[kept])
    graph = mesh.face_graph
    rim = open_boundary_faces(mesh.welded_edges, mesh.face_count)
    assert 0 < rim.sum() < 0.2 * mesh.face_count
    raw = centroids[kept, 0] + 2.0  # 1..3 over the ball
    raw[np.flatnonzero(rim)[0]] = 30.0  # one rim face reads a far wall
    away = faces_away_from(rim, graph, 2)
    values = postprocess_shdf(raw, graph, window_size=2, smooth=False, rim=rim)
    expected = (raw - raw[away].min()) / (raw[away].max() - raw[away].min())
    np.testing.assert_allclose(values[away], expected[away])
    assert values.max() == 1.0 and values[np.flatnonzero(rim)[0]] == 1.0
    squeezed = postprocess_shdf(raw, graph, window_size=2, smooth=False)
    assert np.ptp(squeezed[away]) < 0.1  # without the rim: everything near 0
    # A closed mesh (no rim) is normalised over every face, as before.
    closed = TriangleMesh(np.asarray(ball.vertices), np.asarray(ball.faces))
    assert not open_boundary_faces(closed.welded_edges, closed.face_count).any()


def test_faces_away_from_counts_edge_rings() -> None:
    ball = trimesh.creation.icosphere(subdivisions=2)
    mesh = TriangleMesh(np.asarray(ball.vertices), np.asarray(ball.faces))
    graph = mesh.face_graph
    seed = np.zeros(mesh.face_count, dtype=bool)
    seed[0] = True
    assert faces_away_from(seed, graph, 0).sum() == mesh.face_count - 1
    assert faces_away_from(seed, graph, 1).sum() == mesh.face_count - 4
    assert faces_away_from(np.zeros_like(seed), graph, 3).all()


def test_faces_away_from_matches_ring_by_ring_definition() -> None:
    """The one-walk band equals growing the seed set one edge ring at a time, on an open
    multi-shell mesh with scattered seeds (a seed next to a seed, a ring past the shells)."""
    rng = np.random.default_rng(7)
    ball = trimesh.creation.icosphere(subdivisions=3)
    faces = np.asarray(ball.faces)
    faces = faces[rng.random(len(faces)) > 0.05]  # holes
    offset = len(ball.vertices)
    mesh = TriangleMesh(
        np.concatenate([ball.vertices, np.asarray(ball.vertices) + 3.0]),
        np.concatenate([faces, faces[:200] + offset]),
    )
    graph = mesh.face_graph
    neighbours: list[list[int]] = [[] for _ in range(mesh.face_count)]
    for a, b in graph.pairs:
        neighbours[a].append(int(b))
        neighbours[b].append(int(a))
    for rings in (0, 1, 3, 40):
        seeds = rng.random(mesh.face_count) < 0.01
        near = seeds.copy()
        for _ in range(rings):
            near[[n for face in np.flatnonzero(near) for n in neighbours[face]]] = True
        np.testing.assert_array_equal(faces_away_from(seeds, graph, rings), ~near)
