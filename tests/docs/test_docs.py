"""The documentation: the site builds with ``mkdocs build --strict`` and the docs' runnable blocks run.

A fenced code block is runnable when the line before its fence is the HTML comment ``<!-- runs -->``
(it must exit 0) or ``<!-- runs: exit N -->`` (it must exit with code N); mkdocs renders neither
comment.  Each block runs in a scratch folder of its own that links the repository's ``scenarios/``,
``tests/``, ``benchmarks/``, ``tools/`` and ``.venv`` (so ``source .venv/bin/activate`` and ``scenarios/merging.yaml`` work as in
a clone): ``bash`` blocks with ``set -e``, ``python`` blocks with this interpreter.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

from tests.conftest import REPO

DOCS = REPO / "docs"
MARKER = re.compile(r"^<!--\s*runs(?::\s*exit\s+(\d+))?\s*-->\s*$")
FENCE = re.compile(r"^(`{3,})\s*([\w+-]*)")
BLOCK_TIMEOUT_S = 120  # a block is meant to take under ~20 s on an idle core; this only stops a hang


@dataclass(frozen=True)
class Block:
    """One runnable code block: where it is, its language, its text and the exit code it must give."""

    path: Path
    line: int  # 1-based line of the opening fence
    lang: str
    code: str
    exit_code: int

    @property
    def id(self) -> str:
        return f"{self.path.relative_to(DOCS)}:{self.line}"


def runnable_blocks(path: Path) -> list[Block]:
    """The blocks of one Markdown file whose fence follows a ``runs`` marker (unterminated: an error)."""
    lines = path.read_text(encoding="utf-8").splitlines()
    blocks: list[Block] = []
    i = 0
    while i < len(lines):
        marker = MARKER.match(lines[i].strip())
        fence = FENCE.match(lines[i + 1]) if marker and i + 1 < len(lines) else None
        if marker and not fence:
            raise ValueError(f"{path}:{i + 1}: a runs marker must be followed by a code fence")
        if not fence:
            i += 1
            continue
        ticks, lang = fence.group(1), fence.group(2)
        end = next((j for j in range(i + 2, len(lines)) if lines[j].strip() == ticks), None)
        if end is None:
            raise ValueError(f"{path}:{i + 2}: unterminated code block")
        blocks.append(Block(path, i + 2, lang, "\n".join(lines[i + 2:end]) + "\n", int(marker.group(1) or 0)))
        i = end + 1
    return blocks


def all_blocks() -> list[Block]:
    return [b for p in sorted(DOCS.rglob("*.md")) for b in runnable_blocks(p)]


def scratch_folder(tmp: Path) -> Path:
    """A folder that looks like a clone to the docs' commands (links, nothing copied)."""
    for name in ("scenarios", "tests", "benchmarks", "tools"):
        (tmp / name).symlink_to(REPO / name)
    (tmp / ".venv").symlink_to(Path(sys.prefix))
    return tmp


def run_block(block: Block, cwd: Path) -> subprocess.CompletedProcess[str]:
    """Run a block in ``cwd`` with the project's interpreter and scripts first on PATH."""
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}"}
    if block.lang in ("bash", "sh", "shell", "console"):
        cmd = ["bash", "-e", "-c", block.code]
    elif block.lang in ("python", "py"):
        cmd = [sys.executable, "-c", block.code]
    else:
        raise ValueError(f"{block.id}: a runnable block must be bash or python, not {block.lang!r}")
    return subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=BLOCK_TIMEOUT_S)


BLOCKS = all_blocks()


def test_the_docs_mark_runnable_blocks() -> None:
    assert len(BLOCKS) >= 5, [b.id for b in BLOCKS]


@pytest.mark.parametrize("block", BLOCKS, ids=[b.id for b in BLOCKS])
def test_runnable_block_runs(block: Block, tmp_path: Path) -> None:
    res = run_block(block, scratch_folder(tmp_path))
    assert res.returncode == block.exit_code, (
        f"{block.id}: exit {res.returncode}, expected {block.exit_code}\n"
        f"--- stdout\n{res.stdout[-3000:]}\n--- stderr\n{res.stderr[-3000:]}")


def test_a_failing_block_fails(tmp_path: Path) -> None:
    """The runner is not a rubber stamp: a block that fails, or exits with another code, is caught."""
    page = tmp_path / "page.md"
    page.write_text("<!-- runs -->\n```bash\ntrue\nfalse\necho unreachable\n```\n\n"
                    "<!-- runs: exit 2 -->\n```python\nraise SystemExit(3)\n```\n\n"
                    "```bash\nnot marked, not run\n```\n")
    blocks = runnable_blocks(page)
    assert [(b.lang, b.exit_code) for b in blocks] == [("bash", 0), ("python", 2)]
    (tmp_path / "cwd").mkdir()
    outcomes = [run_block(b, scratch_folder(tmp_path / "cwd")) for b in blocks[:1]]
    outcomes += [run_block(blocks[1], tmp_path / "cwd")]
    assert outcomes[0].returncode != 0 and "unreachable" not in outcomes[0].stdout
    assert outcomes[1].returncode == 3 != blocks[1].exit_code


def test_a_marker_without_a_block_is_an_error(tmp_path: Path) -> None:
    page = tmp_path / "page.md"
    page.write_text("<!-- runs -->\n\ntext\n")
    with pytest.raises(ValueError, match="must be followed by a code fence"):
        runnable_blocks(page)


def test_site_builds_strictly(tmp_path: Path) -> None:
    res = subprocess.run([str(Path(sys.executable).parent / "mkdocs"), "build", "--strict", "--site-dir",
                          str(tmp_path / "site")], cwd=REPO, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr[-4000:]
    assert (tmp_path / "site" / "index.html").exists()
    assert (tmp_path / "site" / "reference" / "engine" / "index.html").exists()
