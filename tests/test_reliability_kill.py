"""Interrupted recordings: SIGKILL at random moments loses at most ~1 s; SIGINT/SIGTERM leave a complete file.

The simulator is deterministic (same seed, same bytes), so a killed recording is compared with
a complete recording of the same seed: what ``recover`` gets back must be exactly the first N
messages the complete file holds, and the gap to what the recorder had handed to its writer
when it died must be at most the writer's flush interval (1 s of log time).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import numpy as np
import pyarrow.parquet as pq
import pytest
from conftest import DEADLINE_S, wait_until
from mcap.reader import make_reader
from test_reliability_data import mounted_tmpfs

from phonepose.errors import DamagedFileError
from phonepose.session import SessionReader
from phonepose.session.recover import salvage

pytestmark = pytest.mark.slow

SCENARIO = ["--scenario", "exp2", "--path", "TRI1", "--trial", "1", "--seed", "3"]
PROGRESS_EVERY_S = 0.1   # the recorder reports progress about every 0.1 s of session time

# The child reports (after each write) how far it has recorded, so the parent knows what the
# writer had been handed when the kill landed: at least the last report, less than 0.1 s more.
CHILD = """
import sys
from phonepose.record.sim import record_sim
def progress(done_ns, total_ns):
    print(done_ns, flush=True)
