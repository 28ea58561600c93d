"""The display camera of ``record live``: OpenCV's VideoCapture on a device index or a video file.

- **Device** (``--camera 0``): asks for MJPG at the calibration's resolution and for the raw
  buffers (``CAP_PROP_CONVERT_RGB = 0``), so the JPEG bytes the camera produced are kept as they
  are. When the backend hands out decoded frames instead, or a JPEG without Huffman tables (many
  webcams omit them; not every decoder supplies the standard ones), the frame is encoded again
  (quality :data:`JPEG_QUALITY`). A frame is stamped with the V4L2 buffer time when the backend
  reports a plausible one (``CAP_PROP_POS_MSEC`` on the monotonic clock, within 1 s before now),
  else when ``read()`` returns (later than the exposure by the driver and USB latency).
- **File** (``--camera video.mp4``): frames are encoded as JPEG and stamped with the file's frame
  times (``CAP_PROP_POS_MSEC``, else index / fps) offset to the recording's start; read in real
  time (``pace=True``, what a phone's samples line up with) or as fast as possible.
"""

from __future__ import annotations

import contextlib
import os
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from phonepose.errors import ConfigError, InputFileError
from phonepose.record.live.clock import RecorderClock

JPEG_QUALITY = 95
DEFAULT_FPS = 30.0


@dataclass
class Frame:
    t_ns: int          # capture time on the recorder clock
    jpeg: bytes
    reencoded: bool    # True: encoded by us (not the camera's own bytes)


def _has_huffman_tables(data: bytes) -> bool:
    """A complete baseline JPEG: SOI, and a DHT segment before the start of scan."""
    if data[:2] != b"\xff\xd8":
        return False
    sos = data.find(b"\xff\xda")
    return sos > 0 and data.find(b"\xff\xc4", 0, sos) > 0


def encode_jpeg(image: np.ndarray, quality: int = JPEG_QUALITY) -> bytes:
    ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:   # pragma: no cover - cannot happen for a uint8 image
        raise InputFileError("could not encode a camera frame as JPEG")
    return buf.tobytes()


@contextlib.contextmanager
def _opencv_quiet():
    try:
        old = cv2.utils.logging.getLogLevel()
        cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)
    except AttributeError:   # pragma: no cover - builds without the logging utils
        yield
        return
    try:
        yield
    finally:
        cv2.utils.logging.setLogLevel(old)


