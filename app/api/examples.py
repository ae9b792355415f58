"""The stored response examples the API docs show (``app/response_examples/``, written by ``app.openapi_examples``)."""

from __future__ import annotations

import json
from functools import cache
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parents[1] / "response_examples"


@cache
def load(name: str) -> dict[str, Any]:
    """A stored example (empty when it has not been generated)."""
    path = HERE / f"{name}.json"
    return json.loads(path.read_text()) if path.is_file() else {}
