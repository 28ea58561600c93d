"""Numbers a user gives (options, ``--param`` values, config): finite and within a range, or one line.

:func:`check_number` is the one check; ``phonepose.cli.options.number`` makes it a typer
callback. NaN, inf, a value that overflows a float, or one outside the range is a ConfigError
(exit 5) naming the option, the value and the range, before any work.
"""

from __future__ import annotations

import math

from phonepose.errors import ConfigError

SEED_MAX = 2**32 - 1      # the seeds a session records (int64 field) and numpy takes, with room for derived ones
SECONDS_MAX = 1e6         # a time offset into a session: 11.6 days is far past any recording
RATE_MAX_HZ = 1000.0      # ticks per second: 8x the fastest camera the simulator has (120 Hz)
# The slowest: a tick every 10 s, the longest stretch the scheduler ticks through (docs/reliability.md, "Work is
# bounded by the data"); a rate of 5e-324 Hz overflowed the tick period (1e9 / rate ns) instead
RATE_MIN_HZ = 0.1
WORKERS_MAX = 256         # local worker processes (batch and experiment --workers)
UNIT_TIMEOUT_S = 3600.0   # batch --unit-timeout's default: a playback longer than an hour is a session that never ends


def show_number(value) -> str:
    """A number as a message shows it: compact (``1e+300``, not 301 digits), an integer of up to 24 digits whole."""
    if isinstance(value, float):
        return str(int(value)) if value.is_integer() and abs(value) < 1e16 else f"{value:g}"
    if isinstance(value, int) and not isinstance(value, bool) and abs(value) >= 10**24:
        digits = str(abs(value))       # not float(value): 10**400 overflows it
        mantissa = f"{digits[0]}.{digits[1:6]}".rstrip("0").rstrip(".")
        return f"{'-' if value < 0 else ''}{mantissa}e+{len(digits) - 1}"
    return str(value)


def _range_text(lo, hi, lo_open: bool, hi_open: bool, integer: bool) -> str:
    kind = "an integer" if integer else "a finite number"
    if lo is not None and hi is not None:
        return f"{kind} in {'(' if lo_open else '['}{show_number(lo)}, {show_number(hi)}{')' if hi_open else ']'}"
    if lo is not None:
        return f"{kind} {'>' if lo_open else '>='} {show_number(lo)}"
    if hi is not None:
        return f"{kind} {'<' if hi_open else '<='} {show_number(hi)}"
    return kind


def check_number(name: str, value, lo=None, hi=None, *, lo_open: bool = False, hi_open: bool = False,
                 integer: bool = False, unit: str = "", also: tuple = ()):
    """``value`` if it is finite (an int when ``integer``) and within the range, or one of ``also``;
    else ConfigError naming ``name``, the value and the range (``unit`` is added after the range)."""
    if value in also and not (isinstance(value, float) and math.isnan(value)):
        return value
    ok = isinstance(value, int) and not isinstance(value, bool) if integer else \
        isinstance(value, (int, float)) and not isinstance(value, bool)
    if ok and not integer:
        try:
            ok = math.isfinite(float(value))
        except OverflowError:
            ok = False
    if ok:
        ok = not (lo is not None and (value < lo or (lo_open and value == lo))) and \
            not (hi is not None and (value > hi or (hi_open and value == hi)))
    if not ok:
        extra = " or " + " or ".join(show_number(a) for a in also) if also else ""
        sep = "" if name.endswith("=") else " "     # "rate inf", "params rate_hz=inf"
        expected = f"{_range_text(lo, hi, lo_open, hi_open, integer)}{extra}{' ' + unit if unit else ''}"
        keyword = name.split()[0] if name.split() and name.split()[0].isidentifier() else None
        shown = "{" + keyword + "}" + name[len(keyword):] if keyword else name   # the keyword, shown per caller
        raise ConfigError(f"{shown}{sep}{show_number(value)}: expected {expected}", parameter=keyword, value=value,
                          expected=expected)
    return value
