"""The tracking algorithms T1-T7 of the paper's Table 1, as one registry.

Each tracker is a row of the table: (method inside the camera's FoV, method outside it,
correction). "Inside the FoV" is decided as the paper does in practice: the marker was
recognised in this frame (``Observation.in_view``). Wherever a row's method is VIO, that VIO
pose is the anchor-mapped one with the row's correction applied (once the correction exists).

    name  inside   outside  correction
    T1    VIO      VIO      none
    T2    VIO      VIO      CM1   (manual alignment event)
    T3    VIO      VIO      CM2   (one offset at the calibration moment)
    T4    marker   VIO      none
    T5    marker   VIO      CM1
    T6    marker   VIO      CM2
    T7    marker   VIO      CM3   (offset renewed on every sighting)

Behaviour before a correction exists (decided here, documented in docs/pipeline.md): the
tracker reports the *uncorrected* anchor-mapped VIO pose, so T2/T3 equal T1 and T5/T6/T7 equal
T4 until their first CM1 event / CM2 capture / marker sighting. A CM2 event is captured on the
first tick at or after the event on which both the marker and VIO are available (the paper holds
the marker in view in advance). A later event of the same kind replaces the offset.
When the pose a row needs is missing (no VIO yet, anchors not resolved), ``step`` returns None:
the tracker has no estimate at that tick; it never invents one.

Trackers are causal streaming objects: ``reset()`` then ``step(obs)`` once per tick, in order.
More rows ("better trackers of our own") are added with :func:`register`: T7L (T7 with a
latency-aware CM3, phonepose/pipeline/t7l.py) and T8 (the fused tracker, phonepose/pipeline/t8/).
``"paper"`` selects T1-T7, ``"all"`` every row.
"""

from __future__ import annotations

import importlib
import importlib.metadata
import logging
import re
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from enum import StrEnum
from typing import Any

import numpy as np

from phonepose.errors import ConfigError, StopRequest, TrackerError
from phonepose.geometry import Pose, is_finite
from phonepose.pipeline.corrections import CM1Reading, Correction, CorrectionMath, cm1_correction, marker_correction
from phonepose.pipeline.t7l import LatencyAwareCM3Tracker
from phonepose.pipeline.t8 import FusedTracker
from phonepose.pipeline.types import CalibrationKind, Observation, Tracker


class Method(StrEnum):
    VIO = "VIO"
    MARKER = "marker"


class CorrectionKind(StrEnum):
    NONE = "none"
    CM1 = "CM1"
    CM2 = "CM2"
    CM3 = "CM3"


# ----------------------------------------------------------------------------- correction sources
log = logging.getLogger("phonepose")


class CorrectionSource:
    """Keeps the current offset of one correction method up to date, causally, tick by tick."""

    def __init__(self, math: CorrectionMath, cm1_reading: CM1Reading = CM1Reading.CONSISTENT):
        self.math = math
        self.cm1_reading = cm1_reading
        self.current: Correction | None = None

    def reset(self) -> None:
        self.current = None

    def update(self, obs: Observation) -> None:
        """Look at this tick's events / marker and renew ``current`` if the method says so."""


class NoCorrection(CorrectionSource):
    pass


class CM1Source(CorrectionSource):
    """CM1: the offset comes with the manual-alignment event (both poses are in the event)."""

    def update(self, obs: Observation) -> None:
        for event in obs.tick.events:
            if event.kind == CalibrationKind.CM1:
                fix, align = event.pose_fix_vio, event.pose_align_vio
                if fix is None or align is None:
                    log.warning("CM1 event at %d ns ignored: a pose is missing, NaN/inf or "
                                "its quaternion is not unit length", obs.tick.t_ns)
                    continue
                self.current = cm1_correction(fix, align, self.math, self.cm1_reading)


class CM2Source(CorrectionSource):
    """CM2: at the calibration moment, one offset between the marker and VIO poses (eqs. 3-4)."""

    def reset(self) -> None:
        super().reset()
        self.pending = False

    def __init__(self, math: CorrectionMath, cm1_reading: CM1Reading = CM1Reading.CONSISTENT):
        super().__init__(math, cm1_reading)
        self.pending = False

    def update(self, obs: Observation) -> None:
        if any(event.kind == CalibrationKind.CM2 for event in obs.tick.events):
            self.pending = True
        # The marker must be recognised at the moment; if it is not on the event's tick, the
        # first tick after it on which it is (with VIO) is the calibration moment.
        if self.pending and obs.marker is not None and is_finite(obs.marker.T_dvio_controller) \
                and is_finite(obs.T_dvio_controller_vio):
            self.current = marker_correction(obs.marker.T_dvio_controller, obs.T_dvio_controller_vio, self.math)
            self.pending = False


