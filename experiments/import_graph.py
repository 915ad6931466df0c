"""The package's import graph and the size of its pieces, read from the source with `ast`.

    python experiments/import_graph.py            # layers, floors, cycles, largest pieces
    python experiments/import_graph.py --check    # exit 1 on an upward import, a cycle, an oversized piece
                                                  # or a stale module table in docs/architecture.md
    python experiments/import_graph.py --table    # write that table from the code
    python experiments/import_graph.py --out results/import_graph.json   # the same as JSON, with run metadata
    python experiments/import_graph.py --figure docs/figures/layers.png  # the picture on docs/architecture.md

Every import counts, at module level or inside a function. ``kernels/`` is mapped to
``tdcr_warp.kernels`` as the package installs it. The rules (docs/architecture.md):

- a module imports only from its own layer or the layers below it (LAYERS, top first);
- the modules form no cycle (within a layer too);
- no function longer than MAX_FUNCTION lines and no class longer than MAX_CLASS lines.

The floor of a module is 0 when it imports no package module, else one more than the highest
floor among its imports.
"""

from __future__ import annotations

import argparse
import ast
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LAYERS = ("cli", "apps", "physics", "core", "io", "model", "kernels")  # top first
MAX_FUNCTION = 80
MAX_CLASS = 150


def modules(root: Path = ROOT) -> dict[str, Path]:
    """Dotted module name -> source file, for tdcr_warp/ and kernels/."""
    out = {}
    for folder, package in (("tdcr_warp", "tdcr_warp"), ("kernels", "tdcr_warp.kernels")):
        for path in sorted((root / folder).rglob("*.py")):
            parts = list(path.relative_to(root / folder).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join([package, *parts])] = path
    return out


def imports(name: str, path: Path, known: dict[str, Path]) -> set[str]:
    """The package modules that module `name` imports (each 'from X import y' counts X, and X.y
    when that is a module)."""
    is_package = path.name == "__init__.py"
    package = name if is_package else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            candidates = [target] + [f"{target}.{alias.name}" for alias in node.names]
        elif isinstance(node, ast.Import):
            candidates = [alias.name for alias in node.names]
        else:
            continue
        found.update(c for c in candidates if c in known)
    found.discard(name)
    return found


def layer_of(name: str) -> str | None:
    parts = name.split(".")
    return parts[1] if len(parts) > 1 and parts[1] in LAYERS else None


def graph(root: Path = ROOT) -> dict[str, set[str]]:
    known = modules(root)
    return {name: imports(name, path, known) for name, path in known.items()}


def upward_imports(g: dict[str, set[str]]) -> list[str]:
    """'a -> b' for each import of a higher layer (the package's own __init__ files are exempt:
    tdcr_warp/__init__.py re-exports the public API)."""
    bad = []
    for name, deps in g.items():
        here = layer_of(name)
        if here is None:
            continue
        for dep in deps:
            there = layer_of(dep)
            if there is not None and LAYERS.index(there) < LAYERS.index(here):
                bad.append(f"{name} -> {dep} ({here} imports {there}, a layer above it)")
    return sorted(bad)


def cycles(g: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan)."""
    index, low, stack, on_stack, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in g[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                out.append(sorted(component))

    sys.setrecursionlimit(10_000)
    for v in g:
        if v not in index:
            visit(v)
    return out


def floors(g: dict[str, set[str]]) -> dict[str, int]:
    """Each module's floor (needs an acyclic graph)."""
    memo: dict[str, int] = {}

    def floor(v):
        if v not in memo:
            memo[v] = 1 + max((floor(w) for w in g[v]), default=-1)
        return memo[v]

    return {v: floor(v) for v in g}


def pieces(root: Path = ROOT) -> list[tuple[int, str, str]]:
    """(lines, 'file:name', 'function' | 'class') of every function and class, longest first."""
    out = []
    for name, path in modules(root).items():
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                kind = "class" if isinstance(node, ast.ClassDef) else "function"
                out.append((node.end_lineno - node.lineno + 1, f"{path.relative_to(root)}:{node.name}", kind))
    return sorted(out, reverse=True)


def oversized(root: Path = ROOT) -> list[str]:
    limit = {"function": MAX_FUNCTION, "class": MAX_CLASS}
    return [f"{where}: {kind} of {n} lines (limit {limit[kind]})" for n, where, kind in pieces(root) if n > limit[kind]]


ARCHITECTURE = ROOT / "docs" / "architecture.md"
TABLE_BEGIN = "<!-- module table: written by `python experiments/import_graph.py --table`; tests/test_layers.py checks it -->"
TABLE_END = "<!-- end of the module table -->"


def summary(path: Path) -> str:
    """The first sentence of a module's docstring, on one line (| escaped for a Markdown table)."""
    doc = ast.get_docstring(ast.parse(path.read_text(), str(path))) or ""
    first = " ".join(doc.split("\n\n")[0].split())
    cut = first.find(". ")
    return (first if cut < 0 else first[: cut + 1]).replace("|", "\\|")


def module_table(root: Path = ROOT) -> str:
    """Every module of the package, layer by layer (top first) and by name: its file and the first
    sentence of its docstring; the table between TABLE_BEGIN and TABLE_END in docs/architecture.md."""
    known = modules(root)
    rows = [TABLE_BEGIN, "", "| layer | module | what it is |", "|---|---|---|"]
    for layer in (None, *LAYERS):  # None: the package's entry points, above the layers
        for name in sorted(n for n in known if layer_of(n) == layer):
            rows.append(f"| {layer or 'package'} | `{known[name].relative_to(root)}` | {summary(known[name]) or '-'} |")
    return "\n".join(rows + ["", TABLE_END])


