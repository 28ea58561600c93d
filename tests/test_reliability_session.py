"""Reliability of the session layer: disk full while writing, damaged files on reading, bad paths.

Disk full is simulated with a file object whose write() raises ENOSPC after N bytes (and, where
the test runs as root and may mount, with a real 1 MiB tmpfs).
"""

from __future__ import annotations

import errno
import os
import subprocess
import sys

import pytest
from test_reliability_data import mounted_tmpfs, read_keys, session_messages, write_session

from phonepose.errors import DamagedFileError, InputFileError, OutputError
from phonepose.session import SessionReader, SessionWriter
from phonepose.session.recover import salvage


class FullDisk:
    """A file that accepts ``limit`` bytes, writes what fits of the next write, then raises ENOSPC.

    (A plain object, not io.RawIOBase: mcap's Writer would wrap that in its own BufferedWriter.)
    """

    def __init__(self, path, limit: int):
        self._f = open(path, "wb")
        self.name = str(path)
        self.limit = limit
        self.n = 0

    def write(self, b) -> int:
        b = bytes(b)
        room = self.limit - self.n
        if len(b) > room:
            self._f.write(b[:max(room, 0)])
            self.n += max(room, 0)
            raise OSError(errno.ENOSPC, "No space left on device")
        self._f.write(b)
        self.n += len(b)
        return len(b)

    def flush(self) -> None:
        self._f.flush()

    def tell(self) -> int:
        return self.n

    def close(self) -> None:
        self._f.close()


@pytest.fixture(scope="module")
def messages():
    return session_messages(6.0)


@pytest.mark.parametrize("limit", [1_500_000, 3_000_000, 5_500_000])
def test_disk_full_is_one_clean_error_and_the_file_so_far_recovers(tmp_path, messages, limit):
    path = tmp_path / "s.mcap"
    disk = FullDisk(path, limit)
    written = 0
    with pytest.raises(OutputError) as err:
        with SessionWriter(disk) as w:
            for topic, msg, t in messages:
                w.write(topic, msg, t)
                written = t
    disk.close()
    msg = str(err.value)
    assert "No space left on device" in msg and "recover" in msg and "\n" not in msg
    assert err.value.exit_code == 6
    assert path.stat().st_size == limit  # everything that fitted is on disk
    r = salvage(path, tmp_path / "fixed.mcap")
    got = read_keys(tmp_path / "fixed.mcap")
    assert r.messages == len(got) > 0
    # at most the chunk being written (<= 1 s + one message) is missing at the end
    t_last = max(k[1] for k in got)
    assert (written - t_last) / 1e9 <= 1.0 + 2 / 400
    # and what came back is a prefix of what was written, byte for byte
    expected = {(topic, t) for topic, _, t in messages if t <= t_last}
    assert {(k[0], k[1]) for k in got} == expected


def test_disk_full_during_finish_is_an_output_error(tmp_path, messages):
    """All messages fit, the summary does not: OutputError, and every chunk recovers."""
    path = tmp_path / "s.mcap"
    probe = tmp_path / "probe.mcap"
    with SessionWriter(probe) as w:
        for topic, msg, t in messages:
            w.write(topic, msg, t)
    full = probe.stat().st_size
    disk = FullDisk(path, full - 2000)  # the summary section is larger than 2 KB
    w = SessionWriter(disk)
    for topic, msg, t in messages:
        w.write(topic, msg, t)
    with pytest.raises(OutputError, match="cannot finish .*No space left on device"):
        w.finish()
    disk.close()
    r = salvage(path, tmp_path / "fixed.mcap")
    assert r.messages == len(messages) and r.chunks_skipped == 0


def test_disk_full_on_a_real_tmpfs(tmp_path, messages):
    with mounted_tmpfs(tmp_path / "mnt", "size=1m") as mnt:
        with pytest.raises(OutputError, match="No space left on device"):
            with SessionWriter(mnt / "s.mcap") as w:
                for topic, msg, t in messages:
                    w.write(topic, msg, t)
        r = salvage(mnt / "s.mcap", tmp_path / "fixed.mcap")
        assert r.messages >= 500  # the first ~1 MiB chunk: ~1 s of data


