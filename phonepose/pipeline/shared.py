"""The stages every tracker shares, run once per tick: image decode, marker recognition,
anchor mapping. Their output, one :class:`Observation`, is what every tracker steps on.

Image reuse: the paper recognises the marker per camera frame. When a tick carries the same
frame as the previous tick (``Frame.is_new`` False), the previous frame's recognition is reused instead of decoding and
detecting again, so a frame counts as
"in view" for every tick that carries it.

A recognised marker needs the display pose to be placed in display_vio; while the display
pose is unknown the marker is reported as not in view (``Observation.marker`` None).

Look-ahead: ``prefetch(tick)`` starts a tick's decode on one worker thread and its recognition on
another, so that both run while the caller steps the trackers and writes the outputs of the ticks
before it (OpenCV releases the GIL in ``imdecode`` and ``detectMarkers``, which are ~80 % of a
playback on a session with a camera). Recognition is a chain (each frame's crop follows from the
last one's marker), decoding is not: the next frame is decoded while this one is recognised. The
recognition worker takes the frames one after the other in tick order, exactly as ``process`` does
without it, so the results are the same bits; ``process`` of a prefetched tick waits for its result.
Measured on exp1 (docs/performance.md): the playback's wall time falls by the trackers' and outputs'
share when a second core is free, and by 10-15 % more with the decode on its own thread.
"""

from __future__ import annotations

import logging
from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor

import cv2
import numpy as np

from phonepose.pipeline.anchors import AnchorMap
from phonepose.pipeline.markers import MarkerRecognizer
from phonepose.pipeline.types import Frame, MarkerObservation, Observation, SessionContext, Tick
from phonepose.topics import Topic


def decode_gray(image: Frame) -> np.ndarray | None:
    """Grayscale pixels of a frame (JPEG/PNG; anything with ``.data``), decoded once; None if undecodable.

    The pixels as stored: an EXIF orientation (another tool's JPEG) is not applied. The calibration describes the
    stored pixels, and OpenCV's default rotation of them (a 180° tag made T4's p_ATE 20x worse) or a turn to
    portrait put every marker where the camera never saw it."""
    data = np.frombuffer(image.data, dtype=np.uint8)
    if data.size == 0:
        return None
    return cv2.imdecode(data, cv2.IMREAD_GRAYSCALE | cv2.IMREAD_IGNORE_ORIENTATION)


def frame_size_problem(gray: np.ndarray, camera) -> str | None:
    """Why a decoded frame cannot be used with ``camera``'s calibration (another size), or None."""
    h, w = gray.shape[:2]
    if (w, h) == (camera.width, camera.height):
        return None
    return f"{w}x{h} px, not the calibration's {camera.width}x{camera.height}"


def warn_wrong_size(count: int, first: str) -> None:
    """The one warning line for ``count`` frames of another size than the calibration (``first``: what
    :func:`frame_size_problem` said of the first): playback and calibrate-gt say it alike."""
    if count:
        logging.getLogger("phonepose").warning(
            "%s: %d camera frame(s) are %s; they count as showing no marker",
            Topic.CAMERA_IMAGE, count, first)


class SharedStages:
    """``process(tick) -> Observation``, once per tick, in tick order (causal)."""

    def __init__(self, context: SessionContext):
        self.context = context
        # a session without camera images may have no marker spec at all: nothing is recognised then
        self.recognizer = MarkerRecognizer(context.camera, context.marker) if context.marker.dictionary else None
        self.anchor_map = AnchorMap()
        # Map every received VIO sample into display_vio (Observation.controller_vio_samples_dvio).
        # Only trackers with ``uses_vio_samples`` (T8) read them; the engine switches this off
        # when none runs, since it costs ~0.2 ms per tick.
        self.map_vio_samples = True
        self._worker: ThreadPoolExecutor | None = None     # recognition, started by the first prefetch
        self._decoder: ThreadPoolExecutor | None = None    # JPEG decoding, a frame or more ahead of it
        self._pending: deque[tuple[Tick, Future]] = deque()
        self.reset()

    def reset(self) -> None:
        self._drain()
        if self.recognizer is not None:
            self.recognizer.reset()
        self._last_marker: MarkerObservation | None = None
        self.frames_decoded = 0
        self.frames_undecodable = 0   # reported once by the caller (docs/reliability.md)
        self.frames_wrong_size = 0    # decoded, but not of the calibration's size (reported once by the caller)
        self.wrong_size = ""          # the first such frame's size, for that report

    def _recognize(self, tick: Tick, decoded: Future | None = None) -> MarkerObservation | None:
        """The tick's marker; ``decoded``: its new frame's pixels being decoded by ``prefetch``."""
        frame = tick.frame
        if frame is None or self.recognizer is None:   # (a session with images has a marker spec: context.py)
            return None
        if not frame.is_new:
            return self._last_marker
        gray = decoded.result() if decoded is not None else decode_gray(frame)
        self.frames_decoded += 1
        marker = None
        problem = None if gray is None else frame_size_problem(gray, self.context.camera)
        if gray is None:
            self.frames_undecodable += 1
        elif problem is not None:
            self.frames_wrong_size += 1
            self.wrong_size = self.wrong_size or problem
        else:
            marker = self.recognizer.recognize(gray, frame.T_dvio_display, frame.t_ns)
        self._last_marker = marker
        return marker

    def prefetch(self, tick: Tick) -> None:
        """Start ``tick``'s recognition on the worker thread; ticks come in order, each once, and
        are then processed in the same order."""
        if self._worker is None or self._decoder is None:
            self._worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="phonepose-recognition")
            self._decoder = ThreadPoolExecutor(max_workers=1, thread_name_prefix="phonepose-decode")
        frame = tick.frame
        decoded = self._decoder.submit(decode_gray, frame) if frame is not None and frame.is_new else None
        self._pending.append((tick, self._worker.submit(self._recognize, tick, decoded)))

    def close(self) -> None:
        """Stop the worker threads (a prefetched tick not processed yet is dropped)."""
        self._drain()
        for pool in (self._worker, self._decoder):
            if pool is not None:
                pool.shutdown(wait=True, cancel_futures=True)
        self._worker = self._decoder = None

    def _drain(self) -> None:
        while self._pending:
            _tick, future = self._pending.popleft()
            if not future.cancel():
                future.exception()   # waits for the running one: the recognizer is never shared mid-frame

    def process(self, tick: Tick) -> Observation:
        if self._pending:
            ahead, future = self._pending.popleft()
            if ahead is not tick:
                raise RuntimeError("SharedStages.process: ticks must be processed in the order they were prefetched")
            marker = future.result()
        else:
            marker = self._recognize(tick)
        if marker is not None and marker.T_dvio_controller is None:
            marker = None  # cannot be placed in display_vio without the display pose
        vio = self.anchor_map(tick.T_dvio_anchor, tick.T_cvio_anchor, tick.T_cvio_controller)
        samples = []
        for capture_ns, T_cvio_controller in (tick.controller_vio_samples if self.map_vio_samples else ()):
            mapped = self.anchor_map(tick.T_dvio_anchor, tick.T_cvio_anchor, T_cvio_controller)
            if mapped is not None:
                samples.append((capture_ns, mapped))
        return Observation(tick=tick, marker=marker, T_dvio_controller_vio=vio, controller_vio_samples_dvio=samples)
