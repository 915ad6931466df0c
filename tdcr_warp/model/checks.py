"""Checks shared by the model's builders: every bad number stops at the door with an
:class:`InputError` naming the field, the rod and the value."""

from __future__ import annotations

import numbers
import os
import re

import numpy as np

__all__ = ["InputError", "as_field", "check_values", "is_number", "real_array", "require_memory"]


class InputError(ValueError):
    """Bad user input; the message names the field and the offending value."""


# Numbers written as text (command-line arguments, CSV cells): ASCII digits, an optional sign, point
# and exponent, or inf / nan. Python's int() and float() also take "1_000", " 7 " and non-ASCII
# digits ("\u0663"); a careless "1_0" for "1.0" or "10" is refused instead. (In a TOML scene, 1_000
# is TOML's own integer syntax, read by the TOML parser.)
_INTEGER = re.compile(r"[+-]?[0-9]+")
_NUMBER = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?|[+-]?(?:inf|infinity|nan)", re.IGNORECASE)


def is_number(text: str, integer: bool = False) -> bool:
    """Whether ``text`` is a number (an integer) as written above."""
    return (_INTEGER if integer else _NUMBER).fullmatch(text) is not None


def require_memory(nbytes: float, what: str) -> None:
    """An InputError naming ``what`` if it needs more than half of this machine's memory
    (rather than an allocation that swaps, hangs or is killed)."""
    try:
        total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (AttributeError, ValueError, OSError):
        return
    if nbytes > total / 2:
        raise InputError(f"{what} needs {nbytes / 2**30:,.1f} GiB, more than half of this machine's "
                         f"{total / 2**30:.0f} GiB")


_KINDS = {"b": "true/false", "c": "a complex number", "U": "text", "S": "text", "M": "a date", "m": "a time span"}


def real_array(value, name: str, copy: bool = True) -> np.ndarray:
    """``value`` as a float64 array (a new one unless ``copy`` is false), or an InputError naming
    ``name`` for anything but real numbers (complex numbers, text, booleans, dates or other
    objects; ragged nesting), rather than a silent cast (a complex number would lose its imaginary
    part)."""
    try:
        arr = np.asarray(value)
    except (TypeError, ValueError):
        raise InputError(f"{name}: expected a number or a rectangular array of numbers, got {value!r}") from None
    if arr.dtype.kind == "O":  # Python integers beyond int64 (fine), or None, dates, tables, ...
        bad = [x for x in arr.flat if isinstance(x, (bool, np.bool_)) or not isinstance(x, numbers.Real)]
        odd = repr(bad[0]) if bad else None
    else:
        odd = None if arr.dtype.kind in "iuf" else _KINDS.get(arr.dtype.kind, str(arr.dtype))
    if odd is not None:
        raise InputError(f"{name}: expected real numbers, got {odd} in {value!r}")
    return arr.astype(np.float64, copy=copy)


def as_field(name: str, value, tail: tuple[int, ...]) -> np.ndarray:
    """Return ``value`` as a float64 array of shape (1 or B, *tail)."""
    arr = real_array(value, name)
    if arr.shape == tail:
        arr = arr[None]
    if arr.ndim != len(tail) + 1 or arr.shape[1:] != tail or arr.shape[0] < 1:
        want = f"{tail} or (B, {', '.join(map(str, tail))})" if tail else "a number or shape (B,)"
        raise InputError(f"{name}: expected {want}, got shape {arr.shape}")
    bad = ~np.isfinite(arr)
    if bad.any():
        idx = np.argwhere(bad)[0]
        raise InputError(f"{name}: non-finite value {float(arr[tuple(idx)])!r} (rod {idx[0]})")
    arr.flags.writeable = False  # a Robot is immutable: solvers cache what they build from it
    return arr


def check_values(name: str, arr: np.ndarray, ok: np.ndarray, what: str) -> None:
    if not ok.all():
        idx = np.argwhere(~ok)[0]
        raise InputError(f"{name} must be {what}, got {float(arr[tuple(idx)])!r} (rod {idx[0]})")
