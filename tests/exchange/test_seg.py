"""Per-face text files: .seg labels and one-value-per-line files."""

import numpy as np
import pytest

from neural_shdf.errors import ParameterError
from neural_shdf.exchange.seg import read_labels, read_values, write_labels, write_values


def test_label_file_round_trip(tmp_path):
    labels = np.array([0, 3, 3, -1, 12])
    path = tmp_path / "mesh.seg"
    write_labels(path, labels)
    assert path.read_text() == "0\n3\n3\n-1\n12\n"
    np.testing.assert_array_equal(read_labels(path), labels)


@pytest.mark.parametrize(
    "labels",
    [
        np.array([True, False, True]),
        np.array([], dtype=np.int32),
        np.array([2**63 + 5, 3, 2**63 + 5], dtype=np.uint64),
        np.array([-3, 7, -3, 0], dtype=np.int8),
        np.random.default_rng(1).integers(-5, 40, 5000),
    ],
)
def test_label_file_text_is_each_integer_per_line(tmp_path, labels):
    path = tmp_path / "mesh.seg"
    write_labels(path, labels)
    assert path.read_text() == "".join(f"{int(label)}\n" for label in labels)


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
