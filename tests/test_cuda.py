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


def test_cuda_contact_and_segments_match_cpu():
    """Contact in statics and in dynamics, and multiple shooting, give the CPU's answers on CUDA:
    64 rods pulled onto a plane (statics, then 10 steps of 5 ms), and the report's robot split into
    11 segments at dt = 1e-5 s (5 steps)."""
    rng = np.random.default_rng(3)
    B = 64
    offsets = [(0.01, 0.0), (0.0, 0.01), (-0.01, 0.0), (0.0, -0.01)]
    walled = tw.Robot(length=0.5, density=7800.0, gravity=(0, 0, -9.81), tendons=[tw.Tendon(offset=o) for o in offsets],
                      damping_bending=(0.008,) * 3, drag=(0.01,) * 3,
                      obstacles=[tw.Obstacle("plane", point=(0.012, 0, 0), normal=(-1, 0, 0))])
    tau = np.zeros((B, 4))
    tau[:, 0] = rng.uniform(0.0, 3.0, B)
    cpu, gpu = (tw.solve_static(walled, tau, nodes=30, device=d) for d in ("cpu", "cuda:0"))
    assert np.array_equal(cpu.success, gpu.success) and cpu.success.all()
    assert np.abs(cpu.tip_position - gpu.tip_position).max() < 1e-9
    assert (np.abs(cpu.contact_force).sum(axis=(1, 2)) > 0).sum() > 10  # many rods touch
    runs = [tw.Simulator(walled, np.zeros((B, 4)), dt=5e-3, nodes=30, device=d).simulate(np.repeat(tau[:, None], 10, 1), 10)
            for d in ("cpu", "cuda:0")]
    assert runs[0].converged.all() and runs[1].converged.all()
    assert np.abs(runs[0].tip_position - runs[1].tip_position).max() < 1e-8
    seed = tw.Robot(length=0.5, youngs_modulus=190e9, poisson_ratio=0.3, radius=1e-3, density=17189.0,
                    tendons=[tw.Tendon(offset=o) for o in offsets], gravity=(0.0, 0.0, -9.81),
                    damping_bending=(0.008,) * 3, drag=(0.01,) * 3)
    split = [tw.Simulator(seed, [[0.0] * 4], dt=1e-5, nodes=40, segments=11, device=d)
             .simulate(np.tile([[3.0, 0.0, 0.0, 0.0]], (5, 1)), 5) for d in ("cpu", "cuda:0")]
    assert split[0].converged.all() and split[1].converged.all()
    assert np.abs(split[0].tip_position - split[1].tip_position).max() < 1e-9
