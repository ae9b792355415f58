"""An operator's mesh files: read, scaled and centred; every unusable file named."""

import numpy as np
import pytest

from inference.errors import ModelFileError
from inference.simulation.meshes import load_model
from inference.simulation.radar import Radar
from inference.simulation.scene import check_fits

RADAR = Radar()


def test_model_files(tmp_path):
    obj = tmp_path / "box.obj"
    obj.write_text(
        "v -1 -1 -1\nv 1 -1 -1\nv 1 1 -1\nv -1 1 -1\nv -1 -1 1\nv 1 -1 1\nv 1 1 1\nv -1 1 1\n"
        "f 1 2 3 4\nf 5 6 7 8\nf 1 2 6 5\nf 2 3 7 6\nf 3 4 8 7\nf 4 1 5 8\n"
    )
    box = load_model(obj)
    assert len(box.scatterers) > 50 and np.abs(box.surface).max() <= 1.05
    ply = tmp_path / "pts.ply"
    ply.write_text(
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nend_header\n0 0 0\n1 0 0\n0 1 0\n"
    )
    assert len(load_model(ply).surface) == 3
    with pytest.raises(ModelFileError, match="does not exist"):
        load_model(tmp_path / "missing.obj")
    empty = tmp_path / "empty.obj"
    empty.write_text("")
    with pytest.raises(ModelFileError, match="no usable vertices"):
        load_model(empty)
    junk = tmp_path / "junk.ply"
    junk.write_bytes(b"\x00\x01garbage")
    with pytest.raises(ModelFileError, match="not a PLY"):
        load_model(junk)
    with pytest.raises(ModelFileError, match="frame is only"):
        check_fits(load_model(obj, scale=20.0), RADAR)
