"""Numba's on-disk cache of the package's jitted functions, and clearing it when stale.

Numba keys a cached function on its own source file only: its "Notes on Caching" list
"cache invalidation fails to recognize changes in symbols defined in a different file",
and with numba 0.68 a caller cached with ``cache=True`` keeps running the old code of an
edited callee in another module. The task kernel calls ``kernel.advance_chunk``, which
calls the sub-models, so an edit of a sub-model needs the cache cleared.

Nothing here runs on import. ``pneumatic-env clear-cache`` deletes the cache files of a
package folder (the library, ``agents``, ``studies``) whose sources, or the library's,
changed since it last ran (``--all``: every cache file); the test suite calls
:func:`clear_stale_numba_cache` before its first test. An installed (not editable)
package never changes, so only a source checkout needs this.
"""

from __future__ import annotations

import argparse
import hashlib
import importlib.util
from collections.abc import Sequence
from pathlib import Path

__all__ = ["LIBRARY_ROOT", "cached_roots", "clear_numba_cache", "clear_stale_numba_cache"]

LIBRARY_ROOT = Path(__file__).resolve().parent
_STAMP = Path("__pycache__") / "numba-source-digest"


def cached_roots() -> tuple[Path, ...]:
    """The folders whose jitted functions Numba caches: the library, then the installed
    ``pneumatic_env.agents`` and ``pneumatic_env.studies`` (found without importing them)."""
    roots = [LIBRARY_ROOT]
    for name in ("pneumatic_env.agents", "pneumatic_env.studies"):
        spec = importlib.util.find_spec(name)
        if spec is not None and spec.submodule_search_locations:
            roots.append(Path(next(iter(spec.submodule_search_locations))).resolve())
    return tuple(roots)


def _source_digest(roots: Sequence[Path]) -> str:
    """SHA-256 over the Python sources (paths and contents) below ``roots``."""
    h = hashlib.sha256()
    for root in roots:
        for path in sorted(root.rglob("*.py")):
            h.update(str(path.relative_to(root.parent)).encode())
            h.update(path.read_bytes())
    return h.hexdigest()


def _cache_files(root: Path) -> list[Path]:
    return [*root.rglob("*.nbi"), *root.rglob("*.nbc")]


def clear_numba_cache(roots: Sequence[Path] | None = None) -> int:
    """Delete every Numba cache file below ``roots`` (default :func:`cached_roots`);
    the number of files deleted."""
    deleted = 0
    for root in cached_roots() if roots is None else roots:
        for cache_file in _cache_files(Path(root)):
            cache_file.unlink(missing_ok=True)
            deleted += 1
    return deleted


def clear_stale_numba_cache(roots: Sequence[Path] | None = None) -> list[Path]:
    """Clear the cache of each root (default :func:`cached_roots`) whose sources or the
    library's changed since the last call; the roots cleared. A root that cannot be
    written (a read-only installation) is left alone."""
    cleared = []
    for root in cached_roots() if roots is None else roots:
        root = Path(root).resolve()
        stamp = root / _STAMP
        try:
            digest = _source_digest(dict.fromkeys((root, LIBRARY_ROOT)))
            if stamp.is_file() and stamp.read_text() == digest:
                continue
            clear_numba_cache((root,))
            stamp.parent.mkdir(parents=True, exist_ok=True)
            stamp.write_text(digest)
            cleared.append(root)
        except OSError:
            continue
    return cleared


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--all",
        action="store_true",
        help="delete every cache file, not only those of folders whose sources changed",
    )


def run(args: argparse.Namespace) -> int:
    if args.all:
        print(f"deleted {clear_numba_cache()} Numba cache files")
        return 0
    cleared = clear_stale_numba_cache()
    for root in cleared:
        print(f"cleared the Numba cache of {root}")
    if not cleared:
        print("the Numba cache matches the sources")
    return 0
