"""JSON request bodies for tests: a copy with one nested field set."""

import copy
from collections.abc import Sequence
from typing import Any


def with_value(body: dict[str, Any], path: Sequence[str], value: Any) -> dict[str, Any]:
    """A deep copy of ``body`` with the field at ``path`` (keys, outermost first) set to ``value``."""
    out = copy.deepcopy(body)
    node = out
    for key in path[:-1]:
        node = node.setdefault(key, {})
    node[path[-1]] = value
    return out
