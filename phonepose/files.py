"""Every file a command reads and every output it writes, by one rule (docs/reliability.md, "Outputs").

Inputs are checked before the first side effect (:func:`check_input`): an existing, readable,
regular file. A FIFO, socket or device is refused at once (reading one can wait forever).

Outputs are planned, checked, written and committed by an :class:`OutputPlan`::

    plan = OutputPlan(inputs=[session])
    out = plan.dir(out_dir, "out")
    rrd = plan.file(rerun_path, "rerun", suffixes=(".rrd",), what="a Rerun recording")
    with plan:                   # every check, then the temporaries are created and locked
        work(out.tmp, rrd.tmp)   # write into the temporaries
    # leaving the block without an exception renames each into place; with one, removes them

The rule, the same in every command:

1. **Checked before any work.** The folder an output goes in must exist (it is never created);
   an output is never an input (same path, a symlink to it, a hard link of it), an output folder
   never holds an input, and two outputs of one command are never the same file; the name's
   extension is the format written; an existing output is a regular file (or a folder, for a
   folder output): a device, FIFO or socket is refused.
2. **Written under a temporary name this module owns**, beside the target
   (``.<name>.<pid>-<random>.phonepose-tmp``), locked while written (``flock``), and renamed into
   place only when complete. A failed, interrupted or killed command never leaves a partial
   output under the user's name, and an earlier output stays as it was until the new one
   replaces it whole (outputs are put in place with Ctrl-C and SIGTERM held). A killed command's
   temporaries are removed by the next command that writes in the same folder
   (:func:`clear_killed_temporaries`); while one command writes an output, a second one stops with one line. An
   output rewritten while the command runs (a batch's table) puts each complete version in place
   the same way (:meth:`OutputFile.checkpoint`). An error from inside names the user's paths, never
   a temporary's.
3. **Replacing.** A session (``record``, ``recover``) is never replaced without ``--force``: a
   recording cannot be made again. A new recording (``in_place``) is the one exception to rule 2:
   it is written under its final name, created exclusively, because what a killed recorder leaves
   there is the user's data (``phonepose recover`` reads it); with ``--force`` over an existing
   file it goes to a temporary like any output, so the old file stays until the new one is done.
   Any other output file is replaced whole. An output folder is
   replaced whole when it is empty or an earlier phonepose output (its ``.phonepose-output``
   manifest lists every file and folder of that run, and nothing else is in it), so no file of an
   earlier run survives beside the new ones and no file of the user's is lost with them; a folder
   holding anything else is refused, and so is the current directory (when something arrives in it while the
   command works, the finished folder is kept beside it as NAME.new). A replaced output keeps its permissions.

Written by hand: no library does exclusive temporaries with stale-lock recovery and no-clobber
commits, and ``tempfile``'s names cannot be found again after a crash.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import errno

try:
    import fcntl
except ImportError:   # Windows: no advisory locks; a temporary whose process may live is never cleared
    fcntl = None  # type: ignore[assignment]
import hashlib
import json
import os
import re
import secrets
import shutil
import signal
import stat
import threading
from collections.abc import Iterable, Iterator, Sequence
from contextlib import contextmanager, suppress
from dataclasses import dataclass, field
from pathlib import Path

from phonepose.errors import RECOVER_HINT, ConfigError, InputFileError, OutputError, PhoneposeError

TMP_SUFFIX = ".phonepose-tmp"
MANIFEST = ".phonepose-output"
_MCAP_MAGIC = b"\x89MCAP0\r\n"     # (session.index.MCAP_MAGIC: this module imports nothing of the session's)


# What this process's plans did: a stop that finds no plan open and outputs committed lost no work (the CLI
# then exits 0); a stop that cannot unwind (a tracker step that never returns) removes the open plans' temporaries.
_open_plans: list[OutputPlan] = []
_committed: list[Path] = []


# open() flags that only some systems have: without them the call opens the same file, less strictly
_CLOEXEC = getattr(os, "O_CLOEXEC", 0) | getattr(os, "O_NOINHERIT", 0)
_NONBLOCK = getattr(os, "O_NONBLOCK", 0)
_DIRECTORY = getattr(os, "O_DIRECTORY", 0)


def _lock(fd: int, *, shared: bool = False, wait: bool = True) -> bool:
    """``flock`` ``fd``: True when held, False when another process holds it (only with ``wait=False``). Where
    the system has no ``flock`` nothing is locked and True is returned: liveness then comes from the pid in a
    temporary's name (:func:`_pid_alive`)."""
    if fcntl is None:
        return True
    op = (fcntl.LOCK_SH if shared else fcntl.LOCK_EX) | (0 if wait else fcntl.LOCK_NB)
    try:
        fcntl.flock(fd, op)
    except BlockingIOError:
        return False
    return True


def outputs_committed() -> tuple[Path, ...]:
    """The outputs this process has put in place (as the user named them), when no plan is open; else ()."""
    return () if _open_plans else tuple(_committed)


