"""Newton shooting of one chunk of rods on arrays allocated once.

``Shooting`` holds the Model / Control / Step / State / Work of b rods and solves them:
on a CPU the whole Newton loop of every rod runs in one kernel launch (no host round trip
at all); on CUDA one launch per iteration with a thread per (rod, probe), repeated in
blocks between reads of the count of rods still solving, or inside a CUDA graph
(``wp.capture_while``). The verdict of every rod (kernels/newton.py) is made in the kernels;
the host only reads it.
"""

from __future__ import annotations

import functools
import os
import sys
import time

import numpy as np
import warp as wp

from tdcr_warp.core.build import (
    PRECISIONS,
    Device,
    Tables,
    make_control,
    make_state,
    make_step,
    make_work,
    pack_tendons,
    pad_tensions,
    put_model,
    scene_features,
)
from tdcr_warp.core.launch import Mirror, Replay
from tdcr_warp.kernels import layout
from tdcr_warp.kernels.energy import make_energy_kernels
from tdcr_warp.kernels.history import make_history_kernels
from tdcr_warp.kernels.shooting import make_shooting_kernels
from tdcr_warp.kernels.variants import MODELS
from tdcr_warp.model.options import check_model_support
from tdcr_warp.model.robot import Robot

CHECK_EVERY = 4  # CUDA: Newton iterations between reads of the active count
COARSE_MIN_NODES = 16  # statics: the stability verdict's double steps from this many intervals on
COARSE_STEPS = 8  # statics: the first Jacobian's probes cross the rod in about this many RK4 steps


