"""``phonepose experiment``: not built yet (see the issues)."""

from __future__ import annotations
