"""Where T8's orientation error comes from, tick by tick, on one session with exact ground truth.

    python tools/research/t8_rotation_parts.py fr2_exact.mcap                      # T8 at its defaults
    python tools/research/t8_rotation_parts.py fr2_exact.mcap gyro_rate_adapt_s=0  # FusionConfig values as name=value

Plays the session back with T6 and an instrumented T8 and prints RMS angles, inside / outside the view /
total: T8's output against the ground truth; its correction C against the true one (the ground truth times
the VIO at the tick, interpolated after the fact, smoothed over 1 s), and that error's heading and tilt;
T8's gyro prediction and the held VIO orientation against the VIO at the tick; the true C with T8's
prediction; T6's output. docs/pipeline.md ("Real hand motion", fr2_desk) quotes it for T8 with the held
rate (`gyro_rate_adapt_s=0`). A development tool.
"""

from __future__ import annotations

import sys

import numpy as np
from scipy.spatial.transform import Rotation as R
from scipy.spatial.transform import Slerp

from phonepose.pipeline.t8 import FusedTracker, FusionConfig
from phonepose.pipeline.trackers import make_trackers
from phonepose.playback.engine import run_playback


class _Instrumented(FusedTracker):
    """T8 that keeps, per tick, its correction, its prediction and the newest VIO sample."""

    def reset(self) -> None:
        super().reset()
        self.rows: list[dict] = []
        self.vio_all: list[tuple[float, tuple]] = []

    def _add_vio(self, t, pose):
        if not self.vio_all or t > self.vio_all[-1][0]:
            self.vio_all.append((t, tuple(pose[0])))
        super()._add_vio(t, pose)

    def step(self, obs):
        out = super().step(obs)
        f = self.filter
        if out is None or not f.ready or not len(self._vio):
            return out
        t = self._s(obs.tick.t_ns)
        self.rows.append({"t_ns": obs.tick.t_ns, "t": t, "C": tuple(f.q), "inside": self._source == "marker",
                          "q_newest": tuple(self._vio.v[-1, 0:4].tolist()),
                          "q_pred": tuple(self._predicted_rotation(t - f.d)), "q_out": tuple(out.rotation.as_quat())})
        return out


def _angle(a: R, b: R) -> np.ndarray:
    return np.degrees((a * b.inv()).magnitude())


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.asarray(x) ** 2))) if len(x) else float("nan")


def main(session: str, assignments: list[str]) -> None:
    cfg = FusionConfig.from_dict(dict(kv.split("=", 1) for kv in assignments))
    t8 = _Instrumented("T8", cfg)
    others: list = []

    def trackers(names, math):
        others.extend(make_trackers(names, math))
        return [*others, t8]
    res = run_playback(session, trackers=["T6"], write_outputs=False, tracker_factory=trackers)
    index = {int(t): i for i, t in enumerate(res.gt_stamps_ns)}
    rows = [r for r in t8.rows if r["t_ns"] in index]
    truth = res.gt.rotation[np.array([index[r["t_ns"]] for r in rows])]
    t = np.array([r["t"] for r in rows])
    inside = np.array([r["inside"] for r in rows])
    C, out = R.from_quat([r["C"] for r in rows]), R.from_quat([r["q_out"] for r in rows])
    pred, newest = R.from_quat([r["q_pred"] for r in rows]), R.from_quat([r["q_newest"] for r in rows])
    vt = np.array([v[0] for v in t8.vio_all])
    vio_at_tick = Slerp(vt, R.from_quat([v[1] for v in t8.vio_all]))(np.clip(t, vt[0], vt[-1]))
    C_true = truth * vio_at_tick.inv()
    rv = (C_true * C_true[0].inv()).as_rotvec()          # the VIO's white jitter smoothed out over +-0.5 s
    C_smooth = R.from_rotvec(np.array([rv[np.abs(t - ti) <= 0.5].mean(axis=0) for ti in t])) * C_true[0]
    c_err = (C * C_smooth.inv()).as_rotvec()
    t6 = res.trajectories["T6"]
    _, i6, ig = np.intersect1d(t6.stamps_ns, res.gt_stamps_ns, return_indices=True)
    e6, in6 = _angle(t6.poses.rotation[i6], res.gt.rotation[ig]), t6.inside[i6]
    print(f"{session}: {len(t)} ticks ({inside.sum()} inside the view); RMS deg, inside / outside / total")
    for name, e in (("T8 output vs ground truth", _angle(out, truth)),
                    ("C vs the true C (smoothed over 1 s)", _angle(C, C_smooth)),
                    ("  its heading (about z)", np.degrees(np.abs(c_err[:, 2]))),
                    ("  its tilt", np.degrees(np.hypot(c_err[:, 0], c_err[:, 1]))),
                    ("gyro prediction vs the VIO at the tick", _angle(pred, vio_at_tick)),
                    ("newest VIO held vs the VIO at the tick", _angle(newest, vio_at_tick)),
                    ("the true C with T8's prediction", _angle(C_smooth * pred, truth))):
        print(f"  {name:40s} {_rms(e[inside]):6.3f} / {_rms(e[~inside]):6.3f} / {_rms(e):6.3f}")
    print(f"  {'T6 output vs ground truth':40s} {_rms(e6[in6]):6.3f} / {_rms(e6[~in6]):6.3f} / {_rms(e6):6.3f}")
    # T6 outside the view is its one CM2 offset times the VIO pose the tick carries, which the scheduler
    # interpolates at the tick between the last sample received and the first one after it; with the newest
    # received sample instead (what T8 has), on the ticks both have
    C6 = others[0].correction.current.rotation
    causal = dict(zip((int(r["t_ns"]) for r in rows), _angle(C6 * newest, truth), strict=True))
    e6c = np.array([causal.get(int(s), e) if not i else e for s, e, i in zip(t6.stamps_ns[i6], e6, in6, strict=True)])
    print(f"  {'T6, the newest received VIO outside':40s} {_rms(e6c[in6]):6.3f} / {_rms(e6c[~in6]):6.3f} / {_rms(e6c):6.3f}")


if __name__ == "__main__":
    if len(sys.argv) < 2 or sys.argv[1] in ("-h", "--help"):
        print(__doc__)
        sys.exit(0 if len(sys.argv) > 1 else 2)
    main(sys.argv[1], sys.argv[2:])
