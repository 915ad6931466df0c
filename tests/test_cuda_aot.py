"""CUDA readiness without a GPU: every option of the kernel factories builds for sm_90
(H100/H200) ahead of time, with Warp's NVRTC on this CPU-only machine. A GPU run is the only
stronger check (tests/test_cuda.py, skipped here)."""

import os

from tdcr_warp.core.aot import compile_all, covering_variants, group, segmented


def test_every_kernel_option_builds_for_sm90(tmp_path):
    variants = covering_variants()
    seen = {field: {getattr(v, field) for v in variants} for field in ("precision", "integrator", "model", "rod",
                                                                       "dynamic")}
    assert seen == {"precision": {"float64", "float32"}, "integrator": {"euler", "midpoint", "rk4"},
                    "model": {"coupled", "point", "disks"}, "rod": {"cosserat", "kirchhoff"},
                    "dynamic": {False, True}}
    assert {v.features[:5] for v in variants} >= {(True,) * 5, (False,) * 5}
    assert {(v.model, v.features.friction, v.features.displaced > 0) for v in variants} >= {
        ("coupled", True, True), ("point", True, True), ("disks", False, True)}
    assert {(v.dynamic, v.features.contact and v.features.tip > 0) for v in variants} >= {(False, True), (True, True)}
    assert sum(segmented(v) is not None for v in variants) >= 3  # dynamics, and statics with obstacles
    results = compile_all(variants, 90, str(tmp_path), jobs=os.cpu_count() or 1, log=lambda line: None)
    for v, mods in results:
        groups = {group(name) for name, _, _ in mods}
        assert groups == {"fused", "probes", "evaluate"} | ({"history", "energy"} if v.dynamic else set()) | (
            {"contact"} if v.features.contact else set()) | ({"segments", "banded"} if segmented(v) is not None else set()), v
        for name, _, files in mods:
            assert files, f"{v}: {name} built nothing"
            for f in files:
                assert f.endswith(".sm90.cubin"), f
                with open(f, "rb") as fh:
                    assert fh.read(4) == b"\x7fELF", f"{f} is not a CUDA binary"