class Camera:
    """One VideoCapture; :meth:`read` returns the next :class:`Frame` or None at the end of a file."""

    def __init__(self, spec: str | int, clock: RecorderClock, width: int, height: int, pace: bool = True):
        self.spec = str(spec)
        self.clock = clock
        self.pace = pace
        self.is_device = isinstance(spec, int) or self.spec.isdigit()
        if self.is_device:
            with _opencv_quiet():   # a missing device is our one-line error, not OpenCV's warnings
                cap = cv2.VideoCapture(int(self.spec))
            if not cap.isOpened():
                raise InputFileError(f"camera {self.spec}: cannot open it (no such device, or another program uses it)")
            cap.set(cv2.CAP_PROP_FOURCC, cv2.VideoWriter.fourcc(*"MJPG"))
            cap.set(cv2.CAP_PROP_FRAME_WIDTH, width)
            cap.set(cv2.CAP_PROP_FRAME_HEIGHT, height)
            cap.set(cv2.CAP_PROP_CONVERT_RGB, 0)
            fourcc = int(cap.get(cv2.CAP_PROP_FOURCC)) & 0xFFFFFFFF
            if fourcc.to_bytes(4, "little") != b"MJPG":   # no MJPG mode: take decoded BGR frames, encode them
                cap.set(cv2.CAP_PROP_CONVERT_RGB, 1)
        else:
            if not os.path.isfile(self.spec):
                raise InputFileError(f"{self.spec}: no such video file (or give a camera index such as 0)")
            from phonepose.calibration.calibrate import opencv_path

            cap = cv2.VideoCapture(opencv_path(Path(self.spec), "a video"))   # a non-UTF-8 name: refused, not a SIGSEGV
            if not cap.isOpened():
                raise InputFileError(f"{self.spec}: OpenCV cannot read this video file")
        self.cap = cap
        fps = cap.get(cv2.CAP_PROP_FPS)
        self.fps = fps if np.isfinite(fps) and 1.0 <= fps <= 1000.0 else DEFAULT_FPS
        self.frames = 0
        self.reencoded = 0
        self._first_file_ms: float | None = None
        self._last_file_ms: float | None = None
        self._start_ns: int | None = None
        self._start_mono: int | None = None
        self._last_t_ns: int | None = None
        self._peek: Frame | None = None
        first = self._read()
        if first is None:
            raise InputFileError(f"camera {self.spec}: delivers no frames")
        size = self.size
        if size != (width, height):
            raise ConfigError(f"camera {self.spec} gives {size[0]}x{size[1]} frames but the calibration is for "
                              f"{width}x{height}: calibrate the camera at this resolution")
        self._peek = first

    # ------------------------------------------------------------------ frames
    def _read(self) -> Frame | None:
        ok, data = self.cap.read()
        now_mono = time.monotonic_ns()
        if not ok or data is None:
            return None
        raw = data.reshape(-1) if (data.ndim == 1 or (data.ndim == 2 and data.shape[0] == 1)) else None
        if raw is not None and raw.dtype == np.uint8 and _has_huffman_tables(raw[:65536].tobytes()):
            jpeg, reencoded = raw.tobytes(), False
            if self.frames == 0:
                img = cv2.imdecode(raw, cv2.IMREAD_GRAYSCALE)
                if img is None:
                    return None
                self.size = (img.shape[1], img.shape[0])
        else:
            if raw is not None:   # compressed but incomplete (no DHT): decode, encode again
                img = cv2.imdecode(raw, cv2.IMREAD_COLOR)
                if img is None:
                    return None
            elif data.ndim == 3 and data.shape[2] == 2:   # raw YUYV despite CONVERT_RGB (some backends)
                img = cv2.cvtColor(data, cv2.COLOR_YUV2BGR_YUYV)
            else:
                img = data
            if self.frames == 0:
                self.size = (img.shape[1], img.shape[0])
            jpeg, reencoded = encode_jpeg(img), True
            self.reencoded += 1
        self.frames += 1
        return Frame(self._stamp(now_mono), jpeg, reencoded)

    def _stamp(self, now_mono: int) -> int:
        if self.is_device:
            t = self.clock.from_monotonic_ns(now_mono)
            pos = self.cap.get(cv2.CAP_PROP_POS_MSEC)
            if np.isfinite(pos) and pos > 0:
                buf_mono = int(pos * 1e6)
                if 0 <= now_mono - buf_mono <= 1_000_000_000:
                    t = self.clock.from_monotonic_ns(buf_mono)
        else:
            ms = self.cap.get(cv2.CAP_PROP_POS_MSEC)
            if not np.isfinite(ms) or (self._last_file_ms is not None and ms <= self._last_file_ms):
                ms = (self._last_file_ms + 1000.0 / self.fps) if self._last_file_ms is not None else 0.0
            if self._first_file_ms is None:
                self._first_file_ms = ms
                self._start_mono = now_mono
                self._start_ns = self.clock.from_monotonic_ns(now_mono)
            self._last_file_ms = ms
            rel_ns = int(round((ms - self._first_file_ms) * 1e6))
            assert self._start_ns is not None   # set with _first_file_ms
            t = self._start_ns + rel_ns
        if self._last_t_ns is not None and t <= self._last_t_ns:
            t = self._last_t_ns + 1   # frames are strictly ordered on the recorder clock
        self._last_t_ns = t
        return t

    def read(self) -> Frame | None:
        """The next frame (waits for it; a paced file waits until its time), or None at the end."""
        if self._peek is not None:
            frame, self._peek = self._peek, None
        else:
            frame = self._read()
        if frame is not None and not self.is_device and self.pace:
            delay = (frame.t_ns - self.clock.now_ns()) / 1e9
            if delay > 0:
                time.sleep(delay)
        return frame

    def restart_clock(self) -> None:
        """Let a file's first frame be 'now' (called when recording starts, after setup time)."""
        if not self.is_device and self._peek is not None and self._first_file_ms is not None:
            now = self.clock.now_ns()
            shift = now - self._peek.t_ns
            self._peek.t_ns = now
            assert self._start_ns is not None   # set with _first_file_ms
            self._start_ns += shift
            self._last_t_ns = now

    @property
    def start_ns(self) -> int | None:
        """A video file's first frame time on the recorder clock (None for a device)."""
        return self._start_ns

    def close(self) -> None:
        self.cap.release()