class CM3Source(CorrectionSource):
    """CM3: the CM2 offset, renewed on every tick where the marker is recognised."""

    def update(self, obs: Observation) -> None:
        if obs.marker is not None and is_finite(obs.marker.T_dvio_controller) and is_finite(obs.T_dvio_controller_vio):
            self.current = marker_correction(obs.marker.T_dvio_controller, obs.T_dvio_controller_vio, self.math)


CORRECTION_SOURCES: dict[CorrectionKind, type[CorrectionSource]] = {
    CorrectionKind.NONE: NoCorrection,
    CorrectionKind.CM1: CM1Source,
    CorrectionKind.CM2: CM2Source,
    CorrectionKind.CM3: CM3Source,
}


# ----------------------------------------------------------------------------- the table
@dataclass(frozen=True)
class TrackerSpec:
    """One row of Table 1. ``factory`` builds trackers that are not a plain composition."""

    name: str
    inside: Method
    outside: Method
    correction: CorrectionKind
    description: str = ""
    factory: Callable[[TrackerSpec, CorrectionMath, CM1Reading], Tracker] | None = None


class CompositeTracker:
    """A tracker that is exactly a row of Table 1: pick the method by FoV, correct VIO."""

    def __init__(self, spec: TrackerSpec, correction_math: CorrectionMath = CorrectionMath.PAPER,
                 cm1_reading: CM1Reading = CM1Reading.CONSISTENT):
        self.spec = spec
        self.name = spec.name
        self.correction_math = correction_math
        self.correction = CORRECTION_SOURCES[spec.correction](correction_math, cm1_reading)

    uses_vio_samples = False

    @property
    def needs_camera(self) -> bool:
        """A row that uses the marker inside the FoV, or a correction captured from marker sightings (CM2, CM3)."""
        return self.spec.inside is Method.MARKER or self.spec.correction in (CorrectionKind.CM2, CorrectionKind.CM3)

    def reset(self) -> None:
        self.correction.reset()

    def step(self, obs: Observation) -> Pose | None:
        # Renew the offset first: CM3 takes it on this very sighting (it is only *applied* outside).
        self.correction.update(obs)
        method = self.spec.inside if obs.in_view else self.spec.outside
        if method is Method.MARKER:
            assert obs.marker is not None   # Table 1 uses the marker only inside the view (in_view: recognised)
            est = obs.marker.T_dvio_controller
        else:
            vio = obs.T_dvio_controller_vio
            if not is_finite(vio):
                return None
            offset = self.correction.current
            est = vio if offset is None else offset.apply(vio)
        return est if est is None or is_finite(est) else None   # a non-finite input gives no estimate

    def __repr__(self) -> str:
        s = self.spec
        return f"{s.name}({s.inside.value}/{s.outside.value}/{s.correction.value}, {self.correction_math.value})"


def _row(name: str, inside: Method, outside: Method, correction: CorrectionKind, description: str) -> TrackerSpec:
    return TrackerSpec(name, inside, outside, correction, description)


VIO, MARKER = Method.VIO, Method.MARKER
TRACKERS: dict[str, TrackerSpec] = {
    spec.name: spec for spec in [
        _row("T1", VIO, VIO, CorrectionKind.NONE, "anchor-mapped VIO everywhere"),
        _row("T2", VIO, VIO, CorrectionKind.CM1, "VIO corrected by the manual alignment (CM1)"),
        _row("T3", VIO, VIO, CorrectionKind.CM2, "VIO corrected once at the calibration moment (CM2)"),
        _row("T4", MARKER, VIO, CorrectionKind.NONE, "marker in view, else VIO"),
        _row("T5", MARKER, VIO, CorrectionKind.CM1, "marker in view, else VIO + CM1"),
        _row("T6", MARKER, VIO, CorrectionKind.CM2, "marker in view, else VIO + CM2"),
        _row("T7", MARKER, VIO, CorrectionKind.CM3, "marker in view, else VIO + CM3 from the last sighting"),
    ]
}
PAPER_TRACKERS = ("T1", "T2", "T3", "T4", "T5", "T6", "T7")


def register(spec: TrackerSpec) -> None:
    """Add a tracker of our own to the registry (names must be new)."""
    if spec.name in TRACKERS:
        raise ValueError(f"tracker {spec.name!r} already registered")
    TRACKERS[spec.name] = spec