def forget_outputs() -> None:
    """Start the record of :func:`outputs_committed` afresh (a command run in the same process as others)."""
    _committed.clear()


def abort_open_plans() -> None:
    """Remove the temporaries of every open plan: for a stop that ends the process without unwinding."""
    for plan in list(_open_plans):
        plan.abort()


_HELD_SIGNALS = tuple(getattr(signal, name) for name in ("SIGINT", "SIGTERM") if hasattr(signal, name))


@contextmanager
def _signals_held() -> Iterator[None]:
    """Ctrl-C and SIGTERM wait while outputs are renamed into place or their temporaries removed: a stop lands
    before the first rename or after the last, so the outputs are all earlier ones or all new ones, none left
    half removed. The signal is delivered to the handler it was for when the block ends. (Python's handlers run in
    the main thread only; elsewhere nothing is held.)"""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    pending: list[int] = []
    old = {sig: signal.signal(sig, lambda signum, _frame: pending.append(signum)) for sig in _HELD_SIGNALS}
    try:
        yield
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler)
        if pending:
            handler = old[pending[0]]
            if callable(handler):
                handler(pending[0], None)
            elif handler == signal.SIG_DFL:
                signal.raise_signal(pending[0])


# ----------------------------------------------------------------------------- inputs
def check_input(path: str | os.PathLike, what: str = "file") -> Path:
    """``path`` as a Path if it is an existing, readable, regular file; else InputFileError (one line)."""
    p = Path(path)
    try:
        st = os.stat(p)
    except FileNotFoundError:
        raise InputFileError(f"{p}: no such file") from None
    except NotADirectoryError:
        raise InputFileError(f"{p}: no such file (a part of the path is not a directory)") from None
    except OSError as exc:
        raise InputFileError(f"{p}: cannot read ({exc.strerror or exc})") from None
    if stat.S_ISDIR(st.st_mode):
        raise InputFileError(f"{p}: is a directory, not {_a(what)}")
    if not stat.S_ISREG(st.st_mode):
        raise InputFileError(f"{p}: not a regular file (a FIFO, socket or device): give {_a(what)}")
    if not os.access(p, os.R_OK):
        raise InputFileError(f"{p}: cannot read (Permission denied)")
    return p


# The largest text input read whole (a trajectory, an in-view file): 1 GiB of TUM lines (~80 bytes each) is
# ~13 million poses, 37 hours at 100 Hz; a larger "trajectory" is the wrong file (a sparse 10 GB one ran the
# reader out of memory). Smaller kinds pass their own limit (a TOML config, a calibration file).
MAX_TEXT_INPUT_BYTES = 1 << 30
_TEXT_CHUNK_BYTES = 1 << 20
_UTF16_BOMS = (b"\xff\xfe", b"\xfe\xff")


def read_text_input(path: str | os.PathLike, what: str = "text file", *, limit: int = MAX_TEXT_INPUT_BYTES,
                    note: str = "") -> str:
    """The text of a text input, checked as :func:`check_input` and read in chunks: more than ``limit`` bytes
    (``note`` says why that is enough) or a NUL byte (binary data) is refused as soon as it is seen, never read
    whole first; a UTF-8 byte-order mark is dropped, and a file that starts with a UTF-16 one is UTF-16 text.
    Otherwise InputFileError, one line naming the file."""
    p = check_input(path, what)
    unit, scale = next((u, s) for u, s in (("GiB", 1 << 30), ("MiB", 1 << 20), ("KiB", 1 << 10), ("bytes", 1))
                       if limit >= s or s == 1)
    limit_text = f"{limit / scale:.4g} {unit}"
    too_large = InputFileError(f"{p}: larger than {limit_text}, the most phonepose reads as {_a(what)}"
                               f"{f' ({note})' if note else ''}: check that it is the right file")
    data = bytearray()
    try:
        with open(p, "rb") as f:
            if os.fstat(f.fileno()).st_size > limit:
                raise too_large
            utf16 = f.read(2) in _UTF16_BOMS   # Excel's "Unicode text", Windows PowerShell's `>`: UTF-16 with a BOM
            f.seek(0)
            while chunk := f.read(min(_TEXT_CHUNK_BYTES, limit + 1 - len(data))):
                nul = -1 if utf16 else chunk.find(b"\0")     # (UTF-16 text is half NUL bytes: checked decoded)
                if nul >= 0:
                    raise InputFileError(f"{p}: not {_a(what)} (binary data: a NUL byte at byte {len(data) + nul})")
                data += chunk
                if len(data) > limit:     # it grew since it was measured
                    raise too_large
    except OSError as exc:
        raise InputFileError(f"{p}: cannot read ({exc.strerror or exc})") from None
    if utf16:
        try:
            text = data.decode("utf-16")
        except UnicodeDecodeError as exc:
            raise InputFileError(f"{p}: not {_a(what)} (not UTF-16 text after its byte-order mark: byte "
                                 f"{exc.start})") from None
        if "\0" in text:
            raise InputFileError(f"{p}: not {_a(what)} (binary data: a NUL character at character {text.index(chr(0))})")
        return text
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise InputFileError(f"{p}: not {_a(what)} (not UTF-8 text: byte {exc.start})") from None


