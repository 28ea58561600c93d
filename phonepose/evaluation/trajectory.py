"""Stamped trajectories: loaders for TUM, EuRoC csv and KITTI files, and the TUM writer.

A :class:`Trajectory` holds stamps in seconds (float64, or ``None`` for KITTI, which is matched by
index) and a :class:`~phonepose.geometry.Pose` stack ``T_world_body``. Loaders raise
:class:`~phonepose.errors.InputFileError` with one line naming the file (and the line, when one
line is at fault); they read the numbers the way evo and rpg do (``float`` of the text, EuRoC
nanoseconds divided by 1e9), so that stamps compare bit for bit with theirs.
"""

from __future__ import annotations

import logging
import os
import re
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from phonepose.errors import ConfigError, InputFileError, OutputError
from phonepose.geometry import QUAT_NORM_TOL, Pose

FORMATS = ("tum", "euroc", "kitti")

log = logging.getLogger("phonepose")


@dataclass(frozen=True)
class Trajectory:
    stamps: np.ndarray | None  # (N,) seconds, float64; None = index-matched (KITTI)
    poses: Pose  # N poses T_world_body
    source: str = ""

    def __len__(self) -> int:
        return len(self.poses)

    @property
    def positions(self) -> np.ndarray:
        return np.atleast_2d(self.poses.translation)

    def __getitem__(self, index) -> Trajectory:
        stamps = None if self.stamps is None else self.stamps[index]
        return Trajectory(stamps, self.poses[index], self.source)

    def path_length(self) -> float:
        return path_length(self.positions)


def path_length(positions: np.ndarray) -> float:
    """Sum of the distances between consecutive positions (rpg's ``traj_length``)."""
    p = np.asarray(positions, dtype=float)
    if len(p) < 2:
        return 0.0
    d = np.diff(p, axis=0)
    return float(np.sum(np.sqrt(np.sum(d * d, axis=1))))


# ----------------------------------------------------------------------------- reading
# Bounds on what a trajectory file holds, checked when it is read (one line naming the file and line). A
# position beyond 1e7 m is not one on or near the Earth: UTM northings stay below 1e7 m and ECEF coordinates
# below 6.4e6 m, so georeferenced trajectories still load, while 1e308 overflowed the alignment's SVD and the
# metrics (inf/NaN). Squares of 1e7 (1e14) summed over millions of poses stay far inside float64.
MAX_POSITION_M = 1e7
# Stamps become int64 nanoseconds (the session's clock), which end at 9.2e9 s (the year 2262).
MAX_STAMP_S = 9e9


_OFF_EARTH = "position {v:g} m is not one on Earth (beyond ±1e7 m)"
# (columns, bound, what a value beyond it is): a TUM file's columns
TUM_BOUNDS = (([0], MAX_STAMP_S, "stamp {v:g} s is not a time (beyond ±9e9 s, the year 2262)"),
              ([1, 2, 3], MAX_POSITION_M, _OFF_EARTH))


def _check_bounds(path, m: np.ndarray, lines: list[int], bounds) -> None:
    """The first value beyond its bound, as one line naming the file and line (values are finite here)."""
    for cols, bound, text in bounds:
        bad = np.flatnonzero(np.any(np.abs(m[:, cols]) > bound, axis=1))
        if bad.size:
            row = m[bad[0], cols]
            v = float(row[np.argmax(np.abs(row))])
            raise InputFileError(f"{path}:{lines[bad[0]]}: {text.format(v=v)}: check the file's columns and units")


# Lines parsed at a time: the text's lines as Python strings cost ~6x the text, so a 1 GiB file is parsed in blocks
# of about this many characters, each block's rows going into one float64 array.
PARSE_BLOCK_CHARS = 1 << 22


def _text_blocks(text: str) -> Iterator[tuple[int, str]]:
    """(number of the block's first line, the block): ``text`` cut after a ``\n`` every PARSE_BLOCK_CHARS characters or
    so, so that no line is cut (``\n`` ends a line for ``str.splitlines`` whatever came before it)."""
    start, lineno = 0, 1
    while start < len(text):
        end = text.find("\n", start + PARSE_BLOCK_CHARS) + 1 or len(text)
        block = text[start:end]
        yield lineno, block
        lineno += len(block.splitlines())
        start = end


