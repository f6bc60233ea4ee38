"""FBX is refused by extension, by file_type and by content, with what to do instead."""

from pathlib import Path

import pytest

from neural_shdf.cli import EXIT_BAD_INPUT, main
from neural_shdf.errors import UnsupportedFormatError
from neural_shdf.mesh_io import SUPPORTED_FORMATS, load_mesh, sniff_format

BINARY_FBX = b"Kaydara FBX Binary  \x00\x1a\x00" + (7400).to_bytes(4, "little") + bytes(64)
ASCII_FBX = b"; FBX 7.4.0 project file\n; ----\nFBXHeaderExtension:  {\n}\n"
ADVICE = r"USD \(\.usdc/\.usdz\) or glTF \(\.glb\).*Blender with the Neural ShDF add-on"


@pytest.mark.parametrize("data", [BINARY_FBX, ASCII_FBX], ids=["binary", "ascii"])
def test_fbx_is_refused_with_what_to_do_instead(tmp_path: Path, data: bytes):
    assert "fbx" not in SUPPORTED_FORMATS
    assert sniff_format(data) == "fbx"
    path = tmp_path / "Model.FBX"
    path.write_bytes(data)
    for source, file_type in ((path, None), (data, None), (data, "fbx"), (b"x", ".FBX")):
        with pytest.raises(UnsupportedFormatError, match=ADVICE):
            load_mesh(source, file_type)


def test_the_cli_refuses_fbx_with_the_advice(tmp_path: Path, capsys):
    path = tmp_path / "model.fbx"
    path.write_bytes(BINARY_FBX)
    assert main(["segment", str(path), "-o", str(tmp_path / "out.seg"), "-q"]) == EXIT_BAD_INPUT
    assert "Neural ShDF add-on" in capsys.readouterr().err