def being_written(path: str | os.PathLike) -> bool:
    """Does another phonepose hold ``path`` open to write it (a recording in progress: the output rule's
    ``flock``)? Asked without blocking; a file that cannot be opened is not."""
    try:
        fd = os.open(path, os.O_RDONLY | _CLOEXEC | _NONBLOCK)
    except OSError:
        return False
    try:
        return not _lock(fd, shared=True, wait=False)
    except OSError:
        return False
    finally:
        os.close(fd)    # (closing our descriptor releases our lock only, never the writer's)


# Any output's temporary or set-aside earlier output: "." STEM "." PID "-" 8 hex digits SUFFIX
_LEFT_BY_A_RUN = re.compile(rf"\.(?P<stem>.+)\.(?P<pid>\d+)-[0-9a-f]{{8}}(?P<kind>{re.escape(TMP_SUFFIX)}|\.phonepose-old)")


def _pid_alive(pid: int) -> bool:
    """Is a process ``pid`` running (another user's counts; where it cannot be asked, every pid is)?"""
    if os.name == "nt":      # os.kill there ends the process: the process's exit code is asked instead
        return _windows_pid_alive(pid)
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:
        return True
    return True


def _windows_pid_alive(pid: int) -> bool:
    kernel32 = ctypes.WinDLL("kernel32", use_last_error=True)  # type: ignore[attr-defined]
    handle = kernel32.OpenProcess(0x1000, False, pid)   # PROCESS_QUERY_LIMITED_INFORMATION
    if not handle:
        return ctypes.get_last_error() == 5  # type: ignore[attr-defined]  # ERROR_ACCESS_DENIED: running
    try:
        code = ctypes.c_ulong()
        return bool(kernel32.GetExitCodeProcess(handle, ctypes.byref(code))) and code.value == 259   # STILL_ACTIVE
    finally:
        kernel32.CloseHandle(handle)


def killed_runs_left(folder: str | os.PathLike) -> list[Path]:
    """What killed commands left in ``folder``: temporaries (and earlier outputs set aside while one was put in
    place) whose command is gone (its pid runs no process and nothing holds the lock)."""
    try:
        names = sorted(os.listdir(folder))
    except OSError:
        return []
    left = []
    for name in names:
        found = _LEFT_BY_A_RUN.fullmatch(name)
        if found is None or _pid_alive(int(found["pid"])):
            continue
        path = Path(folder) / name
        try:
            fd = os.open(path, os.O_RDONLY | _NONBLOCK)
        except OSError:
            continue
        try:
            if not _lock(fd, wait=False):
                continue       # held: a live command's (its pid seen through another namespace)
        except OSError:
            continue
        finally:
            os.close(fd)
        left.append(path)
    return left


def clear_killed_temporaries(folder: Path, inputs: Sequence[Path] = ()) -> None:
    """Remove what :func:`killed_runs_left` finds: every command that writes in a folder clears what killed ones
    left there, whichever output it was for. An earlier output set aside (killed between the two renames where the
    system has no atomic exchange) goes back under its name if nothing took that name, else it is removed."""
    for path in killed_runs_left(folder):
        if any(_same_file(path, inp) for inp in inputs):
            continue   # never delete an input, whatever its name
        found = _LEFT_BY_A_RUN.fullmatch(path.name)
        assert found is not None
        if found["kind"] != TMP_SUFFIX and not os.path.lexists(folder / found["stem"]):
            if not _SHORTENED.fullmatch(found["stem"]):    # (a shortened name's output cannot be named: kept)
                with suppress(OSError):
                    os.rename(path, folder / found["stem"])
            continue
        _remove(path)


_SHORTENED = re.compile(r".*~[0-9a-f]{16}")    # a name _tmp_stem shortened


def _same_file(a: Path, b: Path) -> bool:
    """Same path after resolving symlinks, or the same inode (a hard link)."""
    try:
        if os.path.realpath(a) == os.path.realpath(b):
            return True
        return os.path.samefile(a, b)
    except OSError:
        return False


def _inside(child: Path, folder: Path) -> bool:
    c, f = os.path.realpath(child), os.path.realpath(folder)
    return c != f and os.path.commonpath([c, f]) == f


