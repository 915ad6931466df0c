"""Input files read with limits: a regular file, no larger than a stated size, read whole (the
outputs are tdcr_warp/io/files.py's).

Every file a command reads as input goes through :func:`read_limited`, so that a path that never
ends (a device such as /dev/zero, a FIFO, a growing file) or a file far beyond what the input can
hold is an :class:`InputError` naming it, never a read until the memory runs out or a wait for a
writer. The limits are documented in docs/getting-started.md (Limits on input files).
"""

from __future__ import annotations

import os
import stat

from tdcr_warp.model.robot import InputError

__all__ = ["MIB", "SCENE_LIMIT", "TABLE_LIMIT", "read_limited"]

MIB = 2**20
SCENE_LIMIT = 8 * MIB  # a scene TOML (per-rod tables beyond that belong in .npy, .csv or .parquet files)
TABLE_LIMIT = 256 * MIB  # a per-rod table file (.npy, .csv, .parquet), and the numbers read from it

_KINDS = ((stat.S_ISDIR, "a directory"), (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
          (stat.S_ISFIFO, "a named pipe"), (stat.S_ISSOCK, "a socket"))


def _size(n: int) -> str:
    return f"{n / MIB:,.1f} MiB" if n >= MIB else f"{n:,} bytes"


def read_limited(path, limit: int, what: str) -> bytearray:
    """The bytes of the regular file ``path``, at most ``limit`` of them; anything else is an
    InputError "``what``: <the problem>" (``what`` names the input, e.g. "cannot read scene
    'a.toml'"): a file that cannot be opened, one that is not a regular file (a directory, a
    device, a FIFO, a socket), or one larger than ``limit`` bytes. The file is opened without blocking (a FIFO
    would wait for a writer) and read up to ``limit`` + 1 bytes (a file that grows while it is
    read is caught too)."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except OSError as e:
        raise InputError(f"{what}: {e.strerror or e}") from None
    except ValueError as e:  # a name with a NUL character
        raise InputError(f"{what}: {e}") from None
    st = os.fstat(fd)
    if not stat.S_ISREG(st.st_mode):
        os.close(fd)
        kind = next((name for test, name in _KINDS if test(st.st_mode)), "something else")
        raise InputError(f"{what}: not a regular file ({kind})")
    with os.fdopen(fd, "rb", buffering=0) as f:
        if st.st_size > limit:
            raise InputError(f"{what}: the file holds {_size(st.st_size)}, more than the {_size(limit)} this "
                             "input takes")
        data = bytearray()
        try:
            while len(data) <= limit and (part := f.read(limit + 1 - len(data))):
                data += part
        except OSError as e:
            raise InputError(f"{what}: {e.strerror or e}") from None
    if len(data) > limit:
        raise InputError(f"{what}: the file grew beyond the {_size(limit)} this input takes while it was read")
    return data