def coarse_stride(n_int: int, integrator: str, dynamic: bool) -> int:
    """Intervals per step of the first Jacobian's probes in a Broyden solve (0: the fine grid):
    about COARSE_STEPS RK4 steps over the rod, each stopping at every loaded node. Measured
    (experiments/bench_integrations.py): the iterations after such a Jacobian barely change
    (Broyden corrects it), while its 7 integrations cost 8 steps each instead of N (N < 16: N / 2).
    4 steps are cheaper still for the report robot, but from strongly bent starts (the stable-branch
    restarts at 10x the buckling load, tests/test_stability.py) Broyden then finds another root."""
    stride = max(2, -(-n_int // COARSE_STEPS))
    return stride if not dynamic and integrator == "rk4" and n_int >= 4 else 0


def verdict_strides(n_int: int, integrator: str, dynamic: bool) -> tuple[int, ...]:
    """The stability verdict's passes over the grid, coarse to fine (intervals per step of its
    fields): double steps, then the full grid; the full grid alone below COARSE_MIN_NODES
    intervals or with another integrator (the physics layer's Verdict adds finer passes)."""
    return (2, 1) if not dynamic and integrator == "rk4" and n_int >= COARSE_MIN_NODES else (1,)


def first_jacobian(sh: Shooting, x: np.ndarray, mask: np.ndarray) -> None:
    """sh.newton.J of the rods in ``mask`` (b,) bool: the finite-difference Jacobian at the scaled
    unknowns x (b, nu), as a Broyden solve makes its first one (statics), without a step."""
    sh.host(sh.x_in).put(x)
    sh.host(sh.mask).put(mask.astype(np.int32))
    wp.launch(sh.kern.jacobian, dim=sh.b, inputs=[sh.model, sh.control, sh.step, sh.newton, sh.nodes, sh.x_in,
                                                  sh.coarse_jacobian, sh.mask], device=sh.device)


def _fused(driver: str | None, device) -> bool:
    return (driver or ("probes" if device.is_cuda else "fused")) == "fused"


COMPILE_NOTICE = {"enabled": True}  # the one-line notice on stderr before a kernel compile


def set_compile_notice(enabled: bool) -> None:
    """Say on stderr when kernels are about to be compiled (default on; the CLI's --quiet turns it off)."""
    COMPILE_NOTICE["enabled"] = bool(enabled)


def _needs_compile(module, device, block_dim: int) -> bool:
    """Whether loading ``module`` compiles it: not loaded in this process and not in Warp's kernel
    cache (False where Warp's internals differ from 1.19's: no notice rather than a wrong one)."""
    try:
        if module.execs.get((device.context, block_dim)) is not None:
            return False
        return not os.path.isdir(os.path.join(wp.config.kernel_cache_dir, module.get_module_identifier(block_dim)))
    except (AttributeError, TypeError):
        return False


def _load_solver_kernels(k, fused: bool, device) -> None:
    """Compile (or load) the kernels a Shooting of variant k runs: its Newton driver and the
    evaluation module (dynamics: a known state; statics: the unloaded rod's Jacobian, the probes of
    sensitivities and the stability verdict). Loaded before threads share the problem: two threads
    loading one module at once can unload the code the other runs (a crash seen in threaded sweeps)."""
    _load_modules((k.solve if fused else k.probe, k.evaluate), device)


def _load_modules(kernels: tuple, device) -> None:
    """Compile (or load) the modules of ``kernels``. Before a compile, one line on stderr says so
    (``set_compile_notice``), and after it how long it took."""
    device = wp.get_device(device)
    block = 1 if device.is_cpu else 256
    compiling = COMPILE_NOTICE["enabled"] and any(_needs_compile(kn.module, device, block) for kn in kernels)
    if compiling:
        print(f"tdcr-warp: compiling kernels for {device} (first use of this robot's features and solver options "
              "with this kernel cache; typically 5-30 s, then cached) ...", end=" ", file=sys.stderr, flush=True)
    t0 = time.perf_counter()
    for kernel in kernels:
        kernel.module.load(device, block)
    if compiling:
        print(f"{time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)


def load_kernels(robot: Robot, options, device=None, *, dynamic: bool = False) -> float:
    """Compile (on first use with this kernel cache) or load every kernel that solving this
    robot with these options needs: statics, and with ``dynamic`` the time step too. Returns
    the seconds it took, so that callers can report solve rates without it."""
    t0 = time.perf_counter()
    check_model_support(robot, options.model, dynamic)  # before a kernel of a combination that does not exist
    if options.model not in MODELS:  # the closed-form rung has no kernels
        return 0.0
    dev = wp.get_device(device)
    tendon = pack_tendons(robot)
    wdtype = PRECISIONS[options.precision][0]
    disks = options.model == "disks"
    variants = [(False, scene_features(robot, tendon, options.specialize, options.kink_loads,
                                       lengths=options.tendon_states, disks=disks))]
    if robot.displaced:  # the reference state of displacement control
        variants.append((False, scene_features(robot, tendon, options.specialize, options.kink_loads, "reference",
                                               disks=disks)))
    if dynamic:
        variants.append((True, scene_features(robot, tendon, options.specialize, options.kink_loads)))
    for dyn, features in variants:
        k = make_shooting_kernels(wdtype, options.integrator, options.model, dyn, options.rod, features)
        _load_solver_kernels(k, _fused(options.driver, dev), dev)
    if dynamic:
        make_history_kernels(wdtype).end_step.module.load(dev, 1 if dev.is_cpu else 256)
        f = variants[-1][1]
        make_energy_kernels(wdtype, f.helix, f.spline).energy.module.load(dev, 1 if dev.is_cpu else 256)
    return time.perf_counter() - t0


class Shooting:
    """The shooting problem of rods lo:hi of a batch (``tables``) under tensions tau (b, K).

    Device fields: ``model``, ``control``, ``step`` (dynamics: BDF-alpha history), ``nodes``
    (the state at the nodes of the last accepted trial) and ``newton`` (unknowns x, Jacobian J,
    status, iterations, integrations, residual, and the scratch of the iteration). ``probe``
    integrates outside the Newton loop (``Probes``); ``loop`` runs that loop (``NewtonLoop``).
    Its launches are recorded once and replayed (tdcr_warp.core.launch.Replay), and its own arrays
    are read and written on the host through ``host`` (a Mirror each).
    """

    def __init__(self, tables: Tables, lo: int, hi: int, tau: np.ndarray, *, precision: str, integrator: str,
                 model: str, device, dynamic: bool = False, rod: str = "cosserat", driver: str | None = None):
        self.dev = Device(device, precision)
        self.device = device
        self.dynamic = dynamic
        self.variant = (self.dev.wdtype, integrator, model, dynamic, rod, tables.features)  # the kernels'
        k = self.kern = make_shooting_kernels(*self.variant)
        self.b = b = hi - lo
        self.tendon_len = np.broadcast_to(tables.rows("tendon_len", lo, hi), (b, tables.tendon_len.shape[1]))
        self.n1 = n1 = tables.grid.shape[1]
        self.n_slots = (n1 - 1) * k.stages + 2 * n1
        self.model = put_model(k, self.dev, tables, lo, hi)
        self.control = make_control(k, self.dev, tau, self.n_slots)
        self.step = make_step(k, self.dev, b, self.n_slots, dynamic)
        self.nodes = make_state(k, self.dev, b, n1, dynamic)
        self.newton = make_work(k, self.dev, b)
        self.x_in = wp.zeros(b, dtype=k.vecu, device=device)  # host-given starts
        self.mask = wp.zeros(b, dtype=int, device=device)
        self.all_rods = wp.ones(b, dtype=int, device=device)
        self._mirrors: dict[int, Mirror] = {}
        self.loop = NewtonLoop(k, device, b, _fused(driver, device))
        self.probe = Probes(self)
        self._evaluate = Replay(k.evaluate, b, device)
        # statics: double steps for the stability verdict where they stay accurate (RK4, error ~h^4,
        # on a fine enough grid); the first Jacobian of a Broyden solve from probes over long steps
        self.verdict_strides = verdict_strides(n1 - 1, integrator, dynamic)
        self.coarse_stride = coarse_stride(n1 - 1, integrator, dynamic)
        self.coarse_jacobian = self.coarse_stride
        _load_solver_kernels(k, self.loop.fused, device)  # before threads race to it

    def host(self, arr: wp.array) -> Mirror:
        """The Mirror of one of this problem's own arrays (made on first use; arrays that a caller
        swaps in, such as a load path's tables, go through ``dev.put``)."""
        m = self._mirrors.get(id(arr))
        if m is None or m.arr is not arr:
            m = self._mirrors[id(arr)] = Mirror(arr, self.dev.ndtype)
        return m

    def set_tensions(self, tau: np.ndarray) -> None:
        self.host(self.control.tau).put(pad_tensions(tau))

    def set_command(self, tau: np.ndarray, avail: np.ndarray | None = None) -> None:
        """Tensions (b, K) [N] and, under displacement control, the unstretched length the motor
        gives each displaced tendon (b, K) [m]."""
        self.set_tensions(tau)
        if avail is not None and self.kern.tstate:
            self.host(self.control.avail).put(avail - self.tendon_len)  # the kernels' lengths are less l

    def set_taut(self, taut: np.ndarray) -> None:
        """Which displaced tendons are taut (b, K) bool: their unknown is a tension; the others
        are slack (zero tension; the unknown measures the slack)."""
        if self.kern.tstate:
            self.host(self.control.taut).put(taut)

    def set_memory(self, slip: np.ndarray, profile: np.ndarray | None) -> None:
        """Friction: slip directions (b, K) in [-1, 1] and, for a stick-slip solve, the previous
        solution's tension profile (b, S, 3K: tension, tau', state at every slot) or None. A
        remembered profile lives on the exact evaluation points of the fine grid, so those solves
        keep every probe on it (no coarse first Jacobian)."""
        if not self.kern.friction:
            return
        ct, K = self.control, self.kern.K
        self.host(ct.slip).put(slip)
        ct.stick = int(profile is not None)
        if profile is not None:
            self.host(ct.tau_old).put(profile[..., :K])
            self.host(ct.dtau_old).put(profile[..., K:2 * K])
        self.coarse_jacobian = self.coarse_stride if profile is None else 0

    def evaluate(self, x: np.ndarray) -> None:
        """One integration per rod from scaled unknowns x (b, nu), storing shapes and slots."""
        self.host(self.x_in).put(x)
        self._evaluate(self.model, self.control, self.step, self.x_in, self.nodes, *self.probe.out, 1)

    def solve(self, start=None, *, tol: float, max_iter: int, max_step: float, broyden: bool,
              mask: np.ndarray | None = None, fresh_jacobian: bool = True) -> None:
        """Newton for the rods in ``mask`` (default all; the others keep their results).

        start: scaled unknowns (b, 6) on the host, a device array of them, or None (the last
        solution). fresh_jacobian: finite differences first, or reuse ``newton.J`` (a warm
        start's Jacobian, or the last one)."""
        if start is None:
            x_from = self.newton.x
        elif isinstance(start, wp.array):
            x_from = start
        else:
            self.host(self.x_in).put(start)
            x_from = self.x_in
        if mask is None:
            m = self.all_rods
        else:
            self.host(self.mask).put(mask)
            m = self.mask
        self.loop.run(self, x_from, m, (tol, max_iter, max_step, broyden), fresh_jacobian)

    def counts(self) -> tuple[np.ndarray, np.ndarray]:
        """Newton iterations and integrations of every rod's last solve, (b,) int64 host copies."""
        return self.host(self.newton.iters).get(np.int64), self.host(self.newton.n_shoot).get(np.int64)

    def set_counts(self, iters: np.ndarray, shots: np.ndarray) -> None:
        """Report these iterations and integrations (a rod's sums over several solves)."""
        self.host(self.newton.iters).put(iters)
        self.host(self.newton.n_shoot).put(shots)

    def status(self) -> np.ndarray:
        """(b,) the status bits of every rod's last solve (a host copy)."""
        return self.host(self.newton.status).get()

    def converged(self) -> np.ndarray:
        return (self.host(self.newton.status).peek() & layout.CONVERGED) != 0

    def tendon_table(self) -> np.ndarray:
        """(b, K, layout.TO_WIDTH) float64 per tendon from the last stored evaluation, lengths in
        full (the kernels keep them less the tendon's arc length)."""
        td = self.host(self.nodes.tend).get(np.float64)
        for col in (layout.TO_PATH, layout.TO_FREE):
            td[..., col] += self.tendon_len
        return td

    def results(self) -> dict[str, np.ndarray]:
        """Host copies (float64) of the solution and the outcome of every rod (with tendon states
        also ``tendons`` (b, K, layout.TO_WIDTH), ``tension_nodes`` (b, N+1, K) and with friction
        ``tension_slots`` (b, S, 3K))."""
        f64, get = np.float64, self.host
        nw, out = self.newton, self.nodes
        status = get(nw.status).get()
        extra = {}
        if self.kern.tstate:
            extra = {"tendons": self.tendon_table(), "tension_nodes": get(out.taun).get(f64)}
        if self.kern.friction:
            extra["tension_slots"] = get(self.step.tprof).get(f64)
        return extra | {
            "positions": get(out.p).get(f64), "rotations": get(out.R).get(f64),
            "n": get(out.n).get(f64), "m": get(out.m).get(f64),
            "x": get(nw.x).get(f64), "converged": (status & layout.CONVERGED) != 0,
            "status": status, "iterations": get(nw.iters).get(), "integrations": get(nw.n_shoot).get(),
            "residual": get(nw.resnorm).get(f64), "orthogonality_error": get(out.orth).get(f64),
            "jacobian": get(nw.J).get(f64),
        }


class NewtonLoop:
    """How the Newton loop of a Shooting's b rods runs on its device: ``fused``, the whole loop of
    every rod in one kernel launch (no host round trip at all; the CPU default), or a launch per
    iteration with a thread per (rod, probe), repeated in blocks of CHECK_EVERY iterations between
    reads of the count of rods still solving (the CUDA default)."""

    def __init__(self, kern, device, b: int, fused: bool):
        self.kern, self.device, self.b, self.fused = kern, device, b, fused
        self._settings: tuple = (None, None)  # the last Newton settings and their typed values
        if fused:
            self.solve = Replay(kern.solve, b, device)
        else:
            self.begin, self.finish = Replay(kern.begin, b, device), Replay(kern.finish, b, device)
            self.probe, self.update = Replay(kern.probe, b * kern.width, device), Replay(kern.update, b, device)

    def run(self, sh: Shooting, x_from: wp.array, mask: wp.array, settings: tuple, fresh_jacobian: bool) -> None:
        """Newton for the rods of ``sh`` in ``mask`` (device int per rod) from the unknowns ``x_from``;
        settings = (tol, max_iter, max_step, broyden), typed for the kernels once per distinct settings."""
        if settings != self._settings[0]:
            tol, max_iter, max_step, broyden = settings
            self._settings = (settings, [sh.dev.wdtype(tol), int(max_iter), sh.dev.wdtype(max_step), int(broyden)])
        newton, nw = self._settings[1], sh.newton
        if self.fused:
            self.solve(sh.model, sh.control, sh.step, nw, sh.nodes, x_from, int(fresh_jacobian), *newton,
                       sh.coarse_jacobian, mask)
            return
        nw.n_active.zero_()
        self.begin(nw, x_from, int(fresh_jacobian), mask)
        self._iterate(sh, newton)
        self.finish(sh.model, sh.control, sh.step, nw, sh.nodes, mask)

    def _iterate(self, sh: Shooting, newton: list) -> None:
        """Iterations with a thread per (rod, probe); no host read inside a block (graph-capturable)."""
        nw, max_iter = sh.newton, newton[1]

        def iteration():
            self.probe(sh.model, sh.control, sh.step, nw, sh.nodes, newton[3], sh.coarse_jacobian)
            nw.n_active.zero_()
            self.update(sh.model, nw, *newton, sh.coarse_jacobian)

        for done in range(0, max_iter, CHECK_EVERY):
            for _ in range(min(CHECK_EVERY, max_iter - done)):
                iteration()
            if int(nw.n_active.numpy()[0]) == 0:
                break


class Probes:
    """Single integrations of a Shooting's rods outside its Newton loop, leaving the solution
    untouched: the probes of finite differences (sensitivities, the stability test). Their shapes
    live apart from the solution's ``nodes``; the outputs ``out`` also serve ``Shooting.evaluate``."""

    def __init__(self, sh: Shooting):
        self.sh = sh
        self.launch = Replay(sh.kern.evaluate, sh.b, sh.device)

    @functools.cached_property
    def out(self) -> tuple[wp.array, wp.array, wp.array]:
        """(b,) residuals, tip positions and tip orientations of the last ``evaluate`` or probe."""
        sh = self.sh
        k, d = sh.kern, sh.device
        return (wp.zeros(sh.b, dtype=k.vecu, device=d), wp.zeros(sh.b, dtype=k.vec3, device=d),
                wp.zeros(sh.b, dtype=k.mat33, device=d))

    @functools.cached_property
    def nodes(self):
        """The shapes of a probe; made with the first probe (once per Shooting, not per probe)."""
        sh = self.sh
        return make_state(sh.kern, sh.dev, sh.b, sh.n1, sh.dynamic)

    def __call__(self, x: np.ndarray, model=None, *, shapes: bool = False) -> dict[str, np.ndarray]:
        """One integration per rod from scaled unknowns x (b, nu) under ``model`` (default the
        problem's; a perturbed Model of the same shape) and the current Control (statics: with
        ``shapes`` and friction the trial point's tension profile is overwritten, so read
        ``Shooting.results`` first). Returns float64 host copies of the residual ``res`` (b, nu), the
        tip ``p`` (b, 3) and ``R`` (b, 3, 3) and with ``shapes`` the node arrays ``P``, ``Rn``, ``n``,
        ``m`` (b, N+1, ...)."""
        sh = self.sh
        out = self.nodes
        sh.host(sh.x_in).put(x)
        self.launch(model or sh.model, sh.control, sh.step, sh.x_in, out, *self.out, int(shapes))
        f64 = np.float64
        res, p, R = (sh.host(a).get(f64) for a in self.out)
        got = {"res": res, "p": p, "R": R}
        if shapes:
            got |= {"P": sh.host(out.p).get(f64), "Rn": sh.host(out.R).get(f64), "n": sh.host(out.n).get(f64),
                    "m": sh.host(out.m).get(f64)}
        return got