# ----------------------------------------------------------------------------- outputs
@dataclass
class _Output:
    path: Path
    parameter: str   # the keyword that gave the path ("out"), or a name to show as is
    tmp: Path | None = field(default=None, init=False)   # the temporary to write into (inside the plan's block)
    _fd: int | None = field(default=None, init=False, repr=False)

    @property
    def name(self) -> str:
        """The output's parameter in a message: a placeholder for a keyword (shown as the CLI's option there)."""
        return "{" + self.parameter + "}" if self.parameter.isidentifier() else self.parameter

    @property
    def keywords(self) -> tuple[str, ...]:
        return (self.parameter,) if self.parameter.isidentifier() else ()

    def fields(self, *also: str) -> dict:
        """An error's structured fields for this output (``also``: other keywords its message names)."""
        return dict(parameter=self.keywords[0] if self.keywords else None, value=self.path, also=also)

    @property
    def target(self) -> Path:
        """Where the output lands: through a symlink, the file or folder it points to (the link stays)."""
        return Path(os.path.realpath(self.path)) if os.path.islink(self.path) else Path(os.path.abspath(self.path))

    def _parent(self) -> Path:
        return self.target.parent

    def _check_parent(self) -> None:
        parent = self._parent()
        shown = self.path.parent if str(self.path.parent) not in ("", ".") or self.path.is_absolute() else Path(".")
        if os.path.islink(self.path) and not parent.is_dir():    # the link's target is what gets written
            raise OutputError(f"{self.name} {self.path}: a symlink to {self.target}, whose directory "
                              f"{'is not a directory' if os.path.lexists(parent) else 'does not exist'}", **self.fields())
        if not parent.is_dir():
            why = f"{shown} is not a directory" if os.path.lexists(parent) else f"directory {shown} does not exist"
            raise OutputError(f"{self.name} {self.path}: {why}", **self.fields())
        if not os.access(parent, os.W_OK | os.X_OK):
            try:
                read_only = hasattr(os, "statvfs") and bool(os.statvfs(parent).f_flag & os.ST_RDONLY)
            except OSError:
                read_only = False
            raise OutputError(f"{self.name} {self.path}: directory {shown} is "
                              f"{'on a read-only file system' if read_only else 'not writable'}", **self.fields())

    def _check_not_input(self, inputs: Sequence[Path]) -> None:
        for inp in inputs:
            if _same_file(self.path, inp):
                raise InputFileError(f"{self.name} {self.path} is the input {inp}: writing it would destroy the "
                                     f"input; choose another name", **self.fields())

    # -- temporaries
    def _tmp_name(self) -> Path:
        return _beside(self.target, TMP_SUFFIX)

    def _clear_stale(self, inputs: Sequence[Path]) -> None:
        """Remove the temporaries a killed command left in this output's folder (any output's); refuse if a live
        command holds one of this output's."""
        t = self.target
        clear_killed_temporaries(t.parent, inputs)
        ours = re.compile(rf"\.{re.escape(_tmp_stem(t))}\.(\d+)-[0-9a-f]{{8}}{re.escape(TMP_SUFFIX)}")
        try:
            names = sorted(os.listdir(t.parent))
        except OSError:
            names = []
        for name in names:
            found = ours.fullmatch(name)    # this output's only: not those of "run.v2" beside "run"
            if found is None:
                continue
            cand = t.parent / name
            if any(_same_file(cand, inp) for inp in inputs):
                continue   # never delete an input, whatever its name
            try:
                fd = os.open(cand, os.O_RDONLY)
            except OSError:
                continue
            try:
                if not _lock(fd, wait=False) or (fcntl is None and _pid_alive(int(found.group(1)))):
                    pid = found.group(1)
                    raise OutputError(f"{self.name} {self.path}: another phonepose (pid {pid}) is writing it; "
                                      f"wait for it to finish or choose another {self.name}", **self.fields()) from None
                _remove(cand)
            finally:
                os.close(fd)

    def _release(self) -> None:
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None

    def abort(self) -> None:
        if self.tmp is not None:
            if not getattr(self, "_direct", False) or _empty(self.tmp):
                _remove(self.tmp)   # a recording under its own name is kept: the writer finished it validly
            self.tmp = None
        self._release()