def table_in(text: str) -> str | None:
    """The module table block of docs/architecture.md's text (None when its markers are missing)."""
    a, b = text.find(TABLE_BEGIN), text.find(TABLE_END)
    return text[a: b + len(TABLE_END)] if 0 <= a < b else None


def stale_table(root: Path = ROOT) -> list[str]:
    """A problem line when docs/architecture.md's module table is not the one the code gives."""
    found = table_in((root / "docs" / "architecture.md").read_text())
    return [] if found == module_table(root) else [
        "docs/architecture.md: the module table differs from the code (python experiments/import_graph.py --table)"]


def layer_imports(g: dict[str, set[str]]) -> dict[tuple[str, str], int]:
    """(importing layer, imported layer) -> number of module imports between two layers."""
    counts: dict[tuple[str, str], int] = {}
    for name, deps in g.items():
        for dep in deps:
            pair = (layer_of(name), layer_of(dep))
            if None not in pair and pair[0] != pair[1]:
                counts[pair] = counts.get(pair, 0) + 1
    return counts


def draw(g: dict[str, set[str]], path: str) -> None:
    """The layers top to bottom, each with its modules (left to right by floor), and an arrow per pair of
    layers with the number of imports from one to the other (all of them point down)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fl, counts = floors(g), layer_imports(g)
    fig, ax = plt.subplots(figsize=(11, 8.5))
    ax.set_axis_off()
    ax.set_xlim(-3.4, 10.2)
    ax.set_ylim(-0.6, len(LAYERS) - 0.4)
    for row, layer in enumerate(LAYERS):
        y = len(LAYERS) - 1 - row
        names = sorted((n for n in g if layer_of(n) == layer and n.count(".") == 2), key=lambda n: (fl[n], n))
        ax.add_patch(plt.Rectangle((0, y - 0.36), 10, 0.72, color=f"C{row}", alpha=0.15, lw=0))
        ax.text(-0.15, y, layer, ha="right", va="center", fontsize=13, weight="bold", color=f"C{row}")
        per_line = 7
        for i, name in enumerate(names):
            line, col = divmod(i, per_line)
            ax.text(0.25 + col * 1.4, y + 0.16 - 0.3 * line, name.rsplit(".", 1)[-1], fontsize=9, va="center",
                    family="monospace")
    for (upper, lower), n in counts.items():
        a, b = LAYERS.index(upper), LAYERS.index(lower)
        x = -3.2 + 0.42 * a + 0.06 * (b - a)
        y0, y1 = len(LAYERS) - 1 - a - 0.3, len(LAYERS) - 1 - b + 0.25
        ax.annotate("", (x, y1), (x, y0), arrowprops=dict(arrowstyle="->", color=f"C{a}", lw=0.5 + 0.2 * n ** 0.5))
        ax.text(x + 0.03, y1 + 0.02, str(n), fontsize=6.5, color=f"C{a}", ha="left", va="bottom")
    ax.set_title(f"tdcr_warp: {len(g)} modules in {len(LAYERS)} layers, each importing only from the layers below "
                 f"(arrows: the number of imports from one layer to another); no cycle", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--check", action="store_true",
                        help="exit 1 on an upward import, a cycle, an oversized piece or a stale module table")
    parser.add_argument("--out", help="also write the graph, floors, largest pieces and problems as JSON")
    parser.add_argument("--figure", help="draw the layers picture (PNG) into this file")
    parser.add_argument("--table", action="store_true", help="write the module table into docs/architecture.md")
    parser.add_argument("--smoke", action="store_true", help="accepted for the experiments' smoke test (always quick)")
    args = parser.parse_args(argv)
    if args.table:
        text = ARCHITECTURE.read_text()
        old = table_in(text)
        ARCHITECTURE.write_text(text.replace(old, module_table()) if old else text + "\n" + module_table() + "\n")
    g = graph()
    problems = upward_imports(g) + [" -> ".join(c) + " (cycle)" for c in cycles(g)] + oversized() + stale_table()
    fl = floors(g) if not cycles(g) else {}
    if fl:
        print(f"{len(g)} modules on {max(fl.values()) + 1} floors")
        for layer in LAYERS:
            names = sorted((n for n in g if layer_of(n) == layer), key=lambda n: (fl[n], n))
            print(f"  {layer:8s} " + ", ".join(f"{n.split('.', 2)[-1]}({fl[n]})" for n in names))
    largest = {kind: next(p for p in pieces() if p[2] == kind) for kind in ("function", "class")}
    print("; ".join(f"largest {kind}: {where} ({n} lines)" for kind, (n, where, _) in largest.items()))
    for line in problems:
        print("PROBLEM:", line)
    if args.figure:
        draw(g, args.figure)
    if args.out:
        sys.path.insert(0, str(ROOT / "experiments"))
        from _common import metadata, write_report

        write_report(args.out, {"meta": metadata("none"), "layers": LAYERS, "floors": fl,
                                "layer_imports": {f"{a} -> {b}": n for (a, b), n in sorted(layer_imports(g).items())},
                                "imports": {n: sorted(d) for n, d in g.items()},
                                "largest": {k: {"where": w, "lines": n} for k, (n, w, _) in largest.items()},
                                "problems": problems})
    return 1 if (args.check and problems) else 0


if __name__ == "__main__":
    sys.exit(main())
