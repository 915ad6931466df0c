"""Writing into output folders without surprises (docs/outputs.md, "Output safety").

* No link is followed and no existing file is truncated: a file is written to a temporary one
  that this process creates new (``O_CREAT | O_EXCL | O_NOFOLLOW``, an unguessable name) and
  renamed over its target (a rename replaces a link, it never writes through it). A lock file
  is opened with ``O_NOFOLLOW`` and refused when it is a link, not a regular file, or has a
  second hard link.
* One file mode: every file is created with 0666 less the umask, as ``open()`` creates one
  (``tempfile.mkstemp`` would make 0600).
* One writer per folder: :class:`FolderLock`, an exclusive ``flock`` on ``DIR/.lock``.
* Names shown on a terminal go through :func:`printable`: control characters escaped.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import json
import os
import secrets
import socket
import stat
import time
from pathlib import Path
from typing import Self

from tdcr_warp.model.checks import InputError

__all__ = ["FILE_MODE", "FolderLock", "open_lock", "printable", "temporary", "write_atomic"]

FILE_MODE = 0o666  # the mode files are created with, less the umask (as open() does)
LOCK = ".lock"


def printable(text) -> str:
    """``str(text)`` (a path, a label) with every character that is not printable (C0 and C1
    controls such as ESC, newline, DEL, bidirectional overrides) escaped as Python writes it
    (``\\x1b``, ``\\n``, ``\\u202e``): a name cannot move the cursor, clear the screen or split
    a one-line message."""
    return "".join(c if c.isprintable() else c.encode("unicode_escape", "backslashreplace").decode("ascii")
                   for c in str(text))


def temporary(path: Path) -> Path:
    """A new empty file beside ``path`` (``.STEM.RANDOM.tmpSUFFIX``: the suffix kept for writers
    that read the format from it), created exclusively without following links, mode
    FILE_MODE less the umask."""
    path = Path(path)
    tmp = path.with_name(f".{path.stem}.{secrets.token_hex(8)}.tmp{path.suffix}")
    os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC, FILE_MODE))
    return tmp


def write_atomic(path: Path, write) -> None:
    """``write(tmp)`` writes the content into ``tmp`` (a :func:`temporary` file beside ``path``),
    which is then renamed over ``path``; the temporary file never outlives the call."""
    path = Path(path)
    tmp = temporary(path)
    try:
        write(tmp)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def open_lock(path: Path):
    """``path`` opened for reading and writing (created, mode FILE_MODE less the umask, when it
    does not exist) without following a link; a link, a file that is not a regular one, or one
    with a second hard link is an InputError (locking would truncate what it points to)."""
    try:
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_CLOEXEC, FILE_MODE)
    except OSError as e:
        why = "is a symbolic link: refusing to follow it" if e.errno == errno.ELOOP else f"cannot be opened ({e.strerror})"
        raise InputError(f"{path}: the lock file {why}; remove it") from None
    st = os.fstat(fd)
    if not stat.S_ISREG(st.st_mode) or st.st_nlink != 1:
        os.close(fd)
        what = "not a regular file" if not stat.S_ISREG(st.st_mode) else f"a file with {st.st_nlink} hard links"
        raise InputError(f"{path}: the lock file is {what}: refusing to write it; remove it")
    return os.fdopen(fd, "r+")


class FolderLock:
    """One writer per output folder: an exclusive ``flock`` on ``out/.lock`` (:func:`open_lock`),
    which records the holder (command, pid, host, start) and is removed when the writer ends. The
    kernel drops the lock when the process ends however it ends (kill -9 included), so a lock
    file left behind by a dead process is stale by construction: the next writer takes it over
    (``stale`` says whose it was). A second live writer (a run or a sweep) is refused with a
    message naming the folder and the holder."""

    def __init__(self, out: Path, command: str):
        self.path = Path(out) / LOCK
        self.command = command
        self.stale: dict | None = None
        self._f = None

    def __enter__(self) -> Self:
        while True:
            f = open_lock(self.path)
            try:
                fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                holder = _holder(f.read())
                f.close()
                raise InputError(f"{self.path.parent} is being written by another {holder}; wait for it to "
                                 "end or choose another --out") from None
            if _is_at(f, self.path):
                break
            f.close()  # its holder ended and removed it: lock the file now at the path
        with contextlib.suppress(ValueError):
            self.stale = json.loads(f.read().strip() or "null")
        f.seek(0)
        f.truncate()
        f.write(json.dumps({"command": self.command, "pid": os.getpid(), "host": socket.gethostname(),
                            "started": time.strftime("%Y-%m-%dT%H:%M:%S%z")}))
        f.flush()
        self._f = f
        return self

    def __exit__(self, *exc) -> None:
        self.path.unlink(missing_ok=True)  # while still held: a waiter that opened it sees it gone
        fcntl.flock(self._f, fcntl.LOCK_UN)
        self._f.close()


def _is_at(f, path: Path) -> bool:
    """Whether the open file ``f`` is still the file at ``path`` (not removed or replaced)."""
    try:
        st = os.stat(path, follow_symlinks=False)
    except FileNotFoundError:
        return False
    mine = os.fstat(f.fileno())
    return (st.st_dev, st.st_ino) == (mine.st_dev, mine.st_ino)


def _holder(text: str) -> str:
    """The holder a lock file records, in words: ``tdcr-warp static (pid 12 on host, started ...)``."""
    try:
        h = json.loads(text)
        return f"tdcr-warp {h.get('command', 'sweep')} (pid {h['pid']} on {h['host']}, started {h['started']})"
    except (ValueError, KeyError, TypeError, AttributeError):
        return f"process ({text.strip() or 'unknown'})"
