"""The same solver on CUDA gives the CPU's answers (skipped without a GPU)."""

import numpy as np
import pytest
import warp as wp

import tdcr_warp as tw

pytestmark = pytest.mark.skipif(not wp.is_cuda_available(), reason="no CUDA device")


@pytest.mark.parametrize("model", ["coupled", "point"])
def test_cuda_matches_cpu(model):
    rng = np.random.default_rng(1)
    B = 300
    rob = tw.Robot(length=rng.uniform(0.3, 0.6, B), density=7800.0, gravity=(0, -9.81, 0),
                   tendons=[tw.Tendon(offset=(0.01, 0.0)), tw.Tendon(offset=(0.0, 0.01), length=0.2),
                            tw.Tendon(routing="helix", helix_radius=0.008, turns=0.5)])
    tau = rng.uniform(0, 3, (B, 3))
    cpu = tw.solve_static(rob, tau, model=model, device="cpu")
    gpu = tw.solve_static(rob, tau, model=model, device="cuda:0")
    assert np.array_equal(cpu.converged, gpu.converged)
    ok = cpu.converged
    assert np.abs(cpu.tip_position[ok] - gpu.tip_position[ok]).max() < 1e-9
