"""Park & Ogawa 2024's published numbers (CMC 79(2):3047-3065), transcribed from the paper.

Table 4 (frames per sequence), Tables 2-3 (experiment 1) and Tables 5-6 (experiment 2).
Units as printed: cm and degrees. Where the paper groups trackers (e.g. "T4, T5, T6, T7"),
each tracker of the group gets the group's number.
"""

from __future__ import annotations

# Table 4: (inside, outside) frames at 20 Hz per (path, trial)
TABLE4_FRAMES = {
    ("TRI1", 1): (93, 0), ("TRI1", 2): (94, 0), ("TRI1", 3): (91, 0),
    ("TRI2", 1): (84, 28), ("TRI2", 2): (80, 24), ("TRI2", 3): (104, 33),
    ("REC1", 1): (119, 0), ("REC1", 2): (117, 0), ("REC1", 3): (137, 0),
    ("REC2", 1): (111, 37), ("REC2", 2): (103, 38), ("REC2", 3): (108, 45),
}


def _expand(rows: dict) -> dict:
    out = {}
    for names, values in rows.items():
        for name in names.split(","):
            out[name.strip()] = values
    return out


# Table 5: TRI1 + REC1 (entirely inside the view), averages over the 6 sequences.
TABLE5_AVERAGE = _expand({
    "T1": {"p_ate_cm": 6.6, "r_ate_deg": 11.1, "p_re_cm": 2.3},
    "T2": {"p_ate_cm": 4.7, "r_ate_deg": 10.2, "p_re_cm": 2.3},
    "T3": {"p_ate_cm": 2.7, "r_ate_deg": 12.2, "p_re_cm": 2.3},
    "T4, T5, T6, T7": {"p_ate_cm": 1.4, "r_ate_deg": 12.6, "p_re_cm": 1.0},
})

# Table 6: TRI2 + REC2, "Average" columns (within the FoV, outside the FoV, total).
TABLE6_AVERAGE: dict[str, dict[str, tuple[float | str, ...]]] = {   # str: NO_VALUE, for ours below
    "T1": {"inside": (7.1, 12.0, 2.7), "outside": (11.6, 18.8, 4.6), "total": (8.5, 14.1, 3.9)},
    "T2": {"inside": (5.4, 12.0, 2.7), "outside": (8.9, 13.2, 4.6), "total": (6.4, 12.3, 3.9)},
    "T3": {"inside": (3.3, 11.1, 2.7), "outside": (7.7, 11.2, 4.6), "total": (4.8, 11.1, 3.9)},
    "T4": {"inside": (1.4, 13.0, 1.0), "outside": (11.6, 18.8, 4.6), "total": (5.9, 14.8, 5.1)},
    "T5": {"inside": (1.4, 13.0, 1.0), "outside": (8.4, 13.5, 4.5), "total": (4.4, 13.2, 3.8)},
    "T6": {"inside": (1.4, 13.0, 1.0), "outside": (7.1, 11.2, 4.3), "total": (3.8, 12.5, 3.3)},
    "T7": {"inside": (1.4, 13.0, 1.0), "outside": (6.1, 12.5, 4.6), "total": (3.3, 12.9, 3.1)},
}
"""(p_ATE cm, r_ATE deg, p_RE cm) per split."""

# Table 2 (experiment 1, targets inside the view): (pos cm, rot deg)
TABLE2_INSIDE = _expand({"T1": (2.7, 16.6), "T2": (0.5, 18.2), "T3": (0.7, 16.9), "T4, T5, T6, T7": (0.5, 9.2)})
# Table 3 (experiment 1, targets outside the view)
TABLE3_OUTSIDE = _expand({"T1, T4": (2.2, 14.9), "T2, T5": (1.0, 15.6), "T3, T6": (0.9, 17.6), "T7": (2.1, 9.8)})

TRACKERS = ["T1", "T2", "T3", "T4", "T5", "T6", "T7"]

# Our own trackers, reported beside T1-T7 in every table (the paper has no number for them: "—").
OURS = ["T7L", "T8"]
REPORTED = TRACKERS + OURS
NO_VALUE = "—"

for _table in (TABLE5_AVERAGE,):
    for _name in OURS:
        _table[_name] = {"p_ate_cm": NO_VALUE, "r_ate_deg": NO_VALUE, "p_re_cm": NO_VALUE}
for _name in OURS:
    TABLE6_AVERAGE[_name] = {s: (NO_VALUE,) * 3 for s in ("inside", "outside", "total")}
    TABLE2_INSIDE[_name] = (NO_VALUE, NO_VALUE)
    TABLE3_OUTSIDE[_name] = (NO_VALUE, NO_VALUE)