def test_writer_output_dir_not_writable(tmp_path):
    with pytest.raises(OutputError, match="cannot write .*No such file or directory"):
        SessionWriter(tmp_path / "missing-dir" / "s.mcap")
    (tmp_path / "a-file").write_text("x")
    with pytest.raises(OutputError, match="cannot write .*Not a directory"):
        SessionWriter(tmp_path / "a-file" / "s.mcap")


def test_reader_on_damaged_files_points_to_recover(tmp_path):
    path = tmp_path / "s.mcap"
    write_session(path, 3.0)
    data = path.read_bytes()
    # truncated: no summary
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(DamagedFileError, match=r"phonepose recover .*cut.mcap"):
        SessionReader(cut)
    # corrupt chunk in a finished file: the summary opens, reading the messages fails cleanly
    bad = tmp_path / "bad.mcap"
    b = bytearray(data)
    for k in range(200):
        b[len(b) // 3 + k * 7] ^= 0xFF
    bad.write_bytes(bytes(b))
    with SessionReader(bad) as r:
        assert r.summary().message_count == len(read_keys(path))
        with pytest.raises(DamagedFileError, match=r"damaged MCAP file: the chunk at byte \d+ \(log time "
                                                   r"\d+\.\d\d-\d+\.\d\d s\) (fails its CRC check|does not decompress); "
                                                   "run `phonepose recover"):
            for _ in r.messages():
                pass


@pytest.mark.parametrize("make,exc,text", [
    (lambda p: None, InputFileError, "no such file"),
    (lambda p: p.mkdir(), InputFileError, "is a directory"),
    (lambda p: p.write_bytes(b""), InputFileError, "empty file"),
    (lambda p: p.write_bytes(b"PK\x03\x04 zip, not mcap"), InputFileError, "not an MCAP file"),
    (lambda p: p.write_bytes(b"\x89MCAP0\r\n"), DamagedFileError, "recover"),
])
def test_reader_bad_files(tmp_path, make, exc, text):
    p = tmp_path / "x.mcap"
    make(p)
    with pytest.raises(exc, match=text):
        SessionReader(p)


def run(*args):
    return subprocess.run([sys.executable, "-m", "phonepose", *args], capture_output=True, text=True)


def test_info_on_unreadable_file_is_one_line(tmp_path):
    if os.geteuid() == 0:
        # root reads everything: use a path whose parent is a file instead (ENOTDIR)
        (tmp_path / "f").write_text("x")
        target = tmp_path / "f" / "s.mcap"
        r = run("info", str(target))
        assert r.returncode == 2 and "no such file" in r.stderr
    else:
        p = tmp_path / "s.mcap"
        p.write_bytes(b"\x89MCAP0\r\n")
        p.chmod(0)
        r = run("info", str(p))
        assert r.returncode == 2 and "cannot read" in r.stderr
    assert r.stderr.count("\n") == 1 and "Traceback" not in r.stderr


def test_a_session_cut_while_it_is_read_says_so_not_damaged(tmp_path):
    """A session another program still copies, or cuts, while playback reads it: the chunks past the new end
    were "damaged MCAP file ...; run `phonepose recover`" (exit 3), which sends the user to repair a file that
    is only being written. The line says the file changed; with the file unchanged, damage is damage."""
    path = tmp_path / "s.mcap"
    write_session(path, 6.0)
    size = path.stat().st_size
    with SessionReader(path) as reader:
        messages = reader.messages()
        next(messages)
        os.truncate(path, size // 2)
        with pytest.raises(InputFileError) as e:
            for _ in messages:
                pass
    assert str(e.value) == (f"{path}: changed while it was read ({size} bytes, now {size // 2}): another program "
                            f"is writing or cutting it; run phonepose again when it is done")
    with pytest.raises(DamagedFileError, match="it ends without its footer"):   # cut before it is opened: damaged
        SessionReader(path)
