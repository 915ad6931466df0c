"""tdcr_warp.io.files: writes that follow no link, one file mode, one writer per folder, and
names shown with their control characters escaped."""

import json
import os
import stat

import pytest

from tdcr_warp.io.files import FolderLock, open_lock, printable, temporary, write_atomic
from tdcr_warp.model.robot import InputError

PRECIOUS = "a file outside the output folder\n"


@pytest.fixture
def umask_027():
    old = os.umask(0o027)
    yield 0o640
    os.umask(old)


def test_printable_escapes_every_control_character():
    assert printable("out/\x1b[2J\x07scene\n\r\t\x7f\x9b\u202e.toml") == \
        "out/\\x1b[2J\\x07scene\\n\\r\\t\\x7f\\x9b\\u202e.toml"
    assert printable("plain/ü é ∂ 'quoted' \\ path") == "plain/ü é ∂ 'quoted' \\ path"  # printable text untouched
    assert printable(printable("\x1b")) == "\\x1b"  # idempotent: escaping twice changes nothing
    assert printable(os.fsdecode(b"bad\xffname")) == "bad\\udcffname"  # an undecodable byte of a file name


def test_write_atomic_replaces_a_link_and_never_writes_through_it(tmp_path):
    target = tmp_path / "precious.txt"
    target.write_text(PRECIOUS)
    link = tmp_path / "results.json"
    link.symlink_to(target)
    write_atomic(link, lambda tmp: open(tmp, "w").write("new"))
    assert target.read_text() == PRECIOUS
    assert not link.is_symlink() and link.read_text() == "new"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["precious.txt", "results.json"]  # no temporary left


def test_a_failed_write_leaves_neither_target_nor_temporary(tmp_path):
    def fail(tmp):
        open(tmp, "w").write("half")
        raise RuntimeError("disk full")
    with pytest.raises(RuntimeError):
        write_atomic(tmp_path / "a.json", fail)
    assert list(tmp_path.iterdir()) == []


def test_files_get_the_mode_open_gives_them(tmp_path, umask_027):
    """0666 less the umask, as open() creates a file (tempfile.mkstemp would give 0600)."""
    write_atomic(tmp_path / "a.npz", lambda tmp: open(tmp, "wb").write(b"x"))
    (tmp_path / "b.txt").write_text("plain open()")
    tmp = temporary(tmp_path / "c.png")
    assert tmp.name.startswith(".c.") and tmp.name.endswith(".tmp.png")  # the suffix kept for the writer
    modes = {p.name: stat.S_IMODE(p.stat().st_mode) for p in tmp_path.iterdir()}
    assert set(modes.values()) == {umask_027}, modes


def test_temporary_never_opens_an_existing_name(tmp_path, monkeypatch):
    """Created with O_EXCL | O_NOFOLLOW: a link planted at the (random) name is an error, not a
    path to the file it points to."""
    target = tmp_path / "precious.txt"
    target.write_text(PRECIOUS)
    monkeypatch.setattr("secrets.token_hex", lambda n: "fixed")
    (tmp_path / ".x.fixed.tmp.json").symlink_to(target)
    with pytest.raises(FileExistsError):
        temporary(tmp_path / "x.json")
    assert target.read_text() == PRECIOUS


@pytest.mark.parametrize("kind", ["symlink", "dangling symlink", "hard link", "fifo", "directory"])
def test_a_lock_path_that_is_not_a_plain_file_is_refused(tmp_path, kind):
    target = tmp_path / "precious.txt"
    target.write_text(PRECIOUS)
    lock = tmp_path / "out" / ".lock"
    lock.parent.mkdir()
    {"symlink": lambda: lock.symlink_to(target), "dangling symlink": lambda: lock.symlink_to(tmp_path / "nowhere"),
     "hard link": lambda: os.link(target, lock), "fifo": lambda: os.mkfifo(lock), "directory": lock.mkdir}[kind]()
    with pytest.raises(InputError) as e:
        open_lock(lock)
    message = str(e.value)
    assert message.startswith(f"{lock}: the lock file ") and message.endswith("; remove it"), message
    assert ("symbolic link" in message) == ("symlink" in kind)
    assert target.read_text() == PRECIOUS and not (tmp_path / "nowhere").exists()
    with pytest.raises(InputError):
        FolderLock(lock.parent, "static").__enter__()
    assert target.read_text() == PRECIOUS


def test_a_second_writer_is_refused_naming_the_folder_and_the_holder(tmp_path):
    with FolderLock(tmp_path, "static") as lock:
        held = json.loads((tmp_path / ".lock").read_text())
        assert held["command"] == "static" and held["pid"] == os.getpid() and lock.stale is None
        with pytest.raises(InputError) as e:
            FolderLock(tmp_path, "montecarlo").__enter__()
        assert str(e.value) == (f"{tmp_path} is being written by another tdcr-warp static (pid {os.getpid()} on "
                                f"{held['host']}, started {held['started']}); wait for it to end or choose another "
                                "--out")
    assert not (tmp_path / ".lock").exists()  # removed when the writer ends
    with FolderLock(tmp_path, "simulate"):  # free again
        pass


def test_a_dead_writers_lock_is_taken_over(tmp_path):
    (tmp_path / ".lock").write_text(json.dumps({"command": "static", "pid": 999999999, "host": "h", "started": "t"}))
    with FolderLock(tmp_path, "static") as lock:
        assert lock.stale["pid"] == 999999999
        assert json.loads((tmp_path / ".lock").read_text())["pid"] == os.getpid()
