"""API keys: random tokens, stored as SHA-256 digests.

A key is 32 random bytes (``gsa_`` + 43 url-safe characters), so a fast digest is
enough: nothing can be guessed by brute force, and a lookup by digest never
compares secrets byte by byte.
"""

from __future__ import annotations

import hashlib
import secrets


def new_api_key() -> str:
    return "gsa_" + secrets.token_urlsafe(32)


def hash_api_key(key: str) -> str:
    return hashlib.sha256(key.encode("utf-8")).hexdigest()
