"""The Numba cache is cleared where sources changed, on request and never on import."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from pneumatic_env.numba_cache import cached_roots, clear_stale_numba_cache


def _package(tmp_path: Path) -> tuple[Path, Path, Path]:
    root = tmp_path / "pkg"
    (root / "__pycache__").mkdir(parents=True)
    source = root / "callee.py"
    source.write_text("X = 1\n")
    cache_file = root / "__pycache__" / "caller.g-3.py311.nbi"
    cache_file.write_bytes(b"index")
    return root, source, cache_file


def test_a_changed_source_clears_its_folders_cache_once(tmp_path):
    root, source, cache_file = _package(tmp_path)
    assert clear_stale_numba_cache([root]) == [root.resolve()]
    assert not cache_file.exists()
    cache_file.write_bytes(b"index")
    assert clear_stale_numba_cache([root]) == []  # unchanged sources: the cache stays
    assert cache_file.exists()
    source.write_text("X = 2\n")  # an edited callee
    assert clear_stale_numba_cache([root]) == [root.resolve()]
    assert not cache_file.exists()


def test_the_cached_folders_are_the_library_agents_and_studies():
    assert [p.name for p in cached_roots()] == ["pneumatic_env", "agents", "studies"]


def test_importing_the_packages_deletes_no_cache_file():
    roots = cached_roots()
    sentinels = [root / "__pycache__" / "zz_import_sentinel.nbi" for root in roots]
    stamps = [root / "__pycache__" / "numba-source-digest" for root in roots]
    saved = [s.read_text() if s.is_file() else None for s in stamps]
    try:
        for sentinel, stamp in zip(sentinels, stamps, strict=True):
            sentinel.parent.mkdir(exist_ok=True)
            sentinel.write_bytes(b"")
            stamp.write_text("a digest of other sources")
        code = "import pneumatic_env, pneumatic_env.agents, pneumatic_env.studies"
        subprocess.run([sys.executable, "-c", code], check=True)
        assert all(s.exists() for s in sentinels)
    finally:
        for sentinel, stamp, text in zip(sentinels, stamps, saved, strict=True):
            sentinel.unlink(missing_ok=True)
            if text is None:
                stamp.unlink(missing_ok=True)
            else:
                stamp.write_text(text)
