"""What a batch runs: the parameters a user can sweep, their cross product, and the row keys.

A *unit* of work is one playback: one session with one parameter combination, running every
tracker that still needs a row (the shared stages, decode + marker recognition, run once per tick
for all of them). It gives one row per tracker. A row's key is ``(session, params, tracker)``;
``params`` is the canonical JSON of *every* parameter's effective value (defaults included), so a
run that spells out a default and one that does not give the same key.
"""

from __future__ import annotations

import itertools
import json
import os
import re
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass

from phonepose.errors import ConfigError
from phonepose.numbers import RATE_MAX_HZ, RATE_MIN_HZ, SECONDS_MAX, check_number


def _float(key: str, text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise ConfigError(f"{{params}} {key}: {text!r} is not a number", parameter="params", value=text,
                          expected="a number") from None


def _rate(key: str, text: str) -> float:
    return check_number(f"params {key}=", _float(key, text), RATE_MIN_HZ, RATE_MAX_HZ, unit="Hz")


def _seconds_or_none(key: str, text: str) -> float | None:
    if text.strip().lower() in ("none", "null", ""):
        return None
    return check_number(f"params {key}=", _float(key, text), 0, SECONDS_MAX, unit="s")


def _choice(enum_name: str) -> Callable[[str, str], str]:
    def parse(key: str, text: str) -> str:
        from phonepose.pipeline import corrections

        cls = getattr(corrections, enum_name)
        try:
            return cls.parse(text.strip()).value
        except ConfigError as exc:
            raise ConfigError(f"{{params}} {key}: {exc}", parameter="params", value=text) from None
    return parse


@dataclass(frozen=True)
class ParamSpec:
    key: str
    arrow_type: str              # "float64" | "string": the type of the column param_<key>
    default: object
    parse: Callable[[str, str], object]
    help: str


# The playback options a user sweeps (run_playback's arguments; cm1_reading goes to make_trackers).
PARAMS: dict[str, ParamSpec] = {p.key: p for p in (
    ParamSpec("rate_hz", "float64", 20.0, _rate, "tick rate, Hz (run_playback rate_hz)"),
    ParamSpec("correction_math", "string", "paper", _choice("CorrectionMath"), "paper | se3"),
    ParamSpec("cm1_reading", "string", "consistent", _choice("CM1Reading"), "consistent | paper-literal (CM1 trackers)"),
    ParamSpec("start_s", "float64", None, _seconds_or_none, "play from this many seconds after the session start"),
    ParamSpec("end_s", "float64", None, _seconds_or_none, "play until this many seconds after the session start"),
)}


def parse_param_options(options: Iterable[str]) -> dict[str, list]:
    """``["rate_hz=10,20", "correction_math=se3"]`` → ``{"rate_hz": [10.0, 20.0], "correction_math": ["se3"]}``.

    Unknown keys, a key given twice, or a bad value: ConfigError (one line, exit 5).
    """
    out: dict[str, list] = {}
    for opt in options:
        key, sep, values = opt.partition("=")
        key = key.strip()
        if not sep or not key:
            raise ConfigError(f"{{params}} {opt!r}: expected KEY=V1[,V2...]; keys: {', '.join(PARAMS)}",
                              parameter="params", value=opt, expected="KEY=V1[,V2...]")
        spec = PARAMS.get(key)
        if spec is None:
            raise ConfigError(f"{{params}}: unknown key {key!r}; valid: {', '.join(PARAMS)}", parameter="params",
                              value=key, expected=f"one of {', '.join(PARAMS)}")
        if key in out:
            raise ConfigError(f"{{params}} {key} given twice; list its values in one option: {key}=V1,V2",
                              parameter="params", value=key)
        parsed: dict = {}   # a dict keeps the order and drops repeats in O(1) each (a list: O(n^2))
        for text in values.split(","):
            parsed.setdefault(spec.parse(key, text.strip()), None)
        out[key] = list(parsed)
    return out


# The most playbacks (sessions x parameter combinations) one batch plans. A real study is a few
# hundred sessions x tens of combinations (10^3-10^4 units); planning holds every unit and row key
# in memory (~1 KB a unit with its rows' keys, a few seconds to plan 10^5) and the table is
# rewritten whole, so 10^5 units is far above any study and still safe to plan; a sweep typed with
# one value too many per axis (2*10^8 units) would otherwise fill the machine's memory before the
# first line. Counted from the value counts before any combination exists (check_unit_count).
MAX_UNITS = 100_000


def count_units(n_sessions: int, sweep: dict[str, list]) -> int:
    """Sessions x the product of every swept key's value count (unswept keys: one value)."""
    n = n_sessions
    for key in PARAMS:
        n *= max(1, len(sweep.get(key, ())))
    return n


def check_unit_count(n_sessions: int, sweep: dict[str, list], limit: int = MAX_UNITS) -> int:
    """The batch's number of units, or ConfigError (one line) above ``limit``: before any list of them."""
    n = count_units(n_sessions, sweep)
    if n > limit:
        counts = " x ".join([f"{n_sessions} session{'s' if n_sessions != 1 else ''}"]
                            + [f"{len(sweep[k])} {k}" for k in PARAMS if len(sweep.get(k, ())) > 1])
        raise ConfigError(f"{{params}}: {counts} = {n:,} playbacks, more than a batch's limit of {limit:,}; "
                          "split it into several batches (fewer sessions or {params} values each, "
                          "one {out} per batch)", parameter="params", value=n, expected=f"<= {limit:,} playbacks",
                          also=["out"])
    return n


def param_combinations(sweep: dict[str, list]) -> list[dict]:
    """The cross product, every key present (defaults filled in), in PARAMS order; start < end checked.
    Callers check its size first (check_unit_count): it is a list."""
    axes = [sweep.get(k, [spec.default]) for k, spec in PARAMS.items()]
    combos = []
    for values in itertools.product(*axes):
        combo = dict(zip(PARAMS, values, strict=True))
        s, e = combo["start_s"], combo["end_s"]
        if s is not None and e is not None and e <= s:
            raise ConfigError(f"{{params}} end_s ({e}) must be after start_s ({s})", parameter="params", value=e)
        combos.append(combo)
    return combos


def params_json(params: dict) -> str:
    """Canonical text of a parameter combination: the ``params`` column and part of the row key."""
    return json.dumps({k: params.get(k) for k in sorted(params)}, sort_keys=True, separators=(",", ":"))


def params_label(params: dict, keys: Iterable[str] | None = None) -> str:
    """Short text of a combination for people: ``rate_hz=10 correction_math=se3`` (only ``keys`` if given)."""
    def fmt(v) -> str:
        return f"{v:g}" if isinstance(v, float) else str(v)
    return " ".join(f"{k}={fmt(params.get(k))}" for k in (keys if keys is not None else params))


def session_key(path: str | os.PathLike) -> str:
    """The ``session`` column: the path as given, normalised (``./a//b.mcap`` → ``a/b.mcap``)."""
    return os.path.normpath(os.fspath(path))


def session_signature(path: str) -> tuple[int, int] | None:
    """(bytes, mtime_ns) of the file as this machine sees it; None if it cannot be seen here."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    return st.st_size, st.st_mtime_ns


def tracker_sort_key(name: str) -> tuple:
    """Natural order: T2 before T10."""
    return tuple((0, int(p)) if p.isdigit() else (1, p) for p in re.split(r"(\d+)", name) if p)


def params_sort_key(params: dict) -> tuple:
    """Typed order of a combination (None first), keys in PARAMS order then any others."""
    keys = list(PARAMS) + sorted(k for k in params if k not in PARAMS)
    return tuple((0, "") if params.get(k) is None else (1, params[k]) for k in keys)


def row_key(session: str, params: str, tracker: str) -> tuple[str, str, str]:
    return (session, params, tracker)


@dataclass(frozen=True)
class Unit:
    """One playback: a session, one parameter combination, the trackers that need rows."""

    session: str                 # the session column (path as given, normalised)
    path: str                    # what the worker opens (absolute, resolved on the client)
    params: tuple[tuple[str, object], ...]
    trackers: tuple[str, ...]
    refs: tuple[tuple[str, str], ...] = ()   # a user's tracker: (name, package.module:Class or entry point)

    @property
    def tracker_refs(self) -> list[str]:
        """What make_trackers builds this unit's trackers from (in the worker)."""
        refs = dict(self.refs)
        return [refs.get(t, t) for t in self.trackers]

    @property
    def params_dict(self) -> dict:
        return dict(self.params)


@dataclass
class Plan:
    units: list[Unit]            # playbacks to run
    keys: list[tuple[str, str, str]]   # every row the batch asks for (run or skipped)
    skipped: int                 # rows already in the table with status ok
    retried: int                 # rows in the table with status error, run again
    stale: int                   # ok rows whose session file changed since (size or mtime), run again
    sessions: int
    combinations: int
    trackers: list[str]
    varying: list[str]           # parameters with more than one value (what tells combinations apart)


def make_plan(sessions: Sequence[str | os.PathLike], trackers: Sequence[str], combos: list[dict],
              existing: dict[tuple[str, str, str], dict], refs: dict[str, str] | None = None) -> Plan:
    """Which (session, params, tracker) rows the batch wants, and which playbacks still have to run.

    ``existing``: rows of the table already written, by key. A row is skipped when its status is
    ok and the session file still has the size and mtime recorded in it (or the file cannot be
    seen from here: then the row is trusted). Error rows are retried.
    """
    seen: dict[str, str] = {}
    for s in sessions:
        key = session_key(s)
        seen.setdefault(key, os.path.abspath(key))
    units: list[Unit] = []
    keys = []
    skipped = retried = stale = 0
    for session, path in sorted(seen.items()):
        sig = session_signature(path)
        for combo in sorted(combos, key=params_sort_key):
            pj = params_json(combo)
            todo = []
            for tracker in trackers:
                k = row_key(session, pj, tracker)
                keys.append(k)
                row = existing.get(k)
                if row is not None and row.get("status") == "ok":
                    if sig is None or (row.get("session_bytes"), row.get("session_mtime_ns")) == sig:
                        skipped += 1
                        continue
                    stale += 1
                elif row is not None:
                    retried += 1
                todo.append(tracker)
            if todo:
                units.append(Unit(session, path, tuple(combo.items()), tuple(todo),
                                  tuple((t, refs[t]) for t in todo if refs and t in refs)))
    varying = [k for k in PARAMS if len({json.dumps(c.get(k)) for c in combos}) > 1]
    return Plan(units, keys, skipped, retried, stale, len(seen), len(combos), list(trackers), varying)
