"""API keys: random tokens, stored as HMAC-SHA256 under a server secret, compared in constant time.

A key is 32 random bytes (``gsa_`` + 43 url-safe characters). Why HMAC and not a
slow salted hash: a slow hash (bcrypt, scrypt) protects low-entropy secrets such
as passwords against guessing; a 256-bit random key cannot be guessed either way,
and a slow hash would add tens of milliseconds to every request. The HMAC's secret
lives outside the database (``GSA_KEY_SECRET`` or ``DATA_DIR/key-secret``), so a
copied database alone cannot even confirm a key. Rows are found by the key's
non-secret 8-character prefix and the digest is compared with
``hmac.compare_digest``. Keys are never logged: the access log has no headers.
Rows from before migration 0003 hold plain SHA-256 digests (``sha256`` scheme) and
are rewritten as HMAC the first time their key is used.
"""

from __future__ import annotations

import hashlib
import hmac
import os
import secrets
from pathlib import Path

HMAC_SCHEME = "hmac-sha256"
LEGACY_SCHEME = "sha256"
PREFIX_CHARS = 8


def new_api_key() -> str:
    return "gsa_" + secrets.token_urlsafe(32)


def key_prefix(key: str) -> str:
    return key[:PREFIX_CHARS]


def key_digest(key: str, secret: bytes, scheme: str = HMAC_SCHEME) -> str:
    """Return the stored form of ``key`` under ``scheme``."""
    data = key.encode("utf-8", errors="surrogatepass")
    if scheme == LEGACY_SCHEME:
        return hashlib.sha256(data).hexdigest()
    return hmac.new(secret, data, hashlib.sha256).hexdigest()


def digests_equal(a: str, b: str) -> bool:
    return hmac.compare_digest(a.encode("ascii", errors="replace"), b.encode("ascii", errors="replace"))


def key_fingerprint(key: str) -> str:
    """A short non-secret name for a key from GSA_API_KEYS (its operator is ``env-<fingerprint>``)."""
    return key_digest(key, b"", LEGACY_SCHEME)[:12]


def private_dir(path: Path) -> Path:
    """Create ``path`` and any missing parents readable by this user only (0700); return it.

    (``Path.mkdir(parents=True)`` gives the parents the umask's mode, so each is made here.)
    """
    missing = [p for p in (path, *path.parents) if not p.exists()]
    for p in reversed(missing):
        p.mkdir(mode=0o700, exist_ok=True)
    return path


def write_private(path: Path, data: bytes) -> None:
    """Write ``data`` to a new file only this user can read (0600), whatever the umask."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "wb") as fh:
        fh.write(data)


def load_key_secret(configured: str, data_dir: Path) -> bytes:
    """Return the HMAC secret: ``GSA_KEY_SECRET`` if set, else ``data_dir/key-secret`` (made once, mode 600)."""
    if configured:
        return configured.encode("utf-8")
    path = Path(data_dir) / "key-secret"
    if not path.exists():
        private_dir(path.parent)
        tmp = path.with_name(f"key-secret.{os.getpid()}.tmp")
        write_private(tmp, secrets.token_hex(32).encode("ascii"))
        try:
            os.link(tmp, path)  # atomic and exclusive: two starting workers agree on one secret
        except FileExistsError:
            pass
        finally:
            tmp.unlink()
    secret = path.read_text().strip()
    if len(secret) < 32:
        raise ValueError(f"{path} holds a secret shorter than 32 characters; delete it or set GSA_KEY_SECRET")
    return secret.encode("utf-8")


class AuthThrottle:
    """Back-off for clients that send wrong API keys: after ``limit`` wrong keys from one address within
    ``window_s``, that address is answered 429 (any key, right or wrong, so the answers stop telling keys apart)
    until its oldest failure leaves the window. Per worker process; at most ``max_clients`` addresses are
    remembered (the quietest forgotten first)."""

    def __init__(self, limit: int, window_s: float = 60.0, max_clients: int = 10_000) -> None:
        import threading
        from collections import OrderedDict

        self.limit, self.window_s, self.max_clients = limit, window_s, max_clients
        self._fails: OrderedDict[str, list[float]] = OrderedDict()
        self._lock = threading.Lock()

    def _recent(self, client: str, now: float) -> list[float]:
        times = [t for t in self._fails.get(client, ()) if now - t < self.window_s]
        if times:
            self._fails[client] = times
        else:
            self._fails.pop(client, None)
        return times

    def wait_s(self, client: str, now: float | None = None) -> float:
        """Seconds ``client`` must wait before a key of its is looked at again (0: go ahead)."""
        import time

        now = time.monotonic() if now is None else now
        with self._lock:
            times = self._recent(client, now)
            return max(0.0, times[0] + self.window_s - now) if len(times) >= self.limit else 0.0

    def failed(self, client: str, now: float | None = None) -> None:
        """Count a wrong key from ``client``."""
        import time

        now = time.monotonic() if now is None else now
        with self._lock:
            times = self._recent(client, now)
            self._fails[client] = [*times, now][-self.limit :]
            self._fails.move_to_end(client)
            while len(self._fails) > self.max_clients:
                self._fails.popitem(last=False)