@dataclass
class OutputFile(_Output):
    suffixes: tuple[str, ...] = ()
    what: str = "this file"
    session: bool = False     # a recording: never replaced without force
    force: bool = False
    in_place: bool = False    # a new recording: written under its final name (see the module docstring)
    rewritten: bool = False   # committed by checkpoint() as the command goes (a batch's table)
    _direct: bool = field(default=False, init=False, repr=False)

    def check(self, inputs: Sequence[Path]) -> None:
        self._check_not_input(inputs)
        st = None
        if os.path.lexists(self.path) or os.path.lexists(self.target):
            try:
                st = os.stat(self.target)
            except OSError:
                st = None
            if st is not None and stat.S_ISDIR(st.st_mode):
                raise OutputError(f"{self.name} {self.path}: is a directory; {self.name} takes a file name", **self.fields())
            if st is not None and not stat.S_ISREG(st.st_mode):
                raise OutputError(f"{self.name} {self.path}: not a regular file (a device, FIFO or socket); "
                                  f"give a file name", **self.fields())
            if st is not None and being_written(self.target):   # a recording in progress: --force or not
                raise OutputError(f"{self.name} {self.path}: another phonepose is writing it (a recording in "
                                  f"progress); wait for it to finish or choose another {self.name}", **self.fields())
        if self.suffixes and self.path.suffix.lower() not in self.suffixes:
            raise ConfigError(f"{self.name} {self.path}: writes {self.what}; give a name ending in "
                              f"{_one_of(self.suffixes)}", **self.fields())
        if self.suffixes and os.path.islink(self.path) and self.target.suffix.lower() not in self.suffixes:
            # written through the link: the file replaced is its target, whose name is what the user reads
            raise ConfigError(f"{self.name} {self.path}: a symlink to {self.target}, which does not end in "
                              f"{_one_of(self.suffixes)}; give the file's own name", **self.fields())
        self._check_parent()
        if self.session and not self.force and st is not None:
            raise OutputError(f"{self.path} already exists: choose another {self.name}, or add {{force=True}} to "
                              f"replace it", **self.fields("force"))
        if not self.session and st is not None and _is_recording(self.target):
            what = f"points to {self.target}, " if os.path.islink(self.path) else "is "
            raise OutputError(f"{self.name} {self.path}: {what}a recording (MCAP), which only a recording "
                              f"replaces; choose another name", **self.fields())

    def begin(self, inputs: Sequence[Path]) -> Path:
        self._direct = self.in_place and not os.path.lexists(self.target)
        if self._direct:
            clear_killed_temporaries(self.target.parent, inputs)
        else:
            self._clear_stale(inputs)
        tmp = self.target if self._direct else self._tmp_name()
        try:
            self._fd = os.open(tmp, os.O_CREAT | os.O_EXCL | os.O_RDWR | _CLOEXEC, 0o666)
        except FileExistsError:
            raise OutputError(f"{self.path} already exists: choose another {self.name}, or add {{force=True}} to "
                              f"replace it", **self.fields("force")) from None
        except OSError as exc:
            raise OutputError(f"cannot write {self.path}: {exc.strerror or exc}") from None
        _lock(self._fd)
        self.tmp = tmp
        return tmp

    def checkpoint(self) -> Path:
        """Rename what the temporary holds into place now and go on with a fresh, locked temporary
        (returned, and in ``tmp``): for an output rewritten whole while the command runs (a batch's
        table). The new temporary is locked before the old one is renamed, so a second command finds
        the output locked for as long as this one runs."""
        tmp, fd, target = self.tmp, self._fd, self.target
        assert tmp is not None and fd is not None and not self._direct and not self.session
        new = self._tmp_name()
        try:
            new_fd = os.open(new, os.O_CREAT | os.O_EXCL | os.O_RDWR | _CLOEXEC, 0o666)
        except OSError as exc:
            raise OutputError(f"cannot write {self.path}: {exc.strerror or exc}") from None
        _lock(new_fd)
        with _signals_held():    # the version goes in and the temporaries are swapped, or neither
            return self._put_in_place(tmp, fd, target, new, new_fd)

    def _put_in_place(self, tmp: Path, fd: int, target: Path, new: Path, new_fd: int) -> Path:
        try:
            os.fsync(fd)
            if os.path.lexists(target) and not stat.S_ISREG(os.lstat(target).st_mode):
                raise OutputError(f"{self.name} {self.path}: not a regular file; not replaced", **self.fields())
            _keep_mode(tmp, target)
            os.rename(tmp, target)
            _fsync_dir(target.parent)
        except BaseException as exc:
            os.close(new_fd)
            _remove(new)
            if isinstance(exc, OSError):
                raise OutputError(f"cannot write {self.path}: {exc.strerror or exc}") from None
            raise
        os.close(fd)
        self.tmp, self._fd = new, new_fd
        return new

    def commit(self) -> None:
        tmp, target = self.tmp, self.target
        assert tmp is not None and self._fd is not None
        if self.rewritten:    # what it wrote is in place (checkpoint); the last temporary was not used
            self.abort()
            return
        if self._direct:
            try:
                os.fsync(self._fd)
            except OSError as exc:
                raise OutputError(f"cannot write {self.path}: {exc.strerror or exc} (the file written so far "
                                  f"stays readable; run `phonepose recover`)") from None
            finally:
                self.tmp = None
                self._release()
            return
        try:
            os.fsync(self._fd)     # the data of the inode, whoever wrote it (rerun, the MCAP writer)
            if self.session and not self.force:
                os.link(tmp, target)   # no-clobber: fails if the target appeared meanwhile
                os.unlink(tmp)
            else:
                if os.path.lexists(target) and not stat.S_ISREG(os.lstat(target).st_mode):
                    raise OutputError(f"{self.name} {self.path}: not a regular file; not replaced", **self.fields())
                if being_written(target):     # it may have begun since the check: a recording is never replaced
                    raise OutputError(f"{self.name} {self.path}: another phonepose began writing it (a recording "
                                      f"in progress); not replaced", **self.fields())
                _keep_mode(tmp, target)
                os.rename(tmp, target)
            _fsync_dir(target.parent)
        except FileExistsError:
            self.abort()
            raise OutputError(f"{self.path} already exists: choose another {self.name}, or add {{force=True}} to "
                              f"replace it", **self.fields("force")) from None
        except OSError as exc:
            self.abort()
            raise OutputError(f"cannot write {self.path}: {exc.strerror or exc}") from None
        self.tmp = None
        self._release()


