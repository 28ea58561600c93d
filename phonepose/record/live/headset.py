"""The headset page's messages turned into the session's ground truth: :class:`HeadsetGroundTruth`.

A WebXR headset (Meta Quest, Pico, ...) opens the headset page (static/headset.html); every XR frame
it sends its viewer pose and each controller's grip pose in one stationary reference space
(server.py ``xrframe``). The controller fixed to the phone (``record live --gt-controller``, the
paper's L-sensor) becomes ``/gt/controller/pose``, the other one (on the board: the R-sensor)
``/gt/board_controller/pose``, the viewer ``/gt/headset/pose``; all in :data:`Frame.GT_WORLD`
(webxr.py converts the axes), stamped with the frame's time on the recorder clock, which is also
their log time: the clock ``calibrate-gt`` and playback associate the ground truth on. No
``/gt/calibration`` is written: ``calibrate-gt`` estimates how that world, the grip and the clock
tie to the display (docs/recording-real-sessions.md).

Tracking: a controller (or the viewer) that has no pose in a frame leaves a gap in its topic (nothing
is made up); the first gap is logged when it begins, every gap is counted and the closing summary
gives their number and duration. A session without the phone's controller says so once.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from phonepose.errors import keyword
from phonepose.record.live.webxr import xr_to_gt_world
from phonepose.schemas.topics import Frame as F
from phonepose.schemas.topics import Topic
from phonepose.session.codec import pose_in_frame
from phonepose.text import printable

TEXT_LIMIT = 200   # characters of a page's text (user agent, reason, space, dictionary) shown in a log line
SESSION_LINES = 3  # immersive session starts (and ends) logged per connection (then only counted)

GT_HANDS = ("right", "left")
CONTROLLER_GRACE_NS = 1_000_000_000    # controllers may appear a little after the XR session starts


def other_hand(hand: str) -> str:
    return "left" if hand == "right" else "right"


def device_of(user_agent: str) -> str:
    """``Quest 3, OculusBrowser/33.0`` from a headset browser's user agent (the device is the last item of
    its first parenthesis, the browser its XR browser's product token); the raw agent, cut, otherwise."""
    paren = re.search(r"\(([^)]*)\)", user_agent)
    device = paren.group(1).split(";")[-1].strip() if paren else ""
    browser = re.search(r"(OculusBrowser|PicoBrowser|Wolvic|HeadlessChrome|Firefox|Chrome)/\d+(?:\.\d+)*", user_agent)
    parts = [p for p in (device, browser.group(0) if browser else "") if p]
    return ", ".join(parts) if parts else (user_agent[:60] or "unknown browser")


@dataclass
class _Track:
    """Where one body's poses are missing: gaps between the last pose before and the first after."""

    what: str
    last_ns: int | None = None        # the last pose's capture time
    lost_ns: int | None = None        # set while the body is not tracked: the last pose before the gap
    gaps: int = 0
    total_ns: int = 0
    longest_ns: int = 0

    def update(self, capture_ns: int, tracked: bool) -> str | None:
        """One frame; returns "lost" when a first gap begins, "back" at the end of a gap."""
        if tracked:
            event = None
            if self.lost_ns is not None:
                self._close(capture_ns)
                event = "back"
            self.last_ns = capture_ns
            return event
        if self.last_ns is not None and self.lost_ns is None:
            self.lost_ns = self.last_ns
            return "lost"
        return None

    def _close(self, end_ns: int) -> None:
        assert self.lost_ns is not None
        d = end_ns - self.lost_ns
        self.gaps += 1
        self.total_ns += d
        self.longest_ns = max(self.longest_ns, d)
        self.lost_ns = None

    def summary(self) -> str | None:
        """The closing line, if tracking was ever lost (a gap still open at the end counts to the last frame)."""
        if self.lost_ns is not None and self.last_ns is not None:
            self._close(max(self.last_ns, self.lost_ns))
        if not self.gaps:
            return None
        return (f"{self.what}: tracking lost {self.gaps} time(s), {self.total_ns / 1e9:.2f} s in all (longest "
                f"{self.longest_ns / 1e9:.2f} s): the ground truth has gaps there")


