"""The built-in simulated world of the paper's setup (section 4, Fig. 8).

``record_sim`` records one simulated session to an MCAP file; ``SimSession`` exposes the
ground truth behind it (tests, calibration of the defaults against the paper).
"""

from __future__ import annotations

import os

from phonepose.record.recorder import ProgressCallback, Recorder, RecordResult
from phonepose.record.sim.config import SimConfig, default_config, load_config
from phonepose.record.sim.scenarios import PATHS, SCENARIOS, TABLE4, TRIALS, check_choice
from phonepose.record.sim.simulation import T0_NS, SimSession, SimSource

__all__ = ["PATHS", "SCENARIOS", "TABLE4", "TRIALS", "T0_NS", "SimConfig", "SimSession", "SimSource",
           "default_config", "load_config", "record_sim"]


def record_sim(out: str | os.PathLike, *, scenario: str = "exp2", path: str | None = "TRI1", trial: int = 1,
               seed: int = 0, config: SimConfig | str | os.PathLike | None = None,
               progress: ProgressCallback | None = None, rerun_path: str | os.PathLike | None = None,
               spawn: bool = False) -> RecordResult:
    """Simulate one session and record it to ``out``.

    ``config``: a :class:`SimConfig`, a TOML file overriding the defaults, or None (defaults).
    ``progress(done_ns, total_ns)`` is called about every 0.1 s of session time.
    """
    check_choice(scenario, path, trial)
    if config is None:
        cfg = default_config()
    elif isinstance(config, SimConfig):
        cfg = config
    else:
        cfg = load_config(config)
    session = SimSession(scenario, path if scenario == "exp2" else None, trial, seed, cfg)
    return Recorder(SimSource(session), out, progress=progress, rerun_path=rerun_path, spawn=spawn).run()
