"""The ChArUco calibration board: its definition, its one-line text description, and a printable PNG.

The default board (7 x 5 squares of 30 mm, 22 mm markers, ``DICT_5X5_100``) is 210 x 150 mm, so it
fits a landscape A4 sheet with margins. Its markers come from a 5x5 dictionary, so the phone's
marker (``DICT_4X4_50`` id 7) is never mistaken for part of the board, nor a board marker for it.

The text description (:func:`board_spec`, :func:`parse_board_spec`) is what ``--board`` takes and
what the calibration file stores under ``board``::

    charuco squares=7x5 square_mm=30 marker_mm=22 dictionary=DICT_5X5_100
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np

from phonepose.errors import ConfigError
from phonepose.numbers import show_number

MM_PER_INCH = 25.4

# Paper sizes in mm, landscape (width, height); "fit" = the board plus a margin.
PAPER_MM = {"a4": (297.0, 210.0), "a3": (420.0, 297.0), "letter": (279.4, 215.9)}
FIT_MARGIN_MM = 15.0
FIT_MIN_WIDTH_MM = 140.0   # a "fit" page is at least this wide: the 50 mm bar and its label need ~100 mm
TEXT_HEIGHT_MM = 2.5       # capital letters of the printed description
TEXT_GAP_MM = 4.0          # between the board and the first line of text
LINE_MM = 5.0              # line pitch of the text under the board


# What a printable board can be (BoardSpec checks each value; `phonepose board --help` states them): squares a
# printer or plotter can hold, from 1 mm to 0.5 m, and at most 100 of them a side (OpenCV's samples print 5x7,
# and a 4X4_1000 dictionary holds 1000 markers). square_mm=1e-300 became a SystemError in OpenCV, 100000 a 44 TiB page.
SQUARES_MAX = 100
SQUARE_MM = (1.0, 500.0)
# The most pixels a page is drawn with, checked before it is allocated: A3 at 1200 dpi is 278 Mpx (278 MB of
# grayscale); a 10 m board on --paper fit at 1200 dpi asked for 209 GiB.
MAX_PAGE_PIXELS = 300_000_000


@dataclass(frozen=True)
class BoardSpec:
    """A ChArUco board: ``squares_x`` columns by ``squares_y`` rows of ``square_mm`` squares, with
    ``marker_mm`` ArUco markers of ``dictionary`` in the white squares. ``legacy`` selects OpenCV's
    pre-4.6 layout, which differs only for an even number of rows (boards printed by old OpenCV)."""

    squares_x: int = 7
    squares_y: int = 5
    square_mm: float = 30.0
    marker_mm: float = 22.0
    dictionary: str = "DICT_5X5_100"
    legacy: bool = False

    def __post_init__(self) -> None:
        sx, sy = show_number(self.squares_x), show_number(self.squares_y)
        if not (2 <= self.squares_x <= SQUARES_MAX and 2 <= self.squares_y <= SQUARES_MAX) \
                or self.squares_x * self.squares_y < 6:
            raise ConfigError(f"board squares {sx}x{sy}: expected 2 to {SQUARES_MAX} squares a side, "
                              "at least 6 in all")
        lo, hi = SQUARE_MM
        if not lo <= self.square_mm <= hi:     # NaN too
            raise ConfigError(f"board square_mm={self.square_mm:g}: expected a side in [{lo:g}, {hi:g}] mm "
                              "(what a printer or plotter prints)")
        if not 0 < self.marker_mm < self.square_mm:
            raise ConfigError(f"board marker_mm={self.marker_mm:g}: expected a side in (0, {self.square_mm:g}) mm "
                              "(inside its square, square_mm)")
        n_markers = self.squares_x * self.squares_y // 2
        dict_size = _dictionary(self.dictionary).bytesList.shape[0]
        if n_markers > dict_size:
            raise ConfigError(f"board {self.squares_x}x{self.squares_y} needs {n_markers} markers; "
                              f"{self.dictionary} has only {dict_size}")

    @property
    def n_corners(self) -> int:
        """Inner chessboard corners: what a view can show at most."""
        return (self.squares_x - 1) * (self.squares_y - 1)

    @property
    def size_mm(self) -> tuple[float, float]:
        return self.squares_x * self.square_mm, self.squares_y * self.square_mm

    def opencv(self) -> cv2.aruco.CharucoBoard:
        """OpenCV's board object, in metres (calibration extrinsics come out in metres)."""
        board = cv2.aruco.CharucoBoard((self.squares_x, self.squares_y), self.square_mm / 1000.0,
                                       self.marker_mm / 1000.0, _dictionary(self.dictionary))
        board.setLegacyPattern(self.legacy)
        return board