class HeadsetGroundTruth:
    """What the headset connection reports, as ``/gt/...`` records through the recording's ``emit``/``log``."""

    def __init__(self, recording, gt_hand: str = "right") -> None:
        if gt_hand not in GT_HANDS:
            from phonepose.errors import ConfigError

            raise ConfigError(f"{{gt_controller}} {gt_hand!r}: expected right or left", parameter="gt_controller",
                              value=gt_hand, expected="right or left")
        self.rec = recording
        self.gt_hand = gt_hand
        self.board_hand = other_hand(gt_hand)
        self.source = ""                               # SessionInfo.ground_truth_source, once a headset said hello
        self.tracks = {gt_hand: _Track(f"{gt_hand} controller (on the phone)"),
                       self.board_hand: _Track(f"{self.board_hand} controller (on the board)"),
                       "viewer": _Track("headset (viewer)")}
        self.topics = {gt_hand: Topic.GT_CONTROLLER_POSE, self.board_hand: Topic.GT_BOARD_CONTROLLER_POSE,
                       "viewer": Topic.GT_HEADSET_POSE}
        self.first_frame_ns: int | None = None
        self.hands_seen: set[str] = set()
        self.warned: set[str] = set()
        self.frames = 0

    # ------------------------------------------------------------------ messages
    def on_hello(self, who: str, msg: dict) -> None:
        ua = msg["user_agent"] or "unknown browser"
        shown, reason = printable(ua, TEXT_LIMIT), printable(msg["message"] or "no reason given", TEXT_LIMIT)
        if msg["webxr"]:
            self.rec.log(f"{who}: {shown}; WebXR immersive-vr available")
        else:
            self.rec.log(f"{who}: {shown}; no WebXR immersive-vr ({reason}): no ground "
                         "truth will come from this page (open the headset link in the headset's own browser)",
                         level="warning")
        source = f"webxr-headset ({device_of(ua)}, {self.gt_hand} controller)"
        if source != self.source:
            self.source = source
            self.rec.ground_truth_source_changed(source)

    def on_session(self, who: str, msg: dict) -> None:
        message = printable(msg["message"], TEXT_LIMIT)
        if msg["state"] == "ended":
            self.rec.limited(who, "immersive session ends", f"the immersive session ended"
                             f"{': ' + message if message else ''}", limit=SESSION_LINES)
            return
        note = f" ({message})" if message else ""
        level = "info" if msg["space"] == "local-floor" else "warning"
        self.rec.limited(who, "immersive session starts", f"immersive-vr session started, poses in its "
                         f"'{printable(msg['space'], TEXT_LIMIT)}' reference space{note}", level=level,
                         limit=SESSION_LINES)

    def on_frame(self, who: str, capture_ns: int, viewer, controllers) -> None:
        self.frames += 1
        if self.first_frame_ns is None:
            self.first_frame_ns = capture_ns
        poses = {"viewer": viewer}
        for hand, pose in controllers:
            if hand in GT_HANDS:
                self.hands_seen.add(hand)
                poses.setdefault(hand, pose)      # a second source of one hand (hand tracking beside it): the first
        for body, topic in self.topics.items():
            pose = poses.get(body)
            if pose is not None:
                T = xr_to_gt_world(*pose)
                self.rec.check_order(topic, capture_ns)
                self.rec.stats[topic] += 1
                self.rec.emit(topic, pose_in_frame(T, F.GT_WORLD, capture_ns), capture_ns)
            event = self.tracks[body].update(capture_ns, pose is not None)
            if event == "lost" and body not in self.warned:
                self.warned.add(body)
                t = (capture_ns - self.first_frame_ns) / 1e9
                self.rec.log(f"{who}: {self.tracks[body].what} lost tracking {t:.1f} s into the XR session: "
                             f"{topic} has a gap until it is tracked again (gaps are counted, closing summary)",
                             level="warning")
        self._check_controllers(who, capture_ns, controllers)

    def _check_controllers(self, who: str, capture_ns: int, controllers) -> None:
        """Once, after the grace period: no controller at all, or not the phone's."""
        assert self.first_frame_ns is not None
        if capture_ns - self.first_frame_ns < CONTROLLER_GRACE_NS or self.gt_hand in self.hands_seen:
            return
        if not self.hands_seen and "none" not in self.warned:
            self.warned.add("none")
            self.rec.log(f"{who}: the XR session has no controllers: no ground truth for the phone (turn the "
                         f"{self.gt_hand} controller on, or press one of its buttons)", level="warning")
        elif self.hands_seen and "hand" not in self.warned:
            self.warned.add("hand")
            self.rec.log(f"{who}: no {self.gt_hand} controller in the XR session (only "
                         f"{', '.join(sorted(self.hands_seen))}): the phone's controller is {keyword('gt_controller')} "
                         f"{self.gt_hand}; turn it on, or record with {keyword('gt_controller')} "
                         f"{other_hand(self.gt_hand)}",
                         level="warning")

    # ------------------------------------------------------------------ end
    def summary(self) -> list[str]:
        if not self.frames:
            return []
        lines = [line for line in (t.summary() for t in self.tracks.values()) if line]
        if self.gt_hand not in self.hands_seen:
            lines.append(f"the headset sent {self.frames} XR frames but never the {self.gt_hand} controller: "
                         f"no {Topic.GT_CONTROLLER_POSE}")
        return lines
