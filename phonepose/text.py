"""Text from a file or a client, made safe to print on one terminal line.

A session's topic names, schema names and metadata, and what a phone page sends (its user agent, a
marker's dictionary), are anyone's text: an escape sequence in them would reach the user's terminal
(``ESC]0;...BEL`` retitles it, ``ESC[2J`` clears it), a newline would forge a line of phonepose's
own, and U+202E reverses what follows. :func:`printable` shows every such character as its escape.
"""

from __future__ import annotations

import unicodedata

# Cc: C0/C1 controls and DEL (ESC, BEL, CR, LF, backspace); Cf: format characters (the bidi overrides
# U+202A-202E, U+2066-2069, zero-width joiners); Zl/Zp: the line and paragraph separators; Cs: lone
# surrogates (undecodable bytes of a file name). Tab is shown too: a table cell stays one cell.
_HIDDEN = frozenset(("Cc", "Cf", "Zl", "Zp", "Cs"))


def printable(text: str, limit: int | None = None) -> str:
    """``text`` with every control, format and separator character escaped (``\\x1b``, ``\\n``,
    ``\\u202e``), so that it prints as the one line it is; cut to ``limit`` characters (with "...")."""
    if limit is not None and len(text) > limit:
        text = text[: max(limit - 3, 0)] + "..."
    if text.isprintable():      # the usual case, at C speed: no escape needed
        return text
    return "".join(_escaped(c) if unicodedata.category(c) in _HIDDEN else c for c in text)


def _escaped(c: str) -> str:
    code = ord(c)
    if c in "\n\r\t":
        return {"\n": "\\n", "\r": "\\r", "\t": "\\t"}[c]
    return f"\\x{code:02x}" if code < 0x100 else f"\\u{code:04x}"