def _dictionary(name: str) -> cv2.aruco.Dictionary:
    from phonepose.pipeline.markers import aruco_dictionary  # the one place that maps names (ConfigError if unknown)

    return aruco_dictionary(name)


DEFAULT_BOARD = BoardSpec()


def board_spec(board: BoardSpec = DEFAULT_BOARD) -> str:
    """The one-line description of ``board`` that :func:`parse_board_spec` reads back."""
    text = (f"charuco squares={board.squares_x}x{board.squares_y} square_mm={board.square_mm:g} "
            f"marker_mm={board.marker_mm:g} dictionary={board.dictionary}")
    return text + (" legacy=1" if board.legacy else "")


def parse_board_spec(text: str) -> BoardSpec:
    """Read a description written by :func:`board_spec`. Keys may come in any order and any left
    out keep the default board's value; a bad key or value is a ConfigError naming it."""
    words = text.split()
    if words and words[0].lower() == "charuco":
        words = words[1:]
    values: dict = {}
    known = "squares, square_mm, marker_mm, dictionary, legacy"
    for word in words:
        key, sep, value = word.partition("=")
        key = key.lower()
        try:
            if not sep:
                raise ValueError
            if key == "squares":
                sx, sy = value.lower().split("x")
                values["squares_x"], values["squares_y"] = int(sx), int(sy)
            elif key in ("square_mm", "marker_mm"):
                values[key] = float(value)
            elif key == "dictionary":
                values["dictionary"] = value.upper()
            elif key == "legacy":
                values["legacy"] = {"1": True, "true": True, "0": False, "false": False}[value.lower()]
            else:
                raise ConfigError(f"board spec {text!r}: unknown key {key!r} (known: {known})")
        except (ValueError, KeyError):
            raise ConfigError(f"board spec {text!r}: bad {word!r} (expected e.g. "
                              f"'{board_spec(DEFAULT_BOARD)}')") from None
    return replace(DEFAULT_BOARD, **values)


def px_per_mm(dpi: float) -> float:
    return dpi / MM_PER_INCH


def _wrap(words: list[str], fits) -> list[str]:
    """Greedy word wrap: as many ``|``-separated phrases per line as ``fits(line)`` allows."""
    lines: list[str] = []
    for word in words:
        if lines and fits(f"{lines[-1]}  |  {word}"):
            lines[-1] = f"{lines[-1]}  |  {word}"
        else:
            lines.append(word)
    return lines