record_sim(sys.argv[1], scenario="exp2", path="TRI1", trial=1, seed=3, progress=progress)
"""


def _file_order(path) -> list[tuple]:
    with open(path, "rb") as f:
        return [(c.topic, m.log_time, m.sequence, m.data)
                for _, c, m in make_reader(f).iter_messages(log_time_order=False)]


@pytest.fixture(scope="module")
def complete(tmp_path_factory):
    out = tmp_path_factory.mktemp("kill") / "complete.mcap"
    r = subprocess.run([sys.executable, "-m", "phonepose", "record", "sim", *SCENARIO, "--out", str(out), "-q"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    with SessionReader(out) as reader:
        start = reader.summary().start_ns
    return out, _file_order(out), start


def test_sigkill_at_random_moments_loses_at_most_a_second(complete, tmp_path):
    path, full, start = complete
    end_s = (max(m[1] for m in full) - start) / 1e9
    rng = np.random.default_rng(11)
    targets = sorted(float(x) for x in rng.uniform(1.5, end_s - 1.0, 3))
    results = []
    for i, target in enumerate(targets):
        out = tmp_path / f"killed{i}.mcap"
        child = subprocess.Popen([sys.executable, "-c", CHILD, str(out)], stdout=subprocess.PIPE, text=True)
        reported = 0
        for line in child.stdout:
            reported = max(reported, int(line))
            if reported / 1e9 >= target:
                child.send_signal(signal.SIGKILL)
                break
        reported = max([reported] + [int(x) for x in child.stdout.read().split()])  # written before death
        child.wait(timeout=DEADLINE_S)
        assert child.returncode == -signal.SIGKILL
        with pytest.raises(DamagedFileError):
            SessionReader(out)       # no summary: the file needs recover
        fixed = tmp_path / f"fixed{i}.mcap"
        report = salvage(out, fixed)
        got = _file_order(fixed)
        assert got == full[: len(got)]                     # exactly the first N messages, byte for byte
        recovered_s = (max(m[1] for m in got) - start) / 1e9
        handed_max_s = reported / 1e9 + PROGRESS_EVERY_S   # the writer had at most this much
        lost_s = handed_max_s - recovered_s
        results.append((round(target, 2), len(got), len(full), round(reported / 1e9 - recovered_s, 3),
                        round(lost_s, 3), report.chunks_skipped))
        assert lost_s <= 1.0 + PROGRESS_EVERY_S + 0.02, results[-1]
    print("SIGKILL (target s, recovered, complete, lost >= s, lost <= s, damaged chunks):", results)
    # the recovered recording is a normal session again: it plays back
    r = subprocess.run([sys.executable, "-m", "phonepose", "playback", str(fixed), "-q", "-t", "T1", "-t", "T7",
                        "--out", str(tmp_path / "playback")], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    ticks = int(r.stdout.split(" ticks in ")[0].split()[-1])
    assert ticks >= 20 * (recovered_s - 1.0)          # a tick every 50 ms over what was recovered
    assert (tmp_path / "playback" / "metrics.json").exists()


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_sigint_sigterm_leave_a_complete_file(complete, tmp_path, sig):
    path, full, start = complete
    out = tmp_path / "stopped.mcap"
    child = subprocess.Popen([sys.executable, "-m", "phonepose", "record", "sim", *SCENARIO, "--out", str(out), "-q"],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    wait_until(lambda: child.poll() is not None or (out.exists() and out.stat().st_size > 4_000_000),
               what="the recording to pass 4 MB")                 # a few seconds into the session
    assert child.poll() is None, "recording ended before the signal"
    child.send_signal(sig)
    stdout, stderr = child.communicate(timeout=DEADLINE_S)
    assert child.returncode == 0, stderr
    assert "interrupted, file is valid" in stdout
    with open(out, "rb") as f:
        summary = make_reader(f).get_summary()               # summary and index exist
    assert summary is not None and summary.statistics.message_count > 0
    got = _file_order(out)
    assert summary.statistics.message_count == len(got)
    assert 0 < len(got) < len(full) and got == full[: len(got)]
    with SessionReader(out) as reader:
        assert reader.summary().message_count == len(got)


def test_disk_full_while_recording_is_one_line_and_the_file_recovers(tmp_path):
    """A real 2 MiB tmpfs (root with mount permission only; the ENOSPC double in test_reliability_session runs everywhere)."""
    with mounted_tmpfs(tmp_path / "mnt", "size=2m") as mnt:
        out = mnt / "s.mcap"
        r = subprocess.run([sys.executable, "-m", "phonepose", "record", "sim", *SCENARIO, "--out", str(out), "-q"],
                           capture_output=True, text=True, timeout=300)
        assert r.returncode == 6
        assert r.stderr.strip() == (f"phonepose: error: cannot write {out}: No space left on device "
                                    "(the file written so far stays readable; run `phonepose recover`)")
        report = salvage(out, tmp_path / "fixed.mcap")
        # at least the first flushed second of the recording (the writer flushes once per second of log time)
        assert report.chunks_recovered >= 1 and report.end_ns - report.start_ns >= 900_000_000 and report.messages > 300
        with SessionReader(tmp_path / "fixed.mcap") as reader:
            assert reader.summary().has("/display/camera/image")


# ----------------------------------------------------------------------------- a stopped batch stops its workers
def _session_members(sid: int) -> list[tuple[int, str]]:
    """(pid, command) of the live processes of session ``sid`` (zombies excluded)."""
    out = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat") as f:
                stat = f.read()
            with open(f"/proc/{entry}/cmdline", "rb") as f:
                cmd = f.read().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue
        fields = stat[stat.rindex(")") + 2:].split()
        if int(fields[3]) == sid and fields[0] != "Z":
            out.append((int(entry), cmd))
    return out


@pytest.fixture(scope="module")
def batch_sessions(tmp_path_factory):
    from phonepose.testing.playback_session import write_test_session

    d = tmp_path_factory.mktemp("batch")
    for i in range(4):
        write_test_session(d / f"s{i}.mcap", duration_s=30.0)
    return d


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGKILL], ids=["SIGTERM", "SIGKILL"])
def test_stopping_a_batch_stops_its_workers(batch_sessions, tmp_path, sig):
    """`kill -TERM` or `kill -9` of `phonepose batch`: its workers and multiprocessing's resource tracker are
    gone within seconds (PR_SET_PDEATHSIG; before: over a minute, holding the caller's stdout open); SIGTERM
    also writes the finished rows and says so in one line."""
    out = tmp_path / "t.parquet"
    p = subprocess.Popen([sys.executable, "-m", "phonepose", "batch", *sorted(map(str, batch_sessions.glob("*.mcap"))),
                          "-t", "all", "-p", "rate_hz=20,40", "--workers", "2", "-q", "--out", str(out)],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True)
    def running() -> bool:                         # both workers up and a first unit written
        assert p.poll() is None, p.communicate()
        return len([c for _, c in _session_members(p.pid) if "spawn_main" in c]) >= 2 and out.exists()
    wait_until(running, what="the batch's two workers and its first unit", timeout=300)
    rows_before = pq.read_table(out).num_rows
    t0 = time.monotonic()
    p.send_signal(sig)
    wait_until(lambda: not _session_members(p.pid), what="every process of the batch to end", timeout=60)
    gone_s = time.monotonic() - t0
    stdout, stderr = p.communicate(timeout=60)     # the pipes close: nothing holds them any more
    assert not _session_members(p.pid), _session_members(p.pid)
    print(f"{sig.name}: every process of the batch gone {gone_s:.2f} s after the signal")
    assert gone_s < 20
    assert "leaked semaphore" not in stderr.decode()
    rows = pq.read_table(out).num_rows
    assert rows >= rows_before > 0
    if sig == signal.SIGTERM:
        assert p.returncode == 143
        assert stderr.decode().strip().splitlines()[-1] == (
            f"phonepose: error: terminated (SIGTERM): {rows} finished rows are in {out}; the next run with the same "
            "--out goes on from there")
