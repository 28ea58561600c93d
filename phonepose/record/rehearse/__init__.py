"""``phonepose record rehearse``: a real recording rehearsed with no hardware.

A simulated session is the truth (scene.py); its frames become a video that ``record live --camera
FILE`` plays; headless Chromium opens the real phone and headset pages with emulated WebXR devices
(IWER) that play the simulated motion (browser.py, driver.js; session.py runs the recording); then
calibrate-gt and playback score the recording against the source session (score.py).

    result = rehearse("rehearsal", scenario="exp2", path="REC1")
    for row in rows(result.scores): print(row.what, row.value)
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:   # imported when used: numpy, OpenCV and the simulator would slow `phonepose --help`
    from phonepose.record.rehearse.score import Row, Scores

__all__ = ["LEAD_IN_S", "RehearsalResult", "rehearse", "rows"]

LEAD_IN_S = 20.0             # still frames before the simulated motion: the browser starts meanwhile
DEFAULT_TIMEOUT_S = 120.0    # each wait on the browser (page load, AR session); generous, as on a loaded machine


def rows(scores: Scores) -> list[Row]:
    """The rehearsal's table (score.rows)."""
    from phonepose.record.rehearse.score import rows as score_rows

    return score_rows(scores)


@dataclass
class RehearsalResult:
    out_dir: Path
    scores: Scores
    files: dict[str, str]
    tracking: list[str]          # the live trackers' closing summary (empty without them)

    @property
    def met(self) -> bool:
        return all(r.met is not False for r in rows(self.scores))


def rehearse(out_dir: str | os.PathLike, *, scenario: str = "exp2", path: str | None = "REC1", trial: int = 1,
             seed: int = 0, config: str | os.PathLike | None = None, lead_in_s: float = LEAD_IN_S,
             headset: bool = True, iwer: str | os.PathLike | None = None, timeout_s: float = DEFAULT_TIMEOUT_S,
             echo: Callable[[str], None] = print, tracking=None) -> RehearsalResult:
    """Rehearse one recording into the folder ``out_dir`` (phonepose.files' rule: written under a temporary
    name, in place when complete): source.mcap, camera.avi, camera.yaml, live.mcap, gt-calibration.yaml
    (with the headset), rehearsal.json (the scores). ``tracking`` (a record.live.session.LiveTracking) runs
    trackers live during the recording (``record live -t``)."""
    from phonepose.calibration.calibrate import opencv_path
    from phonepose.errors import OutputError, keyword
    from phonepose.files import OutputPlan, check_input
    from phonepose.record.rehearse.browser import find_iwer
    from phonepose.record.rehearse.scene import build_scene, rehearsal_config
    from phonepose.record.rehearse.score import score
    from phonepose.record.rehearse.session import record_rehearsal
    from phonepose.record.sim.scenarios import check_choice, check_seed

    check_choice(scenario, path, trial)
    check_seed(seed)
    # OpenCV writes camera.avi into the folder (a name that is not UTF-8 crashes it: SIGSEGV)
    out_name = keyword("out")
    opencv_path(Path(out_dir), f"a {out_name} folder (camera.avi is written there by OpenCV)",
                f"choose another {out_name}", OutputError)
    if config is not None:
        check_input(config, "TOML file")
    cfg = rehearsal_config(config)
    iwer_js = find_iwer(iwer)
    plan = OutputPlan(inputs=[config] if config is not None else [])
    out = plan.dir(out_dir, "out", command="record rehearse")
    with plan:
        assert out.tmp is not None
        folder = out.tmp
        echo(f"simulating {scenario} {path or ''} trial {trial} seed {seed} and writing its video ...")
        scene = build_scene(folder, scenario=scenario, path=path, trial=trial, seed=seed, config=cfg,
                            lead_in_s=lead_in_s)
        echo(f"record live --camera camera.avi ({scene.frames} frames at {scene.fps:g} Hz, {scene.lead_in_s:g} s still "
             f"lead-in), the phone{' and headset' if headset else ''} page in headless Chromium ...")
        run = record_rehearsal(scene, folder / "live.mcap", iwer=iwer_js, headset=headset, timeout_s=timeout_s,
                               echo=echo, tracking=tracking)
        scores = score(scene, run, calibration_out=folder / "gt-calibration.yaml" if headset else None, echo=echo)
        if tracking is not None and run.tracking:
            from phonepose.playback.livecheck import check_live

            echo("the live estimates against a playback of the rehearsed session ...")
            for c in check_live(folder / "live.mcap"):
                run.tracking.append(f"live {c.tracker} vs playback: {c.identical} of {c.compared} ticks identical"
                                    + (f", {c.different} different" if c.different else ""))
        doc = {"scenario": scenario, "path": path, "trial": trial, "seed": seed, "lead_in_s": scene.lead_in_s,
               "headset": headset, "sim0_ns": run.sim0_ns,
               "page_clocks": {k: asdict(v) for k, v in run.clocks.items()}, "pages": run.page_states,
               "scores": asdict(scores),
               "rows": [asdict(r) for r in rows(scores)]}
        (folder / "rehearsal.json").write_text(json.dumps(doc, indent=1, default=float) + "\n", encoding="utf-8")
        names = sorted(n for n in os.listdir(folder) if not n.startswith("."))
    files = {n: os.fspath(Path(out_dir) / n) for n in names}
    return RehearsalResult(Path(out_dir), scores, files, run.tracking)