def render_board(board: BoardSpec = DEFAULT_BOARD, dpi: int = 300, paper: str = "a4") -> np.ndarray:
    """The printable page as a uint8 grayscale image of ``paper`` (landscape, or ``fit``) at ``dpi``.

    The board is centred; below it, lines state the true sizes and a 50 mm bar lets the user
    check with a ruler that the printer did not scale the page.
    """
    if not 50 <= dpi <= 1200:
        raise ConfigError(f"{{dpi}} {dpi}: expected 50..1200", parameter="dpi", value=dpi, expected="50..1200")
    scale = px_per_mm(dpi)
    bw_mm, bh_mm = board.size_mm
    if paper == "fit":
        page_w_mm = max(bw_mm + 2 * FIT_MARGIN_MM, FIT_MIN_WIDTH_MM)
    elif paper in PAPER_MM:
        page_w_mm = PAPER_MM[paper][0]
    else:
        raise ConfigError(f"{{paper}} {paper!r}: expected one of {', '.join([*PAPER_MM, 'fit'])}", parameter="paper",
                          value=paper, expected=f"one of {', '.join([*PAPER_MM, 'fit'])}")

    # The text under the board, wrapped to the board's width (at least the width the bar needs).
    font, thick = cv2.FONT_HERSHEY_SIMPLEX, max(1, round(0.25 * scale))
    font_scale = TEXT_HEIGHT_MM * scale / cv2.getTextSize("X", font, 1.0, 1)[0][1]
    text_w_px = max(bw_mm, FIT_MIN_WIDTH_MM - 2 * FIT_MARGIN_MM) * scale
    phrases = [f"phonepose {board_spec(board)}", f"board {bw_mm:g} x {bh_mm:g} mm",
               f"squares {board.square_mm:g} mm, markers {board.marker_mm:g} mm",
               f"print at 100 % (no 'fit to page'), {dpi} dpi"]
    lines = _wrap(phrases, lambda t: cv2.getTextSize(t, font, font_scale, thick)[0][0] <= text_w_px)
    text_band_mm = TEXT_GAP_MM + LINE_MM * (len(lines) + 1)

    page_h_mm = bh_mm + 2 * FIT_MARGIN_MM + text_band_mm if paper == "fit" else PAPER_MM[paper][1]
    margin_y = (page_h_mm - bh_mm - text_band_mm) / 2
    text_x_mm = (page_w_mm - text_w_px / scale) / 2
    if min(text_x_mm, margin_y) < 5.0:
        raise ConfigError(f"a {bw_mm:g} x {bh_mm:g} mm board does not fit {paper} paper with margins; "
                          "use {paper} a3, {paper} fit or smaller squares", parameter="paper", value=paper)
    page_px = (round(page_h_mm * scale), round(page_w_mm * scale))
    if page_px[0] * page_px[1] > MAX_PAGE_PIXELS:
        raise ConfigError(f"the page would be {page_px[1]} x {page_px[0]} px ({page_w_mm:.0f} x {page_h_mm:.0f} mm at "
                          f"{dpi} dpi), more than the {MAX_PAGE_PIXELS / 1e6:g} Mpx phonepose draws: use a lower {{dpi}}, "
                          "smaller squares or fewer of them", parameter="dpi", value=dpi)
    bits = _dictionary(board.dictionary).markerSize + 2       # the marker's cells and its black border
    if board.marker_mm * scale < bits:
        raise ConfigError(f"board marker_mm={board.marker_mm:g} is {board.marker_mm * scale:.2g} px at {dpi} dpi, "
                          f"less than its {bits} cells: use markers of at least {bits / scale:.2g} mm or a higher {{dpi}}",
                          parameter="dpi", value=dpi)
    page = np.full(page_px, 255, np.uint8)
    # OpenCV draws the board; we only place it. Its size is rounded to whole pixels: at 300 dpi a
    # 30 mm square is 354.33 px, drawn as 354 px (0.03 mm short), far below what a printer holds.
    bw_px, bh_px = round(bw_mm * scale), round(bh_mm * scale)
    image = board.opencv().generateImage((bw_px, bh_px), marginSize=0, borderBits=1)
    x0, y0 = round((page_w_mm - bw_mm) / 2 * scale), round(margin_y * scale)
    page[y0:y0 + bh_px, x0:x0 + bw_px] = image

    tx = round(text_x_mm * scale)
    base_y = y0 + bh_px + round((TEXT_GAP_MM + TEXT_HEIGHT_MM) * scale)
    for line in lines:
        cv2.putText(page, line, (tx, base_y), font, font_scale, 0, thick, cv2.LINE_AA)
        base_y += round(LINE_MM * scale)
    ruler = "the bar must measure 50 mm:"
    cv2.putText(page, ruler, (tx, base_y), font, font_scale, 0, thick, cv2.LINE_AA)
    bar_x = tx + cv2.getTextSize(ruler, font, font_scale, thick)[0][0] + round(3 * scale)
    bar_h = round(1.5 * scale)
    page[base_y - bar_h:base_y, bar_x:bar_x + round(50 * scale)] = 0
    return page


def board_png(board: BoardSpec = DEFAULT_BOARD, dpi: int = 300, paper: str = "a4") -> bytes:
    """:func:`render_board` as PNG bytes carrying its DPI (a pHYs chunk, which OpenCV's PNG writer
    cannot set; Pillow does), so a print dialog at 100 % prints the true size."""
    import io

    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(render_board(board, dpi, paper)).save(buf, format="PNG", dpi=(dpi, dpi), optimize=True)
    return buf.getvalue()