def tracker_names() -> list[str]:
    """Every registered tracker: T1..T7 first, in the table's order, then our own."""
    return list(TRACKERS)


def split_names(names: Iterable[str] | str) -> list[str]:
    """Tracker names from a list and/or comma-separated strings (``"T1,T7"``, ``["T1", "T4,T8"]``)."""
    if isinstance(names, str):
        names = [names]
    return [n.strip() for item in names for n in str(item).split(",") if n.strip()]


# ----------------------------------------------------------------------------- a user's own trackers
ENTRY_POINT_GROUP = "phonepose.trackers"
TRACKER_PROTOCOL = ("name", "needs_camera", "uses_vio_samples", "reset", "step")   # docs/writing-a-tracker.md


def _entry_points() -> dict[str, importlib.metadata.EntryPoint]:
    """Installed trackers: entry points of the group ``phonepose.trackers``, by name."""
    return {ep.name: ep for ep in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP)}


# A tracker's name is a file name (trajectories/NAME.tum), an MCAP topic (/trackers/NAME/pose), a Rerun entity
# path, a batch table's row and an experiment table's row: ASCII letters, digits, '_', '-' and '.', not starting
# with '.' or '-' (no hidden file, nothing a shell reads as an option), at most NAME_MAX characters.
NAME_MAX = 64
NAME_RULE = (f"1-{NAME_MAX} ASCII letters, digits, '_', '-' or '.', not starting with '.' or '-' (it names "
             "trajectories/NAME.tum)")
_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.-]*")


def _shown(value: object) -> str:
    """A user's value in an error line, short and without calling its code (its repr may raise or be huge)."""
    if isinstance(value, str):
        text = repr(value)
        return text if len(text) <= 40 else text[:36] + "...'"
    if isinstance(value, (int, float, bool)) or value is None:
        return f"{value!r} ({_kind(value)}, not a string)"
    return f"{_kind(value)}, not a string"


def _kind(value: object) -> str:
    """``an int``, ``a function``: the type of a user's value, for an error line."""
    kind = type(value).__name__
    return f"{'an' if kind[:1].lower() in 'aeiou' else 'a'} {kind}"


def is_safe_name(name: object) -> bool:
    """Whether ``name`` may name a tracker's files (NAME_RULE): every built-in's does."""
    return isinstance(name, str) and len(name) <= NAME_MAX and _NAME.fullmatch(name) is not None


def check_tracker_name(name: object, who: str) -> str:
    """``name`` if it follows the rule of a tracker's name (NAME_RULE; not a built-in's, whatever the case),
    else ConfigError naming ``who`` (the tracker as the user gave it, and its class)."""
    if not isinstance(name, str) or not is_safe_name(name):
        raise ConfigError(f"{who} is named {_shown(name)}: a tracker's name is {NAME_RULE}; "
                          "see docs/writing-a-tracker.md")
    builtin = {n.upper(): n for n in TRACKERS}.get(name.upper())
    if builtin is not None:
        same = "the name" if builtin == name else f"in another case the name ({builtin})"
        raise ConfigError(f"{who} is named {name!r}, {same} of a built-in tracker; rename it")
    return name


def check_unique_names(names: Iterable[str], refs: Iterable[str] | None = None) -> None:
    """The trackers of one run have distinct names, also ignoring case (trajectories/t9.tum and T9.tum are
    one file on a case-insensitive disk); ``refs`` (the trackers as the user named them) make the error
    name the two trackers."""
    names = list(names)
    refs = list(refs) if refs is not None else None
    seen: dict[str, tuple[str, str | None]] = {}
    for i, name in enumerate(names):
        ref = refs[i] if refs is not None else None
        first = seen.setdefault(name.casefold(), (name, ref))
        if first == (name, ref) and names.index(name) == i:
            continue
        if first == (name, ref):
            raise ConfigError(f"tracker given twice: {', '.join(names)}")
        which = f"named {name!r}" if first[0] == name else \
            f"named {first[0]!r} and {name!r}, one file name on a case-insensitive disk"
        pair = f"{first[1]} and {ref}" if refs is not None else f"{first[0]!r} and {name!r}"
        raise ConfigError(f"trackers {pair} are {which}: the trackers of a run need distinct names; rename one")


def _passes(exc: BaseException) -> bool:
    """What a user's code may raise that is not its error: Ctrl-C / SIGTERM, and phonepose's own stops."""
    return isinstance(exc, (KeyboardInterrupt, StopRequest))