def _read_matrix(path, delimiter: str | None, ncols: int, what: str, bounds=()) -> tuple[np.ndarray, np.ndarray]:
    """All numeric rows of a text file (``#`` comments and blank lines skipped), ``ncols`` or more each,
    each value within ``bounds`` (:data:`TUM_BOUNDS`), and the line number of each row.

    Parsed block by block (:data:`PARSE_BLOCK_CHARS`), each row by the same ``np.loadtxt`` as a whole file, so the
    numbers are the same and the memory is the text, the array and one block's strings."""
    from phonepose.files import read_text_input

    text = read_text_input(path, "trajectory file",
                           note="1 GiB of TUM lines is ~13 million poses, 37 hours at 100 Hz")
    parts: list[np.ndarray] = []
    numbers: list[np.ndarray] = []
    width = None
    first = True
    for first_line, block in _text_blocks(text):
        rows = []
        lines = []
        for lineno, line in enumerate(block.splitlines(), start=first_line):
            s = line.split("#", 1)[0].strip()
            if s:
                rows.append(s)
                lines.append(lineno)
        if first and rows:
            # a file of one such line is no trajectory: an error below
            if _is_header(rows[0]) and (len(rows) > 1 or _more_rows(text, block)):
                del rows[0], lines[0]
            first = False
        if not rows:
            continue
        m = _parse_rows(path, delimiter, ncols, what, bounds, rows, lines, width)
        width = m.shape[1]
        parts.append(m)
        numbers.append(np.asarray(lines, dtype=np.int64))
    del text
    if not parts:
        raise InputFileError(f"{path}: no poses (expected {what})")
    m = parts[0] if len(parts) == 1 else np.concatenate(parts)
    return m, (numbers[0] if len(numbers) == 1 else np.concatenate(numbers))


def _more_rows(text: str, block: str) -> bool:
    """Whether ``text`` holds a row after ``block`` (its first, whose only row is a header)."""
    return any(line.split("#", 1)[0].strip() for line in text[len(block):].splitlines())


def _parse_rows(path, delimiter: str | None, ncols: int, what: str, bounds, rows: list[str], lines: list[int],
                width: int | None) -> np.ndarray:
    """``rows`` (at ``lines``) as one array; ``width``: the columns of the rows before, if any."""
    try:
        m = np.loadtxt(rows, delimiter=delimiter, ndmin=2, dtype=float)
    except ValueError:
        m = None
    if m is not None and m.shape[1] >= ncols and np.all(np.isfinite(m[:, :ncols])) and width in (None, m.shape[1]):
        _check_bounds(path, m, lines, bounds)
        return m
    # slow path: find the first bad line and name it
    for s, lineno in zip(rows, lines, strict=True):
        parts = [x for x in (s.split(delimiter) if delimiter else s.split())]
        try:
            vals = [float(x) for x in parts]
        except ValueError:
            if delimiter is None and "," in s:
                raise InputFileError(f"{path}:{lineno}: values separated by commas in {s[:60]!r}: {what} is "
                                     "separated by spaces (an EuRoC csv is {fmt} euroc)", parameter="fmt") from None
            raise InputFileError(f"{path}:{lineno}: not a number in {s[:60]!r} (expected {what})") from None
        if len(vals) < ncols:
            raise InputFileError(f"{path}:{lineno}: {len(vals)} values, expected {ncols} ({what})")
        if not np.all(np.isfinite(vals[:ncols])):
            raise InputFileError(f"{path}:{lineno}: non-finite value ({what})")
        _check_bounds(path, np.array([vals[:ncols]]), [lineno], bounds)
        if width is not None and len(vals) != width:
            raise InputFileError(f"{path}:{lineno}: {len(vals)} values, the lines before have {width} ({what})")
        width = len(vals)
    raise InputFileError(f"{path}: rows of unequal length (expected {what})")


