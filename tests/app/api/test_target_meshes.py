"""An operator's own target mesh (GSA_TARGET_MODEL): offered beside the built-in targets, a bad one refused at
start naming the file. Start-up is the subject, not the database: SQLite alone."""

import pytest
from fastapi.testclient import TestClient

from app.main import create_app
from inference.errors import ModelFileError


@pytest.fixture(scope="module")
def backend():
    return "sqlite"


def test_an_operators_mesh_is_offered_and_a_bad_one_refused(settings, tmp_path):
    mesh = tmp_path / "cube-sat.obj"
    verts = [(x, y, z) for x in (-1.5, 1.5) for y in (-1, 1) for z in (-1, 1)]
    faces = [(1, 2, 4, 3), (5, 7, 8, 6), (1, 5, 6, 2), (3, 4, 8, 7), (1, 3, 7, 5), (2, 6, 8, 4)]
    mesh.write_text(
        "".join(f"v {x} {y} {z}\n" for x, y, z in verts) + "".join(f"f {a} {b} {c} {d}\n" for a, b, c, d in faces)
    )
    with TestClient(create_app(settings.model_copy(update={"target_model": mesh}))) as c:
        assert "cube-sat" in c.get("/readyz").json()["targets"]
    broken = tmp_path / "broken.obj"
    broken.write_text("v 1 2\nf 1 2 3\n")
    with pytest.raises(ModelFileError, match="broken.obj"):
        create_app(settings.model_copy(update={"target_model": broken}))
    huge = tmp_path / "huge.obj"
    huge.write_text(mesh.read_text())
    with pytest.raises(ModelFileError, match="frame is only"):
        create_app(settings.model_copy(update={"target_model": huge, "target_scale": 50.0}))
