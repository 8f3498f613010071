"""Keep Numba's on-disk cache consistent with the package source.

Numba keys a cached function on its own source file only. A jitted function that inlines
functions from another module (the task kernel calls ``kernel.advance_chunk``, which calls the
sub-models) keeps running the old code after that other module changes. On import,
the package hashes all of its Python sources. When the digest differs from the one stored
with the cache, the package's cache files are deleted and the functions compile afresh.
"""
from __future__ import annotations

import hashlib
from pathlib import Path

_ROOTS = (Path(__file__).resolve().parent, Path(__file__).resolve().parent.parent / "agents")
_STAMP = Path(__file__).resolve().parent / "__pycache__" / "numba-source-digest"


def _sources() -> list[Path]:
    return sorted(p for root in _ROOTS if root.is_dir() for p in root.rglob("*.py"))


def source_digest() -> str:
    """SHA-256 over the package's Python sources (paths and contents)."""
    h = hashlib.sha256()
    for path in _sources():
        h.update(str(path.relative_to(path.parents[1])).encode())
        h.update(path.read_bytes())
    return h.hexdigest()


def invalidate_stale_numba_cache() -> bool:
    """Delete the package's Numba cache files if any source changed; True if it did."""
    try:
        digest = source_digest()
        if _STAMP.is_file() and _STAMP.read_text() == digest:
            return False
        for root in _ROOTS:
            for cache_file in [*root.rglob("*.nbi"), *root.rglob("*.nbc")]:
                cache_file.unlink(missing_ok=True)
        _STAMP.parent.mkdir(parents=True, exist_ok=True)
        _STAMP.write_text(digest)
        return True
    except OSError:  # a read-only installation: leave its cache alone
        return False
