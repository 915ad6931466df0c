"""A newcomer's path, timed: a fresh clone, the README's first command with empty caches, then
the Monte-Carlo tutorial (a sweep opened in pandas) and the real-robot tutorial (a fitted robot),
their blocks run as written, in page order, from the clone's root.

    python experiments/newcomer_path.py [--smoke] [--out newcomer.json]

The clone, its virtual environment and its caches (pip's, Warp's kernel cache: XDG_CACHE_HOME)
live in a temporary folder, so nothing is reused from this machine's earlier runs; pip still
downloads from the package index, so the set-up time includes the network. The runnable blocks
are read with the test suite's reader (tests/test_docs.py), the same blocks CI runs. --smoke
builds the plan (the README's command, the pages' programs, compiled) without running it.
"""

import argparse
import os
import shlex
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "experiments"), str(ROOT / "tests")]
from _common import metadata, write_report
from test_docs import runnable  # the test suite's reader of the pages' blocks

PAGES = ["docs/tutorials/montecarlo.md", "docs/tutorials/real-robot.md"]


def page_program(page: Path) -> str:
    """One Python program that runs a page's blocks in order: bash blocks in a shell, the python
    blocks in one namespace (as a reader pasting them into one session)."""
    lines = ["import subprocess", "ns = {'__name__': '__page__'}"]
    for block in runnable(page):
        if block.language == "bash":
            lines.append(f"subprocess.run(['bash', '-euo', 'pipefail', '-c', {block.code!r}], check=True)")
        else:
            lines.append(f"exec(compile({block.code!r}, 'line {block.line}', 'exec'), ns)")
    return "\n".join(lines) + "\n"


def timed(step: str, command: str, cwd: Path, env: dict) -> dict:
    print(f"+ {step}: {command}", flush=True)
    start = time.perf_counter()
    done = subprocess.run(["bash", "-c", command], cwd=cwd, env=env, capture_output=True, text=True, check=False)
    seconds = time.perf_counter() - start
    if done.returncode:
        sys.exit(f"{step} failed ({done.returncode}):\n{done.stdout[-3000:]}\n{done.stderr[-3000:]}")
    print(f"  {seconds:.1f} s", flush=True)
    return {"step": step, "command": command, "seconds": round(seconds, 1)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--smoke", action="store_true", help="build the plan, run nothing")
    parser.add_argument("--out", type=Path, default=Path("newcomer.json"), help="the timings (JSON)")
    args = parser.parse_args(argv)
    readme = (ROOT / "README.md").read_text(encoding="utf-8").splitlines()
    first = next(line for line in readme if line.startswith("python3 -m venv") and "warmup" in line)
    if args.smoke:
        for page in PAGES:
            compile(page_program(ROOT / page), page, "exec")
        write_report(args.out, {"meta": metadata("cpu", smoke=True), "readme_command": first, "pages": PAGES})
        return 0
    with tempfile.TemporaryDirectory(prefix="newcomer_") as tmp:
        home = Path(tmp)
        clone = home / "tdcr-warp"
        subprocess.run(["git", "clone", "-q", str(ROOT), str(clone)], check=True)
        env = dict(os.environ, XDG_CACHE_HOME=str(home / "cache"), PIP_CACHE_DIR=str(home / "cache" / "pip"))
        env.pop("VIRTUAL_ENV", None)
        steps = [timed("README line 1 (install, warmup, the default scene)", first, clone, env)]
        env["PATH"] = f"{clone / '.venv' / 'bin'}{os.pathsep}{env['PATH']}"
        steps.append(timed("pandas, which the tutorials open tables with", ".venv/bin/pip install -q pandas", clone, env))
        for page in PAGES:
            program = home / (Path(page).stem + ".py")
            program.write_text(page_program(clone / page), encoding="utf-8")
            steps.append(timed(page, f".venv/bin/python {shlex.quote(str(program))}", clone, env))
    total = sum(s["seconds"] for s in steps)
    write_report(args.out, {"meta": metadata("cpu", load_average=os.getloadavg()), "steps": steps,
                            "total_seconds": round(total, 1)})
    print(f"newcomer path: {total:.0f} s in all")
    return 0


if __name__ == "__main__":
    sys.exit(main())