@dataclass
class OutputDir(_Output):
    command: str = ""
    _written_in: Path | None = field(default=None, init=False, repr=False)   # the temporary, kept for final()

    def check(self, inputs: Sequence[Path]) -> None:
        target = self.target
        cwd = os.path.realpath(os.getcwd())
        if os.path.realpath(target) == cwd or _inside(Path(cwd), target):
            raise OutputError(f"{self.name} {self.path}: is the current directory (or holds it) and would be "
                              f"replaced whole; name a new folder", **self.fields())
        self._check_parent()
        for inp in inputs:
            if _inside(inp, target) or _same_file(inp, target):
                raise InputFileError(f"{self.name} {self.path}: holds the input {inp} and would be replaced "
                                     f"whole; choose another {self.name}", **self.fields())
        self._check_replaceable()

    def final(self, path: str | os.PathLike) -> Path:
        """Where ``path``, written inside the temporary, is once the folder is committed (as the user
        named it); also after the commit."""
        assert self._written_in is not None, "final() names a path of the plan's block"
        return self.path / Path(path).relative_to(self._written_in)

    def _check_replaceable(self) -> None:
        target = self.target
        if not os.path.lexists(target):
            return
        if not target.is_dir():
            raise OutputError(f"{self.name} {self.path}: exists and is not a directory", **self.fields())
        entries = os.listdir(target)
        if not entries:
            return
        if MANIFEST not in entries:
            raise OutputError(f"{self.name} {self.path}: holds files phonepose did not write; choose a new "
                              f"folder, or empty it", **self.fields())
        written = _listed_in_manifest(target / MANIFEST)
        if written is None:
            raise OutputError(f"{self.name} {self.path}: its {MANIFEST} does not list what phonepose wrote (an "
                              f"older phonepose, or edited), so files of yours in it cannot be told apart; choose a "
                              f"new folder, or empty it", **self.fields())
        foreign = sorted(_tree_entries(target) - written - {MANIFEST})
        if foreign:
            named = ", ".join(foreign[:3]) + (f" and {len(foreign) - 3} more" if len(foreign) > 3 else "")
            raise OutputError(f"{self.name} {self.path}: holds {named}, which phonepose did not write there; "
                              f"move {'it' if len(foreign) == 1 else 'them'} away, or choose a new folder", **self.fields())

    def _set_aside(self, tmp: Path) -> Path:
        """The finished folder under a new name beside the one it could not replace (a file of the user's arrived
        in that one while the command ran), so that the command's work is never removed with the temporary."""
        for n in range(1, 1000):
            name = f"{self.target.name}.new" + (f"{n}" if n > 1 else "")
            if not os.path.lexists(self.target.parent / name):
                os.rename(tmp, self.target.parent / name)
                self.tmp = None
                self._release()
                return self.path.parent / name
        raise OutputError(f"{self.name} {self.path}: no free name beside it to keep this run's output", **self.fields())

    def begin(self, inputs: Sequence[Path]) -> Path:
        self._clear_stale(inputs)
        tmp = self._tmp_name()
        try:
            os.mkdir(tmp)
            if fcntl is not None:   # a folder is opened only to lock it (Windows cannot open one)
                self._fd = os.open(tmp, os.O_RDONLY | _DIRECTORY | _CLOEXEC)
        except OSError as exc:
            raise OutputError(f"cannot write {self.path}: {exc.strerror or exc}") from None
        if self._fd is not None:
            _lock(self._fd)
        self.tmp = self._written_in = tmp
        return tmp

    def commit(self) -> None:
        tmp, target = self.tmp, self.target
        assert tmp is not None
        try:
            # every file and folder of this run, so that a later run replaces the folder only if nothing else
            # arrived in it (a recording saved there would be lost with the folder)
            files = sorted(_tree_entries(tmp))
            (tmp / MANIFEST).write_text(json.dumps({"written_by": "phonepose", "command": self.command,
                                                    "files": files}) + "\n")
            _fsync_tree(tmp)
            try:
                self._check_replaceable()   # again: nothing of the user's may have arrived meanwhile
            except OutputError as exc:
                raise OutputError(f"{exc} (this run's output is kept in {self._set_aside(tmp)})") from None
            _keep_mode(tmp, target)
            if os.path.lexists(target):
                old = _beside(target, ".phonepose-old")
                if _exchange(tmp, target):
                    old = tmp                    # tmp now holds the earlier output
                else:                            # no renameat2: two renames, the old kept until the new is in
                    os.rename(target, old)
                    os.rename(tmp, target)
                _fsync_dir(target.parent)
                _remove(old)
            else:
                os.rename(tmp, target)
                _fsync_dir(target.parent)
        except PhoneposeError:
            self.abort()
            raise
        except OSError as exc:
            self.abort()
            raise OutputError(f"cannot write {self.path}: {exc.strerror or exc}") from None
        self.tmp = None
        self._release()