def _is_header(row: str) -> bool:
    """Whether the first row is a column header written without ``#`` (``timestamp tx ty tz qx qy qz qw``,
    ``timestamp,p_x,...``): none of its fields (split at commas and spaces, whatever the format's separator) is a
    number. evo refuses such a file; it is read as if the header were a comment (docs/evaluation.md). A row with
    any number in it is data, and a bad one is an error."""
    for x in re.split(r"[,\s]+", row):
        try:
            float(x)
            return False
        except ValueError:
            pass
    return True


# A quaternion component beyond this is scaled before its norm is taken: the squares of 1e160 overflow float64.
QUAT_SCALE_ABOVE = 1e150


def _quat_norms(quat_xyzw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(the quaternions scipy is given, their norms): a row with a component beyond :data:`QUAT_SCALE_ABOVE` is
    divided by its largest component first (1e300's norm overflowed to inf, which scipy read as a zero quaternion);
    every other row is given unchanged, so its numbers stay evo's and rpg's."""
    q = np.asarray(quat_xyzw, dtype=float)
    big = np.flatnonzero(np.max(np.abs(q), axis=1) > QUAT_SCALE_ABOVE)
    norms = np.linalg.norm(q, axis=1)
    if big.size:
        q = q.copy()
        scale = np.max(np.abs(q[big]), axis=1)
        q[big] /= scale[:, None]
        norms[big] = scale * np.linalg.norm(q[big], axis=1)   # inf only beyond float64's 1.8e308
    return q, norms


def _poses_from_xyzw(path, lines: np.ndarray, xyz, quat_xyzw) -> Pose:
    q, norms = _quat_norms(quat_xyzw)
    bad = np.flatnonzero(~(norms > 1e-12))
    if bad.size:
        raise InputFileError(f"{path}:{lines[bad[0]]}: pose {int(bad[0])} has a zero quaternion (|q| "
                             f"{norms[bad[0]]:.3g}): check the file's columns")
    return Pose.from_xyzw(xyz, q)


def _report_rows(path, stamps: np.ndarray, quat_xyzw: np.ndarray) -> None:
    """One warning line for quaternions off unit length and one for duplicate or backwards stamps; both kept.

    Every non-zero quaternion is normalised, as evo and rpg do (their readers divide by the norm), so a file
    written with few decimals, or by a tool that leaves its quaternions unnormalised, gives their numbers; a
    quaternion more than QUAT_NORM_TOL off unit length is counted in the warning. Duplicate or backwards stamps
    are used as they are: evo and rpg do (real datasets have some, e.g. EuRoC V102), and our numbers must equal
    theirs (docs/evaluation.md).
    """
    norms = _quat_norms(quat_xyzw)[1]
    off = np.abs(norms - 1.0) > QUAT_NORM_TOL
    n_quat = int(np.count_nonzero(off))
    n_time = int(np.count_nonzero(np.diff(stamps) <= 0))
    if n_quat:
        log.warning("%s: %d pose(s) whose quaternion is not unit length (|q| %.6g to %.6g): "
                    "normalised, as evo and rpg do", path, n_quat, norms[off].min(), norms[off].max())
    if n_time:
        log.warning("%s: %d duplicate or non-monotonic timestamp(s), used as evo/rpg do",
                    path, n_time)


def load_tum(path) -> Trajectory:
    """TUM: ``t tx ty tz qx qy qz qw`` per line, time in seconds, quaternion w last."""
    m, lines = _read_matrix(path, None, 8, "TUM 't tx ty tz qx qy qz qw'", TUM_BOUNDS)
    if m.shape[1] != 8:
        raise InputFileError(f"{path}: {m.shape[1]} columns, expected 8 (TUM 't tx ty tz qx qy qz qw')")
    poses = _poses_from_xyzw(path, lines, m[:, 1:4], m[:, 4:8])   # zero quaternions: an error naming the line
    _report_rows(path, m[:, 0], m[:, 4:8])
    return Trajectory(m[:, 0].copy(), poses, str(path))


def load_euroc(path) -> Trajectory:
    """EuRoC/ASL csv: ``t[ns], px, py, pz, qw, qx, qy, qz[, ...]`` (as evo: stamps = t / 1e9)."""
    m, lines = _read_matrix(path, ",", 8, "EuRoC csv 't[ns],px,py,pz,qw,qx,qy,qz,...'",
                     (([0], MAX_STAMP_S * 1e9, "stamp {v:g} ns is not a time (beyond ±9e18 ns, the year 2262)"),
                      *TUM_BOUNDS[1:]))
    quat_xyzw = m[:, [5, 6, 7, 4]]
    poses = _poses_from_xyzw(path, lines, m[:, 1:4], quat_xyzw)   # zero quaternions: an error naming the line
    _report_rows(path, m[:, 0], quat_xyzw)
    return Trajectory(np.divide(m[:, 0], 1e9), poses, str(path))


def load_kitti(path) -> Trajectory:
    """KITTI: 12 values per line, the row-major 3x4 ``[R|t]``; no stamps (poses matched by index)."""
    m, lines = _read_matrix(path, None, 12, "KITTI 3x4 row-major [R|t], 12 values",
                     (([3, 7, 11], MAX_POSITION_M, _OFF_EARTH),))
    if m.shape[1] != 12:
        raise InputFileError(f"{path}: {m.shape[1]} columns, expected 12 (KITTI 3x4 row-major [R|t])")
    mat = np.zeros((len(m), 4, 4))
    mat[:, :3, :] = m.reshape(-1, 3, 4)
    mat[:, 3, 3] = 1.0
    R = mat[:, :3, :3]
    dets = np.linalg.det(R)
    orthogonal = np.all(np.abs(np.einsum("nji,njk->nik", R, R) - np.eye(3)) < 1e-3, axis=(1, 2))
    bad = np.flatnonzero(~((np.abs(dets - 1.0) < 1e-3) & orthogonal))
    if bad.size:
        raise InputFileError(f"{path}:{lines[bad[0]]}: pose {int(bad[0])} is not a rotation (det {dets[bad[0]]:.4g})")
    return Trajectory(None, Pose.from_matrix(mat), str(path))


def load_trajectory(path, fmt: str = "tum") -> Trajectory:
    loaders = {"tum": load_tum, "euroc": load_euroc, "kitti": load_kitti}
    if fmt not in loaders:
        raise ConfigError(f"{{fmt}} {fmt!r}: expected one of {', '.join(FORMATS)}", parameter="fmt", value=fmt,
                          expected=f"one of {', '.join(FORMATS)}")
    return loaders[fmt](path)


# ----------------------------------------------------------------------------- writing
def _format_stamps(stamps) -> list[str]:
    s = np.asarray(stamps)
    if np.issubdtype(s.dtype, np.integer):  # integer nanoseconds: exact
        out = []
        for t in s.tolist():
            sign = "-" if t < 0 else ""
            t = abs(int(t))
            out.append(f"{sign}{t // 1_000_000_000}.{t % 1_000_000_000:09d}")
        return out
    return [f"{t:.9f}" for t in s.astype(float).tolist()]


def tum_lines(stamps, poses: Pose | None) -> list[str]:
    """The lines ``write_tum`` writes (without newlines); quaternions made canonical (qw >= 0)."""
    if poses is None or len(np.atleast_1d(stamps)) == 0:
        return []
    t = np.atleast_2d(poses.translation).astype(float)
    q = np.atleast_2d(poses.rotation.as_quat(canonical=True))
    vals = np.hstack([t, q])
    vals = np.where(np.abs(vals) < 5e-10, 0.0, vals)  # no "-0.000000000"
    stamp_txt = _format_stamps(np.atleast_1d(stamps))
    if len(stamp_txt) != len(vals):
        raise ValueError(f"{len(stamp_txt)} stamps for {len(vals)} poses")
    body = [" ".join(f"{v:.9f}" for v in row) for row in vals.tolist()]
    return [f"{a} {b}" for a, b in zip(stamp_txt, body, strict=True)]


# ----------------------------------------------------------------------------- which session a file is from
SESSION_TAG = "# session: "


def session_tag_line(tag: str | None) -> str:
    """The header line naming the session a file was computed from (``""`` for none)."""
    return "" if not tag else f"{SESSION_TAG}{tag}\n"


def read_session_tag(path: str | os.PathLike) -> str | None:
    """The ``# session: NAME ID`` tag playback writes in its files' headers, or None (any other file).

    Only the leading comment lines are read: evo, rpg and every TUM reader skip ``#`` lines, so the
    tag costs other tools nothing.
    """
    try:
        with open(path, errors="replace") as f:
            # each line read up to 4096 characters: a binary file without newlines is never read whole
            for line in iter(lambda: f.readline(4096), ""):
                if not line.startswith("#"):
                    break
                if line.startswith(SESSION_TAG):
                    return line[len(SESSION_TAG):].strip() or None
    except OSError:
        return None
    return None


TUM_WRITE_BLOCK = 2048   # rows formatted at a time


def _write_rows(path: str | os.PathLike, header: str, session: str | None, n: int,
                lines: Callable[[slice], Iterable[str]]) -> None:
    """``header``, the session tag, then ``lines(rows)`` for each block of ``TUM_WRITE_BLOCK`` rows of ``n``.

    In blocks: the text of a 10-minute trajectory at once would be the playback's peak memory
    (docs/performance.md#memory); each line depends on its row only, so the bytes are the same."""
    try:
        with open(path, "w") as f:
            f.write(header + session_tag_line(session))
            for k in range(0, n, TUM_WRITE_BLOCK):
                f.write("".join(line + "\n" for line in lines(slice(k, k + TUM_WRITE_BLOCK))))
    except OSError as exc:
        raise OutputError(f"cannot write {path}: {exc.strerror or exc}") from None


def write_tum(path: str | os.PathLike, stamps, poses: Pose | None, session: str | None = None) -> None:
    """Write ``t tx ty tz qx qy qz qw`` lines with a ``#`` header, 9 decimals everywhere.

    ``stamps`` are seconds (float) or integer nanoseconds (any integer dtype, written exactly).
    ``session``: a tag naming the session the poses come from (:func:`read_session_tag`).
    The same input always gives the same bytes.
    """
    stamps = np.atleast_1d(stamps)
    n = 0 if poses is None else len(stamps)
    if poses is not None and n and len(np.atleast_2d(poses.translation)) != n:
        raise ValueError(f"{n} stamps for {len(np.atleast_2d(poses.translation))} poses")
    _write_rows(path, "# timestamp tx ty tz qx qy qz qw\n", session, n,
                lambda rows: tum_lines(stamps[rows], poses if n == 1 else poses[rows]))   # type: ignore[index]


# ----------------------------------------------------------------------------- in-view flags
def write_in_view(path: str | os.PathLike, stamps, inside, session: str | None = None) -> None:
    """``timestamp in_view`` lines (1: the marker was recognised at that tick), stamps as in write_tum.

    Playback writes it beside groundtruth.tum so that ``phonepose evaluate --metric paper`` can split
    any trajectory into inside / outside the view and find the boundary jumps.
    """
    stamps = np.atleast_1d(stamps)
    flags = np.asarray(inside, dtype=bool).ravel()
    if len(stamps) != len(flags):
        raise ValueError(f"{len(stamps)} stamps for {len(flags)} flags")
    _write_rows(path, "# timestamp in_view\n", session, len(stamps),
                lambda rows: (f"{s} {int(v)}" for s, v in zip(_format_stamps(stamps[rows]), flags[rows], strict=True)))


def load_in_view(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """(stamps in s, in-view flags) from a file written by :func:`write_in_view`."""
    from phonepose.files import read_text_input

    path = Path(path)
    stamps, flags = [], []
    for n, line in enumerate(read_text_input(path, "in-view file").splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.replace(",", " ").split()
        try:
            if len(parts) != 2 or parts[1] not in ("0", "1"):
                raise ValueError
            stamps.append(float(parts[0]))
            flags.append(parts[1] == "1")
        except ValueError:
            raise InputFileError(f"{path}:{n}: expected 'timestamp in_view(0|1)', got {line[:60]!r}") from None
    return np.array(stamps, dtype=float), np.array(flags, dtype=bool)
