"""Every repository path named in the code, the docs and the `--help` texts exists: `docs/X.md`,
`npga_view/....py`, `tests/....py`, `shaders/gl41_*` and the like. A renamed or moved file whose old name
lingers in a comment, a docstring or a help line fails here."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
TOP = ("docs", "npga_view", "npga_core", "tests", "benchmarks", "scripts", "shaders", "assets", ".ci")
#: a path that starts with one of our top-level folders; a trailing `*` or `<...>` makes it a prefix
PATH = re.compile(r"(?<![\w./-])((?:" + "|".join(re.escape(t) for t in TOP) + r")/[\w./-]*\w)([*<]?)")
#: named paths that are not files of this repository, each with what it is
NOT_OURS = {
    "scripts/evaluation/eval.py": "MonoNPHM's evaluation script (tests/files/test_tracker_pose.py cites its line)",
    "npga_core/assets": "where assets/ is installed (pyproject's package-dir)",
    "npga_core/assets/demo/LICENSE.ict-facekit": "the demo licence inside the wheel (tests/repo/test_package.py)",
}
#: (file, path) pairs where a path names something outside this repository (none)
ELSEWHERE: set[tuple[str, str]] = set()


def _tracked() -> list[str]:
    out = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True)
    if out.returncode != 0:
        pytest.skip("not a git checkout")
    return out.stdout.split()


def _exists(path: str, prefix: bool) -> bool:
    if prefix:
        return any(ROOT.glob(path + "*"))
    return (ROOT / path).exists()


def missing_paths(name: str, text: str) -> list[str]:
    """The repository paths `text` (of file `name`) names that do not exist."""
    bad = []
    for m in PATH.finditer(text):
        path, prefix = m.group(1).rstrip("."), bool(m.group(2))
        if path in NOT_OURS or (name, path) in ELSEWHERE or _exists(path, prefix):
            continue
        bad.append(f"{name}: {path}{'*' if prefix else ''}")
    return bad


def test_paths_named_in_code_and_docs_exist():
    bad = []
    for name in _tracked():
        if name == "tests/repo/test_repo_paths.py":  # (its own examples of missing paths)
            continue
        if name.endswith((".py", ".md", ".toml", ".sh", ".yml", ".txt")) or name in ("Makefile", ".ci/run"):
            bad += missing_paths(name, (ROOT / name).read_text(errors="replace"))
    assert bad == []


def test_paths_named_in_help_texts_exist():
    from npga_view.cli.main import SUBCOMMANDS, build_parser, command_parser

    texts = {"npga-view --help": build_parser().format_help()}
    texts.update({f"npga-view {n} --help": command_parser(n).format_help() for n in SUBCOMMANDS})
    assert len(texts) > 5
    bad = [b for name, text in texts.items() for b in missing_paths(name, text)]
    assert bad == []


def test_the_check_finds_a_missing_path():
    assert missing_paths("x.md", "see docs/NOPE.md and docs/ARCHITECTURE.md, shaders/gl41_*") == ["x.md: docs/NOPE.md"]
    assert missing_paths("x.py", "shaders/zz_*") == ["x.py: shaders/zz_*"]