def _what_failed(exc: BaseException) -> str:
    if isinstance(exc, SystemExit):
        return f"it called sys.exit({'' if exc.code is None else repr(exc.code)}): a tracker must not end the " \
               "process; raise an exception instead"
    text = " ".join(str(exc).split())
    text = text if len(text) <= 300 else text[:297] + "..."
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def _class_name(obj: object) -> str:
    """``module.Class`` of a user's tracker (or of the class or factory function that makes it)."""
    named = obj if isinstance(obj, type) or callable(obj) and hasattr(obj, "__qualname__") else type(obj)
    return f"{getattr(named, '__module__', '?')}.{getattr(named, '__qualname__', type(named).__name__)}"


def _import_reference(ref: str) -> Callable[[], object]:
    """``package.module:ClassName`` (or ``:factory``): the object named, imported."""
    module, _, attr = ref.partition(":")
    if not module or not attr:
        raise ConfigError(f"tracker {ref!r}: a reference is package.module:ClassName")
    try:
        obj: Any = importlib.import_module(module)   # then the attribute a user named: any object
    except ImportError as exc:
        raise ConfigError(f"tracker {ref!r}: cannot import {module}: {exc}") from None
    except BaseException as exc:   # noqa: BLE001 - the module's own code failed (or exited) while importing
        if _passes(exc):
            raise
        raise ConfigError(f"tracker {ref!r}: importing {module} failed: {_what_failed(exc)}") from None
    for part in attr.split("."):
        obj = getattr(obj, part, None)
        if obj is None:
            raise ConfigError(f"tracker {ref!r}: {module} has no {attr}")
    return obj


class UserTracker:
    """A user's tracker as phonepose runs it: its name and capabilities read once, when it is loaded, and
    checked (the name by :func:`check_tracker_name`), and its ``reset``/``step`` guarded, so that whatever
    they raise, a ``sys.exit()`` included, is one :class:`TrackerError` naming it (never an "unexpected"
    line or a silent exit), and a ``step`` returning anything but one finite Pose or None is refused.
    Ctrl-C passes through. Any other attribute is the user's object's (``tracker``)."""

    def __init__(self, ref: str, tracker: Any, name: str, needs_camera: bool, uses_vio_samples: bool):
        self.ref = ref
        self.tracker = tracker
        self.name = name
        self.needs_camera = needs_camera
        self.uses_vio_samples = uses_vio_samples

    def _failed(self, method: str, what: str) -> TrackerError:
        return TrackerError(f"tracker {self.ref!r} ({self.name}) failed in {method}(): {what}", self.name)

    def reset(self) -> None:
        try:
            self.tracker.reset()
        except BaseException as exc:   # noqa: BLE001 - a user's code: whatever it raises is its error
            if _passes(exc):
                raise
            raise self._failed("reset", _what_failed(exc)) from None

    def step(self, obs: Observation) -> Pose | None:
        try:
            pose = self.tracker.step(obs)
        except BaseException as exc:   # noqa: BLE001 - a user's code: whatever it raises is its error
            if _passes(exc):
                raise
            raise self._failed("step", _what_failed(exc)) from None
        if pose is None:
            return None
        if not isinstance(pose, Pose) or not pose.single:
            what = "a Pose of several poses" if isinstance(pose, Pose) else f"a {type(pose).__name__}"
            raise self._failed("step", f"it returned {what}; step returns one phonepose.geometry.Pose, or None")
        if not is_finite(pose):
            raise self._failed("step", "it returned a pose with NaN/inf values; return None when there is no pose")
        return pose

    def __getattr__(self, attr: str) -> Any:
        if attr.startswith("__") or attr == "tracker":   # never for copy/pickle's probes, nor before __init__
            raise AttributeError(attr)
        return getattr(self.tracker, attr)

    def __repr__(self) -> str:
        return f"{self.name}({self.ref}, {_class_name(self.tracker)})"


