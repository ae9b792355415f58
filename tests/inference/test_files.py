"""inference/files.py: hashing, checked JSON and atomic writes."""

from __future__ import annotations

import hashlib

import pytest

from inference.errors import DatasetError
from inference.files import read_json, sha256_file, write_atomic, write_json


def test_sha256_file_is_the_digest_of_the_bytes_across_chunk_boundaries(tmp_path):
    data = bytes(range(256)) * 9000  # 2.2 MB: three 1 MiB chunks
    (tmp_path / "f").write_bytes(data)
    assert sha256_file(tmp_path / "f") == hashlib.sha256(data).hexdigest()


def test_a_failed_write_leaves_the_old_file_and_no_temporary(tmp_path):
    path = tmp_path / "card.json"
    write_json(path, {"a": 1})

    def half(tmp):
        tmp.write_text('{"a": ')
        raise OSError("disk full")

    with pytest.raises(OSError):
        write_atomic(path, half)
    assert read_json(path) == {"a": 1}
    assert [p.name for p in tmp_path.iterdir()] == ["card.json"]


def test_read_json_names_the_file_and_the_field(tmp_path):
    with pytest.raises(DatasetError, match="missing") as e:
        read_json(tmp_path / "manifest.json", DatasetError, "data")
    assert e.value.field == "data"
    (tmp_path / "bad.json").write_text("{not json")
    with pytest.raises(DatasetError, match=r"bad\.json is not readable JSON"):
        read_json(tmp_path / "bad.json", DatasetError, "data")
