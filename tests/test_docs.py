"""The documentation holds to what the code accepts and to the files it points at."""

from __future__ import annotations

import inspect
import re
from pathlib import Path

import pytest

from pneumatic_env.envs import env as env_module
from pneumatic_env.envs.features import FEATURE_OPTIONS
from pneumatic_env.envs.tasks import EnvOptions

ROOT = Path(__file__).resolve().parents[1]
README_MAX_WORDS = 1500
MARKDOWN_FILES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
_LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")
_FENCE = re.compile(r"^(```|~~~)")


def _init_parameters(cls) -> set[str]:
    """The named keyword arguments of ``cls.__init__`` (not ``self``, not ``**kwargs``)."""
    return {
        name
        for name, p in inspect.signature(cls.__init__).parameters.items()
        if name != "self" and p.kind is not inspect.Parameter.VAR_KEYWORD
    }


def _unnamed(docstring: str | None, options) -> list[str]:
    """The options the docstring names in no code span (````option````,
    ````options={"option": v}````)."""
    spans = " ".join(re.findall(r"``(.+?)``", docstring or "", flags=re.DOTALL))
    return sorted(name for name in set(options) if not re.search(rf"\b{name}\b", spans))


def test_single_env_docstring_names_every_option():
    """Every make keyword and reset option the single env accepts, from the code."""
    single = env_module.PneumaticTrackingEnv
    vector = env_module.PneumaticTrackingVectorEnv
    accepted = (
        set(EnvOptions.__dataclass_fields__)
        | set(FEATURE_OPTIONS)
        | _init_parameters(single)
        | (_init_parameters(vector) - {"num_envs"})  # gym.make's max_episode_steps
        | set(env_module.RESET_OPTIONS)
    )
    assert "plant" in accepted and "relative_preview" in accepted
    assert _unnamed(single.__doc__, accepted) == []


def test_vector_env_docstring_names_its_own_options():
    """Its own keywords and reset options; it refers to the single env for the rest."""
    vector = env_module.PneumaticTrackingVectorEnv
    accepted = (_init_parameters(vector) - _init_parameters(env_module.PneumaticTrackingEnv)) | set(
        env_module.VECTOR_RESET_OPTIONS
    )
    assert {"num_envs", "start_step"} <= accepted
    assert _unnamed(vector.__doc__, accepted) == []


def test_unnamed_finds_a_missing_option():
    docstring = 'Takes ``a`` and ``options={"b": 1}``; c and ``cd`` are not code.'
    assert _unnamed(docstring, ["a", "b", "c"]) == ["c"]


def test_readme_is_short():
    words = len((ROOT / "README.md").read_text(encoding="utf-8").split())
    assert words <= README_MAX_WORDS, f"README.md has {words} words, at most {README_MAX_WORDS}"


def _slug(heading: str) -> str:
    """GitHub's anchor of a Markdown heading."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def _prose_lines(path: Path) -> list[str]:
    """The file's lines outside fenced code blocks."""
    lines, fenced = [], False
    for line in path.read_text(encoding="utf-8").splitlines():
        if _FENCE.match(line.strip()):
            fenced = not fenced
        elif not fenced:
            lines.append(line)
    return lines


def _anchors(path: Path) -> set[str]:
    """The anchors of the file's headings; a repeated heading gets -1, -2, ... as on GitHub."""
    anchors: set[str] = set()
    seen: dict[str, int] = {}
    for line in _prose_lines(path):
        if line.startswith("#"):
            slug = _slug(line.lstrip("#"))
            anchors.add(f"{slug}-{seen[slug]}" if slug in seen else slug)
            seen[slug] = seen.get(slug, 0) + 1
    return anchors


def _relative_links(path: Path) -> list[str]:
    targets = []
    for line in _prose_lines(path):
        targets += [t for t in _LINK.findall(line) if not re.match(r"[a-z]+:", t)]
    return targets


@pytest.mark.parametrize("path", MARKDOWN_FILES, ids=lambda p: p.name)
def test_relative_links_point_at_existing_files(path):
    broken = []
    for target in _relative_links(path):
        file_part, _, anchor = target.partition("#")
        file = (path.parent / file_part).resolve() if file_part else path
        if not file.exists():
            broken.append(target)
        elif anchor and file.suffix == ".md" and anchor not in _anchors(file):
            broken.append(target)
    assert broken == [], f"{path.name}: links to missing files or headings: {broken}"


def test_link_check_sees_a_broken_link(tmp_path):
    page = tmp_path / "page.md"
    page.write_text("# Title\n## Title\n\n[ok](#title), [gone](missing.md), [bad](#nowhere)\n")
    assert _relative_links(page) == ["#title", "missing.md", "#nowhere"]
    assert _anchors(page) == {"title", "title-1"}
