"""The documentation: the tutorials and the getting-started page run as written, the site builds
with every warning an error, and the README stays short and starts with the two commands.

Runnable blocks: every fenced block opened by exactly ```bash or ```python at the start of a line
in docs/tutorials/*.md (but the overview, index.md), docs/getting-started.md and README.md. They
run in page order, in one fresh working directory per page that holds a link `examples` to the
repository's examples/ (the pages are written for the repository root): a bash block with `bash -euo pipefail`, this interpreter's bin
folder first on PATH (so `tdcr-warp` is the installed command); the python blocks of a page in one
namespace, in this process, in that directory.

Marker: a block that must not run (the set-up itself, `mkdocs serve`) has the line
`<!-- no-test: why -->` right before its opening fence. The comment shows neither on the site
nor on GitHub. Blocks of other languages (toml, text) never run.
"""

import os
import re
import subprocess
import sys
import traceback
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
PAGES = ([p for p in sorted((DOCS / "tutorials").glob("*.md")) if p.name != "index.md"]
         + [DOCS / "getting-started.md", ROOT / "README.md"])
NO_TEST = "<!-- no-test"
README_MAX_LINES = 200
FIRST_COMMAND = ("python3 -m venv .venv && .venv/bin/pip install -e . && "
                 ".venv/bin/tdcr-warp warmup && .venv/bin/tdcr-warp static examples/seed_robot.toml --out out/seed_robot")
CI_LINE = re.compile(r"^python3 -m venv .* pytest")  # the line .ci/run greps and runs


@dataclass
class Block:
    """One fenced code block of a page: its language, text, first line (1-based) and whether it runs."""

    language: str
    code: str
    line: int
    runs: bool


def fenced_blocks(text: str) -> list[Block]:
    """The top-level fenced blocks of a Markdown text, in order."""
    lines = text.splitlines()
    blocks, i = [], 0
    while i < len(lines):
        opening = re.fullmatch(r"```(\S*)\s*", lines[i])
        if not opening:
            i += 1
            continue
        end = next((j for j in range(i + 1, len(lines)) if lines[j].rstrip() == "```"), None)
        assert end is not None, f"a block opened at line {i + 1} is never closed"
        before = lines[i - 1].strip() if i else ""
        blocks.append(Block(opening.group(1), "\n".join(lines[i + 1:end]) + "\n", i + 2,
                            not before.startswith(NO_TEST)))
        i = end + 1
    return blocks


def runnable(page: Path) -> list[Block]:
    return [b for b in fenced_blocks(page.read_text(encoding="utf-8")) if b.runs and b.language in ("bash", "python")]


def test_the_block_reader_honours_the_marker_and_the_languages():
    text = "x\n```bash\necho a\n```\n<!-- no-test: a server -->\n```bash\nmkdocs serve\n```\n```toml\na = 1\n```\n"
    blocks = fenced_blocks(text)
    assert [(b.language, b.code, b.line, b.runs) for b in blocks] == [
        ("bash", "echo a\n", 3, True), ("bash", "mkdocs serve\n", 7, False), ("toml", "a = 1\n", 10, True)]


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_code_block_of_the_page_runs(page, tmp_path, monkeypatch):
    blocks = runnable(page)
    assert blocks, f"{page.relative_to(ROOT)} has no runnable block"
    (tmp_path / "examples").symlink_to(ROOT / "examples", target_is_directory=True)
    env = dict(os.environ, PATH=f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}")
    monkeypatch.chdir(tmp_path)
    namespace = {"__name__": "__docs__"}
    for n, block in enumerate(blocks, 1):
        where = f"{page.relative_to(ROOT)}, block {n} (line {block.line}, {block.language})"
        if block.language == "bash":
            done = subprocess.run(["bash", "-euo", "pipefail", "-c", block.code], cwd=tmp_path, env=env,
                                  capture_output=True, text=True, timeout=600, check=False)
            if done.returncode:
                pytest.fail(f"{where} exited {done.returncode}:\n{block.code}\n--- stdout\n{done.stdout[-3000:]}"
                            f"\n--- stderr\n{done.stderr[-3000:]}", pytrace=False)
        else:
            try:
                exec(compile(block.code, where, "exec"), namespace)  # noqa: S102 (running the page is the test)
            except Exception:  # noqa: BLE001 (any error of a block fails it, named)
                pytest.fail(f"{where} raised:\n{block.code}\n{traceback.format_exc()}", pytrace=False)


def test_the_site_builds_with_warnings_as_errors(tmp_path):
    try:
        import mkdocs  # noqa: F401
    except ImportError:
        if os.environ.get("CI"):
            raise  # CI installs the docs extra (the README's test line): the build must run there
        pytest.skip("mkdocs is not installed: pip install -e '.[docs]'")
    done = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path / "site")],
                          cwd=ROOT, env=dict(os.environ, NO_MKDOCS_2_WARNING="1"), capture_output=True, text=True,
                          timeout=600, check=False)
    assert done.returncode == 0, f"mkdocs build --strict failed:\n{done.stdout[-5000:]}\n{done.stderr[-5000:]}"
    assert (tmp_path / "site" / "reference" / "api" / "physics" / "index.html").exists()


def test_the_readme_is_short_and_starts_with_the_two_commands():
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    lines = text.splitlines()
    assert len(lines) <= README_MAX_LINES, f"README.md has {len(lines)} lines, at most {README_MAX_LINES}"
    first = fenced_blocks(text)[0]
    before = lines[:first.line - 2]
    assert not any(line.startswith("## ") for line in before), "the two commands come before any section"
    assert first.language == "bash" and first.code.splitlines()[0] == FIRST_COMMAND
    test_line = first.code.splitlines()[1]
    assert CI_LINE.match(test_line) and '".[test,ray,docs]"' in test_line, test_line
    assert next(line for line in lines if CI_LINE.match(line)) == test_line, ".ci/run must find this line first"
    started = [b.code.strip() for b in fenced_blocks((DOCS / "getting-started.md").read_text(encoding="utf-8"))[:2]]
    assert started == first.code.strip().splitlines(), "docs/getting-started.md installs as the README does"


def test_the_readmes_links_point_into_the_repository():
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    targets = [t for t in re.findall(r"\]\(([^)#\s]+)", text) if not t.startswith(("http://", "https://"))]
    assert targets
    missing = [t for t in targets if not (ROOT / t).exists()]
    assert not missing, f"README.md links to {missing}"
