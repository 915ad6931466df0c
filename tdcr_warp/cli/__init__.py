"""Command line: ``tdcr-warp static|simulate|control|ik SCENE.toml``, the sweeps
``tdcr-warp montecarlo|workspace|gain-grid SCENE.toml``, the gain search
``tdcr-warp search SCENE.toml``, measured robots ``tdcr-warp fit|predict SCENE.toml DATA.csv`` and
``tdcr-warp warmup`` (this machine's kernels built ahead of use).

One module per command (its ``register(subparsers)``: the arguments; its ``run(args) -> int``:
the wiring of the layers below), the shared helpers in ``common`` and ``animation``.

Exit status: 0 every rod converged; 1 some rods failed (outputs written, reasons recorded);
2 bad input (the message names the field and the value, no traceback); 130 interrupted (Ctrl-C:
one line on stderr, and no completion file: results.json, metrics.json, ik.json, fit.json).
Every message is printed with its control characters escaped (tdcr_warp.io.files.printable): a
path or label cannot drive the terminal.
"""

from __future__ import annotations

import argparse
import gc
import signal
import sys
import threading

from tdcr_warp.cli import (
    control,
    fit,
    ik,
    predict,
    search,
    simulate,
    static,
    sweep,
    warmup,
)
from tdcr_warp.core.progress import Progress
from tdcr_warp.io.files import printable
from tdcr_warp.model.robot import InputError

# in the order of the help's list of commands
COMMANDS = (static, simulate, control, sweep, search, ik, predict, fit, warmup)


def build_parser() -> argparse.ArgumentParser:
    """The ``tdcr-warp`` parser: every command's arguments, and the command's ``run`` as ``args.run``."""
    ap = argparse.ArgumentParser(prog="tdcr-warp", description="Batched tendon-driven continuum robots on Warp.")
    ap.add_argument("--version", action=_Version, nargs=0, help="show the tdcr-warp and Warp versions and exit")
    sub = ap.add_subparsers(dest="command", required=True)
    for command in COMMANDS:
        command.register(sub)
    return ap


class _Version(argparse.Action):
    """--version: the versions, looked up (Warp imported) only when asked."""

    def __call__(self, parser, namespace, values, option_string=None):
        import warp

        from tdcr_warp import __version__
        print(f"{parser.prog} {__version__} (Warp {warp.__version__})")
        parser.exit()


def _on_sigint(signum, frame) -> None:
    """The first Ctrl-C: ignore any further one (the process is ending: its cleanups run to
    their end), then interrupt as Python does."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    raise KeyboardInterrupt


def _check_device(args) -> None:
    """--device names a device of this machine (checked here unless the chunks run on Ray)."""
    if args.device is not None and getattr(args, "backend", "local") == "local":
        import warp as wp
        try:
            wp.get_device(args.device)
        except (RuntimeError, ValueError) as e:
            raise InputError(f"--device {args.device!r}: {e}") from None


def _import_solver():
    """tdcr_warp.core.solver, which imports Warp and the kernel factories (most of a command's
    start-up), with the cyclic garbage collector paused: the import makes ~1e5 objects and no
    garbage; the collections during it cost ~10% of its 0.3 s (measured, median of 7)."""
    paused = gc.isenabled()
    gc.disable()
    try:
        from tdcr_warp.core import solver
    finally:
        if paused:
            gc.enable()
    return solver


MESSAGE_CHARS = 2000  # the most characters of an error message printed (a hostile key or value can be megabytes)


def one_line(message: str) -> str:
    """``message`` on one line (newlines as spaces), at most MESSAGE_CHARS characters of it."""
    flat = " ".join(message.splitlines())
    return flat if len(flat) <= MESSAGE_CHARS else f"{flat[:MESSAGE_CHARS]} ... ({len(flat):,} characters)"


def main(argv=None) -> int:
    """Run the command line; returns the exit status (0 ok, 1 some rods failed, 2 bad input,
    130 interrupted). A malformed command line (argparse) raises SystemExit(2) after printing
    the usage. Ctrl-C (SIGINT, KeyboardInterrupt) ends any command with one line on stderr and
    no completion file; from the first SIGINT on, SIGINT is ignored (_on_sigint). Without ``argv``
    (the process's own command line: ``tdcr-warp``, ``python -m tdcr_warp``) the objects left are
    frozen (``gc.freeze``) so that the interpreter's exit skips a garbage collection over them."""
    from tdcr_warp.apps.cluster import SweepError

    args = build_parser().parse_args(argv)
    own = (threading.current_thread() is threading.main_thread()
           and signal.getsignal(signal.SIGINT) is signal.default_int_handler)
    if own:  # (not where SIGINT is ignored, as in a background job, or handled by the caller)
        signal.signal(signal.SIGINT, _on_sigint)
    solver = _import_solver()
    notice = solver.COMPILE_NOTICE["enabled"]
    solver.set_compile_notice(not args.quiet)
    if args.verbose:
        import warp as wp
        log_level, wp.config.log_level = wp.config.log_level, wp.LOG_INFO
    try:
        _check_device(args)
        return args.run(args)
    except KeyboardInterrupt:
        Progress.end_line()
        print("tdcr-warp: interrupted", file=sys.stderr)
        return 130
    except (InputError, OSError) as e:
        print(f"tdcr-warp: error: {printable(one_line(str(e)))}", file=sys.stderr)
        return 2
    except SweepError as e:
        print(f"tdcr-warp: error: {printable(one_line(str(e)))}", file=sys.stderr)
        return 1
    finally:
        solver.set_compile_notice(notice)
        if args.verbose:
            wp.config.log_level = log_level
        if own and signal.getsignal(signal.SIGINT) is _on_sigint:  # no SIGINT came: as it was
            signal.signal(signal.SIGINT, signal.default_int_handler)
        if argv is None:  # the process's own command line, which ends now: no final garbage collection
            gc.freeze()   # over Warp's objects at exit (0.4-3 s measured, 0.1 s frozen)
