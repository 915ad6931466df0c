"""The package's layers: every import points down (cli > apps > physics > core > io > model >
kernels), no module imports itself through others, and no piece outgrows the size limits.
The graph is read from the source by experiments/import_graph.py (docs/architecture.md)."""

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "experiments"))
import import_graph  # noqa: E402


@pytest.fixture(scope="module")
def graph():
    return import_graph.graph()


def test_every_module_is_in_a_layer(graph):
    loose = [n for n in graph if import_graph.layer_of(n) is None and n not in ("tdcr_warp", "tdcr_warp.__main__")]
    assert not loose, f"modules outside the layers {import_graph.LAYERS}: {loose}"


def test_imports_point_down(graph):
    assert not import_graph.upward_imports(graph)


def test_no_import_cycle(graph):
    assert not import_graph.cycles(graph)


def test_pieces_within_size_limits():
    assert not import_graph.oversized(), "\n".join(import_graph.oversized())


def _tree(tmp_path, files: dict[str, str]) -> Path:
    for rel, text in files.items():
        path = tmp_path / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return tmp_path


def test_checker_finds_an_upward_import_and_a_cycle(tmp_path):
    """The checks above could fail: a planted upward import and a planted cycle are found."""
    root = _tree(tmp_path, {
        "tdcr_warp/__init__.py": "",
        "tdcr_warp/model/__init__.py": "",
        "tdcr_warp/model/robot.py": "from tdcr_warp.physics.statics import solve\n",
        "tdcr_warp/physics/__init__.py": "",
        "tdcr_warp/physics/statics.py": "def solve():\n    from . import stability\n",
        "tdcr_warp/physics/stability.py": "from tdcr_warp.physics.statics import solve\n",
        "kernels/__init__.py": "",
        "kernels/rod.py": "from .layout import X\n",
        "kernels/layout.py": "X = 1\n",
    })
    g = import_graph.graph(root)
    assert g["tdcr_warp.kernels.rod"] == {"tdcr_warp.kernels.layout"}
    assert import_graph.upward_imports(g) == [
        "tdcr_warp.model.robot -> tdcr_warp.physics.statics (model imports physics, a layer above it)"]
    assert import_graph.cycles(g) == [["tdcr_warp.physics.stability", "tdcr_warp.physics.statics"]]


def test_checker_measures_pieces(tmp_path):
    body = "\n".join(f"    x{i} = {i}" for i in range(import_graph.MAX_FUNCTION))
    root = _tree(tmp_path, {"tdcr_warp/__init__.py": f"def long():\n{body}\n", "kernels/__init__.py": ""})
    assert import_graph.oversized(root) == [
        f"tdcr_warp/__init__.py:long: function of {import_graph.MAX_FUNCTION + 1} lines "
        f"(limit {import_graph.MAX_FUNCTION})"]


def test_the_module_table_of_the_architecture_page_is_the_codes():
    """docs/architecture.md's module table is generated from the code (each module's file and first
    docstring sentence); a module added, removed or redescribed without `import_graph.py --table`
    fails here, and a planted difference is caught."""
    assert import_graph.stale_table() == []
    table = import_graph.module_table()
    assert table.count("\n| ") == len(import_graph.modules()) + 1  # a row a module, and the header
    planted = table.replace("| model | `tdcr_warp/model/robot.py` |", "| model | `tdcr_warp/model/robots.py` |")
    assert planted != table and import_graph.table_in("x\n" + planted + "\ny") != table
