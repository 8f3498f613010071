"""Keep Numba's on-disk cache consistent with the package source.

Numba keys a cached function on its own source file only. A jitted function that inlines
functions from another module (the task kernel calls ``kernel.advance_chunk``, which calls the
sub-models) keeps running the old code after that other module changes. On import, a
package hashes its own Python sources and those of the packages its jitted code inlines;
when the digest differs from the one stored with its cache, its cache files are deleted and
its functions compile afresh. The library calls this for itself; ``pneumatic_env.agents``
and ``pneumatic_env.studies`` call it for their folders (the library's sources included).
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from pathlib import Path

LIBRARY_ROOT = Path(__file__).resolve().parent


def _sources(roots: Sequence[Path]) -> list[Path]:
    return sorted(p for root in roots if root.is_dir() for p in root.rglob("*.py"))


def source_digest(roots: Sequence[Path] = (LIBRARY_ROOT,)) -> str:
    """SHA-256 over the Python sources (paths and contents) below ``roots``."""
    h = hashlib.sha256()
    for path in _sources(roots):
        h.update(str(path.relative_to(path.parents[1])).encode())
        h.update(path.read_bytes())
    return h.hexdigest()


def invalidate_stale_numba_cache(
    root: Path = LIBRARY_ROOT, depends_on: Sequence[Path] = ()
) -> bool:
    """Delete the Numba cache files below ``root`` if a source below ``root`` or
    ``depends_on`` changed since the last call; True if it did."""
    root = Path(root).resolve()
    stamp = root / "__pycache__" / "numba-source-digest"
    try:
        digest = source_digest((root, *depends_on))
        if stamp.is_file() and stamp.read_text() == digest:
            return False
        for cache_file in [*root.rglob("*.nbi"), *root.rglob("*.nbc")]:
            cache_file.unlink(missing_ok=True)
        stamp.parent.mkdir(parents=True, exist_ok=True)
        stamp.write_text(digest)
        return True
    except OSError:  # a read-only installation: leave its cache alone
        return False