class OutputPlan:
    """The outputs of one command: all checked before any work, written to temporaries, committed together."""

    def __init__(self, inputs: Iterable[str | os.PathLike] = ()):
        self.inputs = [Path(p) for p in inputs]
        self.outputs: list[OutputFile | OutputDir] = []
        self._open = False

    def file(self, path: str | os.PathLike, parameter: str, *, suffixes: Sequence[str] = (), what: str = "this file",
             session: bool = False, force: bool = False, in_place: bool = False,
             rewritten: bool = False) -> OutputFile:
        """A file output; ``session``: never replaced without ``force``; ``in_place``: a new recording;
        ``rewritten``: the command puts each complete version in place with ``checkpoint()``."""
        out = OutputFile(Path(path), parameter, suffixes=tuple(s.lower() for s in suffixes), what=what,
                         session=session or in_place, force=force, in_place=in_place, rewritten=rewritten)
        self.outputs.append(out)
        return out

    def dir(self, path: str | os.PathLike, parameter: str, *, command: str = "") -> OutputDir:
        out = OutputDir(Path(path), parameter, command=command)
        self.outputs.append(out)
        return out

    def check(self) -> None:
        """Every rule of the module docstring that can be checked before any work."""
        for out in self.outputs:
            out.check(self.inputs)
        for i, a in enumerate(self.outputs):
            for b in self.outputs[i + 1:]:
                if os.path.realpath(a.target) == os.path.realpath(b.target) or _same_file(a.path, b.path):
                    raise ConfigError(f"{a.name} and {b.name} name the same file {a.path}: give two names",
                                      **a.fields(*b.keywords))
                for x, y in ((a, b), (b, a)):
                    if isinstance(y, OutputDir) and _inside(x.target, y.target):
                        raise ConfigError(f"{x.name} {x.path} lies inside {y.name} {y.path}, which is replaced "
                                          f"whole: write it elsewhere", **x.fields(*y.keywords))

    def __enter__(self) -> OutputPlan:
        self.check()
        _open_plans.append(self)
        try:
            for out in self.outputs:
                out.begin(self.inputs)
        except BaseException:
            with _signals_held():
                self.abort()
                _open_plans.remove(self)
            raise
        self._open = True
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        with _signals_held():
            try:
                self._finish(exc_type, exc)
            finally:
                if self in _open_plans:
                    _open_plans.remove(self)

    def _finish(self, exc_type, exc) -> None:
        self._open = False
        if exc_type is not None:
            temporaries = [(o.tmp, o.path) for o in self.outputs if o.tmp is not None]
            kept = any(getattr(o, "_direct", False) and o.tmp is not None and not _empty(o.tmp) for o in self.outputs)
            self.abort()
            if isinstance(exc, PhoneposeError):
                message = _in_users_terms(str(exc), temporaries, kept)
                if message != str(exc):
                    raise type(exc)(message) from None
            return
        try:
            for out in self.outputs:
                out.commit()
                _committed.append(out.path)
        except BaseException:
            self.abort()
            raise

    def abort(self) -> None:
        for out in self.outputs:
            out.abort()



def check_output(path: str | os.PathLike, parameter: str, *, inputs: Iterable[str | os.PathLike] = (),
                 suffixes: Sequence[str] = (), what: str = "this file") -> None:
    """Rule 1 for one file output, now: a command that works minutes before it writes (a camera
    capture) fails before the work, not after. Writing it later checks again."""
    plan = OutputPlan(inputs)
    plan.file(path, parameter, suffixes=suffixes, what=what)
    plan.check()


def write_text_output(path: str | os.PathLike, text: str | bytes, parameter: str, *,
                      inputs: Iterable[str | os.PathLike] = (), suffixes: Sequence[str] = (),
                      what: str = "this file") -> Path:
    """One small output held in memory (a calibration YAML, a PNG, a JSON report) by the rule above;
    disk full is an error. ``text`` may be bytes."""
    plan = OutputPlan(inputs)
    out = plan.file(path, parameter, suffixes=suffixes, what=what)
    data = text.encode() if isinstance(text, str) else bytes(text)
    with plan:
        assert out.tmp is not None   # the plan's block made it
        try:
            with open(out.tmp, "wb") as f:
                f.write(data)
                f.flush()
                os.fsync(f.fileno())
        except OSError as exc:
            raise OutputError(f"cannot write {path}: {exc.strerror or exc}") from None
    return Path(path)


# ----------------------------------------------------------------------------- helpers
def _in_users_terms(message: str, temporaries: list[tuple[Path, Path]], kept: bool) -> str:
    """An error from inside a plan's block, naming the user's outputs instead of their temporaries; a
    recorder's "run `phonepose recover`" hint only where the file stays (a new recording, ``in_place``)."""
    for tmp, path in temporaries:
        message = message.replace(str(tmp), str(path))
    return message if kept else message.replace(RECOVER_HINT, "")


