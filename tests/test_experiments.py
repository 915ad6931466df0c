"""Every experiment script runs end to end at tiny size (--smoke), so none rots."""

import importlib.util
import json
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPTS = sorted(p for p in (ROOT / "experiments").glob("*.py") if not p.name.startswith("_"))


@pytest.mark.parametrize("script", SCRIPTS, ids=lambda p: p.name)
def test_experiment_smoke(script, tmp_path):
    if script.name == "bench_ray.py":
        pytest.importorskip("ray")
    if script.name == "jax_port.py":  # optional extra "bench"; even at --smoke its JAX compiles take minutes
        pytest.skip("jax_port.py: run by hand (python experiments/jax_port.py --smoke)")
    spec = importlib.util.spec_from_file_location(script.stem, script)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    out = tmp_path / "out.json"
    assert mod.main(["--smoke", "--out", str(out)]) == 0
    assert json.loads(out.read_text())["meta"]["warp"]
