"""The built-in simulated world of the paper's setup (section 4, Fig. 8).

``record_sim`` records one simulated session to an MCAP file; ``SimSession`` exposes the
ground truth behind it (tests, calibration of the defaults against the paper).
"""

from __future__ import annotations

import os

from phonepose.record.recorder import ProgressCallback, Recorder, RecordResult
from phonepose.record.sim.config import SimConfig, default_config, load_config
from phonepose.record.sim.scenarios import PATHS, SCENARIOS, TABLE4, TRIALS, check_choice, check_seed
from phonepose.record.sim.simulation import T0_NS, SimSession, SimSource

__all__ = ["PATHS", "SCENARIOS", "TABLE4", "TRIALS", "T0_NS", "SimConfig", "SimSession", "SimSource",
           "default_config", "load_config", "record_sim"]


def record_sim(out: str | os.PathLike, *, scenario: str = "exp2", path: str | None = "TRI1", trial: int = 1,
               seed: int = 0, config: SimConfig | str | os.PathLike | None = None,
               progress: ProgressCallback | None = None, rerun_path: str | os.PathLike | None = None,
               spawn: bool = False, force: bool = False, config_file: str | os.PathLike | None = None,
               stop_on_signals: bool = False, motion=None) -> RecordResult:
    """Simulate one session and record it to ``out`` (a new file; an existing one only with ``force``).

    ``config``: a :class:`SimConfig`, a TOML file overriding the defaults, or None (defaults);
    ``config_file``: the TOML file a given SimConfig was read from (an input no output may replace).
    ``motion``: a :class:`phonepose.record.sim.recorded.MotionSpec`: a recorded trajectory is the task.
    ``stop_on_signals``: Ctrl-C and SIGTERM end the recording early and leave a finished file
    (``record sim``); otherwise they stop the caller (an experiment) like anywhere else.
    ``progress(done_ns, total_ns)`` is called about every 0.1 s of session time. ``out`` and
    ``rerun_path`` follow phonepose.files: checked before the simulation starts; the session is
    written under its own name (a killed recording is there for ``phonepose recover``), the .rrd
    under a temporary renamed when complete.
    """
    from phonepose.files import OutputPlan

    check_choice(scenario, path, trial)
    check_seed(seed)
    if config is None:
        cfg = default_config()
    elif isinstance(config, SimConfig):
        cfg = config
    else:
        cfg = load_config(config)
    config_file = config if isinstance(config, (str, os.PathLike)) else config_file
    # the files read (the config, a recorded --motion): inputs no output may replace, --force or not
    plan = OutputPlan(inputs=[f for f in (config_file, motion.file if motion is not None else None) if f is not None])
    session_out = plan.file(out, "out", suffixes=(".mcap",), what="an MCAP session", in_place=True, force=force)
    rrd = plan.file(rerun_path, "rerun", suffixes=(".rrd",), what="a Rerun recording") \
        if rerun_path is not None else None
    session = SimSession(scenario, path if scenario == "exp2" else None, trial, seed, cfg, motion=motion)
    with plan:
        assert session_out.tmp is not None   # the plan's block made it
        result = Recorder(SimSource(session), session_out.tmp, progress=progress,
                          rerun_path=rrd.tmp if rrd is not None else None, spawn=spawn,
                          stop_on_signals=stop_on_signals).run()
    result.path = os.fspath(out)
    return result
