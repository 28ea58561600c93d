"""What the process starts with, checked before any work: its arguments, its standard streams, its limits;
and the one line for a failure of its resources (memory, open files, the OS) that no module turned into a
:class:`~phonepose.errors.PhoneposeError`. Used by ``phonepose.cli.main`` (docs/reliability.md, "The
environment a command runs in")."""

from __future__ import annotations

import errno
import os
import sys

try:
    import resource
except ImportError:   # Windows: no rlimits, the C runtime's own limits apply
    resource = None  # type: ignore[assignment]

from phonepose.errors import ConfigError, OutputError, PhoneposeError

# What a command needs of open files at the least (a playback with --rerun: rerun's runtime aborted the process
# below 20), and what is asked for when the soft limit (`ulimit -Sn`) is lower and the hard limit allows it.
MIN_OPEN_FILES = 64
WANTED_OPEN_FILES = 1024


def check_before_any_work(args: list[str]) -> None:
    """Standard streams open, enough file descriptors, every argument readable text."""
    standard_streams()
    ensure_open_files()
    check_arguments(args)


def check_arguments(args: list[str]) -> None:
    """Every argument is UTF-8 text. A file name in another encoding reaches Python with its bytes escaped
    (PEP 383), and the libraries the commands hand paths to cannot take it: OpenCV crashes (SIGSEGV), rerun,
    rich and the JSON outputs raise; one line here instead, before any work."""
    for arg in args:
        try:
            arg.encode("utf-8")
        except UnicodeEncodeError:
            raw = os.fsencode(arg)
            shown = raw.decode("utf-8", "backslashreplace")
            if _is_utf8(raw):   # UTF-8 after all, read by a Python whose locale is ASCII (LC_ALL=C PYTHONUTF8=0)
                raise ConfigError(f"the argument '{shown}' cannot be read in this locale (arguments and file names "
                                  f"are read as {sys.getfilesystemencoding()}): run phonepose in a UTF-8 locale "
                                  f"(LC_ALL=C.UTF-8) or with PYTHONUTF8=1") from None
            raise ConfigError(f"the argument '{shown}' is not UTF-8 text (a file name in another encoding?): "
                              f"rename the file with a UTF-8 name") from None


def _is_utf8(raw: bytes) -> bool:
    try:
        raw.decode("utf-8")
    except UnicodeDecodeError:
        return False
    return True


def standard_streams() -> None:
    """Standard input, output and error open before any work. A descriptor the caller closed (``>&-``) gets
    /dev/null, so that no file phonepose opens becomes descriptor 1 or 2 (what a library writes there would land
    in an output); a closed standard output is refused, since the report would be lost while exit 0 said all
    is well."""
    closed = []
    for fd, name in ((0, "stdin"), (1, "stdout"), (2, "stderr")):
        if getattr(sys, name) is None:
            closed.append(name)
            try:
                os.fstat(fd)
            except OSError:
                null = os.open(os.devnull, os.O_RDWR)
                if null != fd:
                    os.dup2(null, fd)
                    os.close(null)
    if "stdout" in closed:
        raise OutputError("standard output is closed (>&-): the report would be lost; send it to a file, or to "
                          "/dev/null to discard it")


def ensure_open_files() -> None:
    """Enough file descriptors before any work: the soft limit raised to what is wanted when the hard limit allows,
    and one line below :data:`MIN_OPEN_FILES` (rerun's Rust runtime panicked with a page of backtrace, exit 134;
    other commands failed half-way with "Too many open files"). Nothing to check where the system has no rlimits."""
    if resource is None:
        return
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft != resource.RLIM_INFINITY and soft < WANTED_OPEN_FILES:
        wanted = WANTED_OPEN_FILES if hard == resource.RLIM_INFINITY else min(hard, WANTED_OPEN_FILES)
        if wanted > soft:
            resource.setrlimit(resource.RLIMIT_NOFILE, (wanted, hard))
            soft = wanted
    if soft != resource.RLIM_INFINITY and soft < MIN_OPEN_FILES:
        raise PhoneposeError(f"the limit on open files is {soft} (`ulimit -n`); phonepose needs at least "
                             f"{MIN_OPEN_FILES}: raise it (`ulimit -n 1024`)")


def failure_line(exc: BaseException) -> str | None:
    """The one line for the process running out of memory or open files, or for an OS failure no module turned
    into a PhoneposeError; None for anything else (a bug in phonepose)."""
    if _out_of_memory(exc):
        return f"out of memory ({type(exc).__name__}: {' '.join(str(exc).split())[:200]}): the command needs " \
               f"{_memory_limit()}"
    if not isinstance(exc, OSError):
        return None
    where = f"{exc.filename}: " if exc.filename else ""
    if exc.errno in (errno.EMFILE, errno.ENFILE):
        if resource is None:
            return f"{where}too many open files: close other programs"
        soft = resource.getrlimit(resource.RLIMIT_NOFILE)[0]
        return f"{where}too many open files (the limit, `ulimit -n`, is {soft}): raise it"
    return f"{where}{exc.strerror or exc}"


def _out_of_memory(exc: BaseException) -> bool:
    """A MemoryError, or a library that could not be loaded for want of memory (`ulimit -v`)."""
    return isinstance(exc, MemoryError) or (isinstance(exc, ImportError) and any(
        words in str(exc) for words in ("failed to map segment", "cannot allocate memory", "Cannot allocate memory")))


def _memory_limit() -> str:
    if resource is None:
        return "free memory or a larger page file"
    soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    if soft == resource.RLIM_INFINITY:
        return "free memory or a larger swap"
    return f"a larger limit than the {soft / 2**30:.2g} GiB of `ulimit -v`"