def _user_tracker(ref: str, factory: Callable[[], object]) -> Tracker:
    """A user's tracker, built without arguments and checked against the protocol before any tick."""
    try:
        tracker: Any = factory()   # a user's object, checked against the protocol below
    except BaseException as exc:  # noqa: BLE001 - a user's constructor: whatever it raises (or exits with) is its error
        if _passes(exc):
            raise
        raise ConfigError(f"tracker {ref!r} ({_class_name(factory)}): could not be created: "
                          f"{_what_failed(exc)}") from None
    values: dict[str, Any] = {}
    for attr in TRACKER_PROTOCOL:   # read once, here: a property that raises (or exits) is one line too
        try:
            values[attr] = getattr(tracker, attr)
        except AttributeError:
            pass
        except BaseException as exc:   # noqa: BLE001 - a property of a user's object
            if _passes(exc):
                raise
            raise ConfigError(f"tracker {ref!r} ({_class_name(tracker)}): reading its {attr} failed: "
                              f"{_what_failed(exc)}") from None
    missing = [a for a in TRACKER_PROTOCOL if a not in values]
    if missing:
        raise ConfigError(f"tracker {ref!r} is not a phonepose tracker: it has no {', '.join(missing)} "
                          "(docs/writing-a-tracker.md)")
    who = f"tracker {ref!r} ({_class_name(tracker)})"
    name = check_tracker_name(values["name"], who)
    flags = {}
    for attr in ("needs_camera", "uses_vio_samples"):
        value = values[attr]
        if not isinstance(value, (bool, int, np.bool_)):   # True/False (1/0 read the same); not a method, not a string
            raise ConfigError(f"{who}: its {attr} is {_kind(value)}: expected True or False")
        flags[attr] = bool(value)
    return UserTracker(ref, tracker, name, flags["needs_camera"], flags["uses_vio_samples"])


def is_user_tracker(name: str) -> bool:
    """Whether ``name`` refers to a user's tracker (module:Class or an installed entry point), not T1-T8."""
    return ":" in name or (name not in TRACKERS and str(name).upper() not in TRACKERS and name in _entry_points())


def make_tracker(name: str, correction_math: CorrectionMath | str = "paper",
                 cm1_reading: CM1Reading | str = CM1Reading.CONSISTENT) -> Tracker:
    """A built-in tracker by name, or a user's: ``package.module:ClassName`` or an installed entry point's name."""
    spec = TRACKERS.get(name) or TRACKERS.get(str(name).upper())
    if spec is None:
        if ":" in name:
            return _user_tracker(name, _import_reference(name))
        ep = _entry_points().get(name)
        if ep is None:
            installed = "".join(f", {n}" for n in sorted(_entry_points()))
            raise ConfigError(f"unknown tracker {name!r}; valid: {', '.join(tracker_names())}{installed}, all, paper, "
                              "or package.module:ClassName")
        try:
            factory = ep.load()
        except Exception as exc:  # noqa: BLE001 - an installed package's import: its error, in one line
            raise ConfigError(f"tracker {name!r} ({ep.value}): cannot load: {type(exc).__name__}: {exc}") from None
        return _user_tracker(name, factory)
    math = CorrectionMath.parse(correction_math)
    reading = CM1Reading.parse(cm1_reading)
    if spec.factory is not None:
        return spec.factory(spec, math, reading)
    return CompositeTracker(spec, math, reading)


def expand_names(names: Iterable[str] | str) -> list[str]:
    """What the user named, one tracker each: ``"all"`` is every registered one (T1-T7, then ours),
    ``"paper"`` T1-T7; a list and/or comma-separated strings (``"T1,T7"``, ``["T1", "T4,T8"]``)."""
    names = split_names(names)
    if any(n.lower() == "all" for n in names):
        names = tracker_names() + [n for n in names if is_user_tracker(n)]
    elif any(n.lower() == "paper" for n in names):
        names = list(PAPER_TRACKERS) + [n for n in names if is_user_tracker(n)]
    if not names:
        raise ConfigError(f"no tracker given; valid: {', '.join(tracker_names())}, all")
    return names


def make_trackers(names: Iterable[str] | str = "all", correction_math: CorrectionMath | str = "paper",
                  cm1_reading: CM1Reading | str = CM1Reading.CONSISTENT) -> list[Tracker]:
    """Trackers by name (:func:`expand_names`), built-in or a user's (:func:`make_tracker`)."""
    refs = expand_names(names)
    trackers = [make_tracker(n, correction_math, cm1_reading) for n in refs]
    check_unique_names([t.name for t in trackers], refs)
    return trackers


def _fused(spec: TrackerSpec, math: CorrectionMath, reading: CM1Reading) -> Tracker:
    return FusedTracker(spec.name)


register(TrackerSpec("T7L", MARKER, VIO, CorrectionKind.CM3,
                     "ours: T7 with a latency-aware CM3 (VIO paired by capture time, predicted to now)",
                     factory=LatencyAwareCM3Tracker))
register(TrackerSpec("T8", MARKER, VIO, CorrectionKind.CM3,
                     "ours: fused (ESKF on the correction + VIO time offset, gyro, gated, continuous output)",
                     factory=_fused))
