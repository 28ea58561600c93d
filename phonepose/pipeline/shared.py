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
With a second core free, the playback's wall time falls by the trackers' and outputs' share, and further
with the decode on its own thread (docs/performance.md#where-a-playbacks-time-goes).
"""

from __future__ import annotations

import contextlib
import io
import logging
import os
import struct
import sys
import tempfile
import threading
import warnings
from collections import deque
from collections.abc import Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass

import cv2
import numpy as np

from phonepose.pipeline.anchors import AnchorMap
from phonepose.pipeline.markers import MarkerRecognizer
from phonepose.pipeline.types import Frame, MarkerObservation, Observation, SessionContext, Tick
from phonepose.topics import Topic

# The most pixels phonepose decodes in one image: 80 Mpx holds any phone camera's photo (64 Mpx) and stays below the
# size at which Pillow warns of a decompression bomb; a header claiming 20000x20000 px made a playback decode 400 Mpx
# per frame (~870 MB), one claiming 65500x65500 px failed in OpenCV's validateInputImageSize.
MAX_DECODE_PIXELS = 80_000_000
UNDECODABLE = "could not be decoded"


@dataclass(frozen=True)
class Decoded:
    """What :func:`decode_gray` made of an encoded image."""

    gray: np.ndarray | None           # the grayscale pixels as stored; None: not decoded (``problem`` says why)
    problem: str = ""                 # why there are no pixels: UNDECODABLE, or a size (of the header, never decoded)
    wrong_size: bool = False          # ``problem`` is that the header's size is not the one expected
    damaged: str = ""                 # the decoder's own diagnostic ("Corrupt JPEG data: ..."): decoded as far as it goes


# image_size's answer for a header claiming more than twice Pillow's own limit (178 Mpx), whose size Pillow keeps
HUGE = (-1, -1)
_pillow_quiet: list[bool] = []      # whether Pillow's own warning is filtered yet (once, on the first header read)


def image_size(data: bytes) -> tuple[int, int] | None:
    """(width, height) from an encoded image's header (JPEG, PNG, BMP, TIFF, WebP), read by Pillow without decoding
    any pixel; :data:`HUGE` beyond 178 Mpx; None when it is no image Pillow knows."""
    from PIL import Image, UnidentifiedImageError

    if not _pillow_quiet:
        # its warning of a header above 89 Mpx: decode_gray refuses such an image in its own line
        warnings.filterwarnings("ignore", category=Image.DecompressionBombWarning)
        _pillow_quiet.append(True)
    try:
        with Image.open(io.BytesIO(data)) as image:
            return int(image.size[0]), int(image.size[1])
    except Image.DecompressionBombError:
        return HUGE
    except (UnidentifiedImageError, OSError, ValueError, SyntaxError, struct.error, EOFError):
        return None


def decode_gray(data: bytes, expected: tuple[int, int] | None = None) -> Decoded:
    """The one place phonepose decodes an image (playback's camera frames, calibrate-gt's sightings, calibrate-camera's
    photos): its size comes from its header first, and an image of another size than ``expected`` (width, height) or
    of more than :data:`MAX_DECODE_PIXELS` is never decoded. The decoder's own diagnostics are kept off the terminal
    (:func:`c_stderr_captured`) and returned in ``damaged``.

    The pixels as stored: an EXIF orientation (another tool's JPEG) is not applied. The calibration describes the
    stored pixels, and OpenCV's default rotation of them (a 180° tag made T4's p_ATE 20x worse) or a turn to
    portrait put every marker where the camera never saw it."""
    size = image_size(data) if len(data) else None
    if size is None:
        return Decoded(None, UNDECODABLE)
    shown = "more than 178 Mpx" if size == HUGE else f"{size[0]}x{size[1]} px"
    if expected is not None and size != tuple(expected):
        return Decoded(None, f"{shown}, not the calibration's {expected[0]}x{expected[1]}", True)
    if size == HUGE or size[0] * size[1] > MAX_DECODE_PIXELS:
        return Decoded(None, f"{shown} by its header, more than the {MAX_DECODE_PIXELS // 1_000_000} Mpx phonepose "
                             "decodes")
    with c_stderr_captured() as said:
        try:
            gray = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_GRAYSCALE | cv2.IMREAD_IGNORE_ORIENTATION)
        except cv2.error:
            gray = None
    damaged = said[0] if said else ""
    if gray is None:
        return Decoded(None, UNDECODABLE, damaged=damaged)
    if (gray.shape[1], gray.shape[0]) != size:    # the header lied to one of the two readers
        return Decoded(None, f"{gray.shape[1]}x{gray.shape[0]} px, not its header's {size[0]}x{size[1]}", damaged=damaged)
    return Decoded(gray, damaged=damaged)


# What C decoders write straight to the process's stderr, past OpenCV's log level: libjpeg's warnings
# ("Corrupt JPEG data: ...", "Premature end of JPEG file"), libpng's, and OpenCV's own log lines.
_C_DIAGNOSTICS = (b"Corrupt JPEG data", b"Premature end of JPEG file", b"Invalid SOS parameters", b"Inconsistent "
                  b"progression", b"Unsupported marker", b"Bogus ", b"Warning: ", b"libpng ", b"[ WARN:", b"[ INFO:",
                  b"[ERROR:", b"[DEBUG:")
_stderr_lock = threading.Lock()
_capture: dict = {}      # process id: the temporary file descriptor 2 points at during a decode, emptied after each


@contextlib.contextmanager
def c_stderr_captured() -> Iterator[list[str]]:
    """The decoders' lines to file descriptor 2 during the block, kept off the terminal and listed (first one first).

    libjpeg prints its warnings with fprintf(stderr), which no OpenCV setting turns off, so descriptor 2 is pointed at
    a temporary file for the block (os.dup2: POSIX and Windows alike). Whatever else reached it meanwhile (another
    thread's output) is written on to the real stderr afterwards, in order; one block at a time."""
    said: list[str] = []
    with _stderr_lock:
        if os.getpid() not in _capture:     # one a process (a forked worker's own: a shared one shares its offset)
            _capture[os.getpid()] = tempfile.TemporaryFile()
        capture = _capture[os.getpid()]
        try:
            sys.stderr.flush()
            saved = os.dup(2)
        except (OSError, ValueError, AttributeError):    # no descriptor 2 (a GUI process): nothing can reach a terminal
            yield said
            return
        try:
            os.dup2(capture.fileno(), 2)
            yield said
        finally:
            with contextlib.suppress(OSError, ValueError, AttributeError):
                sys.stderr.flush()
            os.dup2(saved, 2)
            os.close(saved)
            _sort_captured(capture, said)


def _sort_captured(capture, said: list[str]) -> None:
    """The decoders' lines of ``capture`` into ``said``; every other byte on to the real stderr; ``capture`` emptied."""
    if not os.lseek(capture.fileno(), 0, os.SEEK_END):
        return
    capture.seek(0)
    text = capture.read()
    capture.seek(0)
    capture.truncate()
    others = []
    for line in text.splitlines(keepends=True):
        if line.startswith(_C_DIAGNOSTICS):
            said.append(line.decode("utf-8", "replace").strip())
        else:
            others.append(line)
    if others:
        with contextlib.suppress(OSError):
            os.write(2, b"".join(others))


def warn_damaged(count: int, first: str) -> None:
    """The one warning line for ``count`` frames the decoder called damaged (``first``: what it said of the first)."""
    if count:
        logging.getLogger("phonepose").warning(
            "%s: %d camera frame(s) hold damaged image data (%s); decoded as far as it goes",
            Topic.CAMERA_IMAGE, count, first)


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
        # when none runs (docs/performance.md#per-tick-cost-of-the-trackers).
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
        self.frames_damaged = 0       # decoded as far as they go, the decoder said why (reported once by the caller)
        self.damaged = ""             # what it said of the first

    def _decode(self, frame: Frame) -> Decoded:
        return decode_gray(frame.data, (self.context.camera.width, self.context.camera.height))

    def _recognize(self, tick: Tick, decoded: Future | None = None) -> MarkerObservation | None:
        """The tick's marker; ``decoded``: its new frame's pixels being decoded by ``prefetch``."""
        frame = tick.frame
        if frame is None or self.recognizer is None:   # (a session with images has a marker spec: context.py)
            return None
        if not frame.is_new:
            return self._last_marker
        image = decoded.result() if decoded is not None else self._decode(frame)
        self.frames_decoded += 1
        marker = None
        if image.damaged:
            self.frames_damaged += 1
            self.damaged = self.damaged or image.damaged
        if image.wrong_size:
            self.frames_wrong_size += 1
            self.wrong_size = self.wrong_size or image.problem
        elif image.gray is None:
            self.frames_undecodable += 1
        else:
            marker = self.recognizer.recognize(image.gray, frame.T_dvio_display, frame.t_ns)
        self._last_marker = marker
        return marker

    def prefetch(self, tick: Tick) -> None:
        """Start ``tick``'s recognition on the worker thread; ticks come in order, each once, and
        are then processed in the same order."""
        if self._worker is None or self._decoder is None:
            self._worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="phonepose-recognition")
            self._decoder = ThreadPoolExecutor(max_workers=1, thread_name_prefix="phonepose-decode")
        frame = tick.frame
        decoded = self._decoder.submit(self._decode, frame) if frame is not None and frame.is_new else None
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