def _a(noun: str) -> str:
    word = noun.split()[0] if noun.split() else noun
    vowel = word[:1] in "AEFHILMNORSX" if word.isupper() else word[:1].lower() in "aeiou"   # an MCAP file
    return f"{'an' if vowel else 'a'} {noun}"


def _one_of(items: Sequence[str]) -> str:
    return items[0] if len(items) == 1 else f"{', '.join(items[:-1])} or {items[-1]}"


# A temporary's name beside its output's: "." NAME "." PID "-" 8 hex digits SUFFIX (a pid has at most 7 digits)
_TMP_NAME_EXTRA = len(f"..{2**22}-{'0' * 8}{TMP_SUFFIX}")


def _tmp_stem(target: Path) -> str:
    """The output's name as its temporaries carry it: the name, or, when a temporary's name would exceed what
    the file system allows (NAME_MAX, 255 bytes, which a name the user gives may nearly fill), its start and a
    hash of the whole name."""
    try:
        name_max = os.pathconf(target.parent, "PC_NAME_MAX")
    except (OSError, ValueError):
        name_max = 255
    raw = os.fsencode(target.name)
    if len(raw) + _TMP_NAME_EXTRA <= name_max:
        return target.name
    digest = hashlib.sha256(raw).hexdigest()[:16]
    keep = max(name_max - _TMP_NAME_EXTRA - len(digest) - 1, 0)
    return f"{raw[:keep].decode('utf-8', 'ignore')}~{digest}"


def _beside(target: Path, suffix: str) -> Path:
    """A new temporary's path beside ``target`` (this process's, with a random part)."""
    return target.parent / f".{_tmp_stem(target)}.{os.getpid()}-{secrets.token_hex(4)}{suffix}"


def _is_recording(p: Path) -> bool:
    """Does ``p`` start as an MCAP file does (what ``record`` and ``recover`` write)?"""
    try:
        with open(p, "rb") as f:
            return f.read(len(_MCAP_MAGIC)) == _MCAP_MAGIC
    except OSError:
        return False


def _tree_entries(root: Path) -> set[str]:
    """Every file and folder below ``root`` as a relative POSIX path (symlinks listed, not followed)."""
    found: set[str] = set()
    for folder, dirs, files in os.walk(root):
        rel = os.path.relpath(folder, root)
        found.update(n if rel == "." else f"{Path(rel).as_posix()}/{n}" for n in (*dirs, *files))
    return found


def _listed_in_manifest(manifest: Path) -> set[str] | None:
    """The paths a manifest says phonepose wrote; None if it lists none (an older phonepose) or is not one."""
    try:
        st = os.lstat(manifest)
        if not stat.S_ISREG(st.st_mode) or st.st_size > 64 * 2**20:
            return None
        files = json.loads(manifest.read_bytes()).get("files")
    except (OSError, ValueError, AttributeError):
        return None
    if not isinstance(files, list) or not all(isinstance(f, str) for f in files):
        return None
    return set(files)


def _keep_mode(tmp: Path, target: Path) -> None:
    """A replaced output keeps the permissions its owner gave it (a calibration made private with chmod 600
    stays private when written anew)."""
    try:
        mode = stat.S_IMODE(os.stat(target).st_mode)
    except FileNotFoundError:
        return
    os.chmod(tmp, mode)


def _empty(p: Path) -> bool:
    try:
        return os.path.getsize(p) == 0
    except OSError:
        return True


def _remove(p: Path) -> None:
    try:
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p, ignore_errors=True)
        else:
            p.unlink()
    except FileNotFoundError:
        pass
    except OSError:
        pass


def _fsync_dir(d: Path) -> None:
    try:
        fd = os.open(d, os.O_RDONLY | _DIRECTORY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _fsync_tree(root: Path) -> None:
    """fsync every file of a finished output folder (ENOSPC surfaces here, not after the rename)."""
    for dirpath, _dirs, files in os.walk(root):
        for name in files:
            fd = os.open(os.path.join(dirpath, name), os.O_RDONLY)
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
        _fsync_dir(Path(dirpath))


_RENAME_EXCHANGE = 2
_AT_FDCWD = -100
_libc: ctypes.CDLL | bool | None = None   # None: not looked up yet; False: no renameat2 here


def _exchange(a: Path, b: Path) -> bool:
    """Swap two paths atomically (Linux renameat2 RENAME_EXCHANGE); False where the system cannot."""
    global _libc
    if _libc is None:
        try:
            _libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
            _libc.renameat2  # noqa: B018 - glibc >= 2.28
        except (OSError, AttributeError):
            _libc = False
    if not isinstance(_libc, ctypes.CDLL):
        return False
    rc = _libc.renameat2(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE)
    if rc == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.ENOSYS, errno.EINVAL, errno.ENOTSUP):
        return False
    raise OSError(err, os.strerror(err), os.fspath(b))
