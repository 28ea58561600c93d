"""Windows and other non-POSIX systems: every module imports, and record sim -> playback -> evaluate run, in a
process where the POSIX-only modules and calls are absent (fcntl, resource, pwd, grp, termios, SIGALRM, pread,
statvfs, O_DIRECTORY, fork, killpg, mkfifo)."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest
from conftest import DEADLINE_S

# Runs first in the child: the POSIX-only names go before anything of phonepose loads.
NO_POSIX = textwrap.dedent("""
    import importlib.abc, os, signal, sys
    BLOCKED = {"fcntl", "resource", "pwd", "grp", "termios", "tty", "pty"}
    class _Blocker(importlib.abc.MetaPathFinder):
        # refuses the POSIX-only modules to phonepose's own imports; a third-party library's platform backend
        # (psutil's Linux one) is what that library would not load on Windows anyway
        def find_spec(self, name, path=None, target=None):
            if name.split(".")[0] not in BLOCKED:
                return None
            frame = sys._getframe(1)
            while frame is not None and frame.f_code.co_filename.startswith("<frozen"):
                frame = frame.f_back
            if frame is not None and frame.f_globals.get("__name__", "").startswith("phonepose"):
                raise ModuleNotFoundError(f"No module named {name!r}", name=name)
            return None
    for name in BLOCKED:
        sys.modules.pop(name, None)
    sys.meta_path.insert(0, _Blocker())
    for name in ("SIGALRM", "SIGKILL", "SIGHUP", "SIGPIPE", "SIGUSR1", "SIGUSR2", "SIGCHLD", "SIGQUIT",
                 "setitimer", "alarm", "ITIMER_REAL", "pthread_kill", "pthread_sigmask", "siginterrupt"):
        if hasattr(signal, name):
            delattr(signal, name)
    for name in ("pread", "pwrite", "statvfs", "O_DIRECTORY", "O_NOFOLLOW", "O_CLOEXEC", "O_NONBLOCK", "fork",
                 "forkpty", "killpg", "setsid", "getpgid", "setpgrp", "mkfifo", "mknod", "geteuid", "getuid", "sync", "fchmod",
                 "posix_fadvise", "sched_getaffinity", "getloadavg", "ST_RDONLY"):
        if hasattr(os, name):
            delattr(os, name)
""")


def _run(code: str, tmp_path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", NO_POSIX + textwrap.dedent(code)], cwd=tmp_path,
                          capture_output=True, text=True, timeout=DEADLINE_S * 5)


def test_the_simulated_process_lacks_what_it_should(tmp_path):
    """The harness itself: fcntl and SIGALRM are gone in the child, so the tests below can fail."""
    r = _run("""
        import os, signal
        try:
            exec("import fcntl", {"__name__": "phonepose.probe"})   # as a phonepose module imports it
        except ModuleNotFoundError:
            print("no fcntl")
        print(hasattr(signal, "SIGALRM"), hasattr(os, "pread"))
    """, tmp_path)
    assert r.returncode == 0, r.stderr
    assert r.stdout.splitlines() == ["no fcntl", "False False"]


def test_every_module_imports_without_posix(tmp_path):
    r = _run("""
        import pkgutil, importlib, phonepose
        names = [m.name for m in pkgutil.walk_packages(phonepose.__path__, "phonepose.") if m.name != "phonepose.__main__"]
        failed = []
        for name in names:
            try:
                importlib.import_module(name)
            except Exception as exc:
                failed.append(f"{name}: {type(exc).__name__}: {exc}")
        print(len(names))
        print("\\n".join(failed))
    """, tmp_path)
    assert r.returncode == 0, r.stderr
    count, *failed = r.stdout.splitlines()
    assert int(count) > 60
    assert [f for f in failed if f] == []


@pytest.mark.long
def test_record_playback_evaluate_without_posix(tmp_path):
    """The demo's path through the CLI's own entry point: a session, its playback folder, an evaluation, and a
    cut copy of the session recovered."""
    r = _run("""
        import os
        from phonepose.cli import main
        def run(*args):
            try:
                main(list(args))
            except SystemExit as exc:
                if exc.code:
                    raise
        run("record", "sim", "-q", "--scenario", "exp2", "--path", "TRI2", "--out", "s.mcap")
        run("playback", "-q", "s.mcap", "-t", "T4", "-t", "T8", "--out", "pb")
        run("evaluate", "--gt", "pb/groundtruth.tum", "--est", "pb/trajectories/T8.tum")
        with open("s.mcap", "rb") as f:
            head = f.read(os.path.getsize("s.mcap") * 2 // 3)
        with open("cut.mcap", "wb") as f:
            f.write(head)
        run("recover", "cut.mcap", "--out", "fixed.mcap")
        run("info", "fixed.mcap")
        print("ALL DONE")
    """, tmp_path)
    assert r.returncode == 0, r.stderr[-3000:]
    assert r.stdout.rstrip().endswith("ALL DONE")
    assert (tmp_path / "pb" / "metrics.json").is_file() and (tmp_path / "pb" / "trajectories" / "T8.tum").is_file()
