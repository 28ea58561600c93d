"""What the user does in each experiment of the paper (section 4): key poses and task windows.

Positions are given in the display camera's optical frame (x right, y down, z depth), where
the paper places targets and paths, and turned into world poses here. The *2 paths reach
outside the camera's view; how far is solved so that the number of 20 Hz frames outside the
view matches the paper's Table 4 for that trial.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from phonepose.errors import ConfigError
from phonepose.geometry import Pose
from phonepose.record.sim.config import SimConfig
from phonepose.record.sim.motion import KeyPose, Trajectory, make_oscillations
from phonepose.record.sim.world import World, look_at_rotation, marker_in_view

SCENARIOS = ("exp1", "exp2")
PATHS = ("TRI1", "TRI2", "REC1", "REC2")
TRIALS = (1, 2, 3)
TICK_HZ = 20.0   # the paper's recording rate (Table 4 counts frames at 20 Hz)

# Paper Table 4: (total frames, frames outside the FoV) at 20 Hz per path and trial.
TABLE4 = {
    "TRI1": [(93, 0), (94, 0), (91, 0)],
    "TRI2": [(112, 28), (104, 24), (137, 33)],
    "REC1": [(119, 0), (117, 0), (137, 0)],
    "REC2": [(148, 37), (141, 38), (153, 45)],
}

# Path way points of the controller body, display-camera optical frame (m). The *2 variants
# push the listed vertices right, well out of the view (PUSH_OUT_M); the time spent outside is
# then solved by the pace of the moves to and from them.
_PATHS = {
    "TRI1": ([(-0.08, 0.05, 0.30), (0.08, 0.06, 0.33), (0.0, -0.06, 0.27)], []),
    "TRI2": ([(-0.10, 0.05, 0.30), (0.06, 0.06, 0.33), (-0.02, -0.06, 0.27)], [1]),
    "REC1": ([(-0.09, -0.05, 0.28), (0.09, -0.05, 0.30), (0.09, 0.06, 0.34), (-0.09, 0.06, 0.32)], []),
    "REC2": ([(-0.11, -0.05, 0.28), (0.05, -0.05, 0.30), (0.05, 0.06, 0.34), (-0.11, 0.06, 0.32)], [1, 2]),
}

# Experiment 1: 16 targets, 8 at 25 cm and 8 at 35 cm depth; at each depth 4 inside the view
# and 4 outside it (left, right, above, below).
def _exp1_targets_cam() -> list[tuple[float, float, float]]:
    out = []
    for z, (xi, yi), (xo, yo) in ((0.25, (0.05, 0.04), (0.25, 0.20)), (0.35, (0.07, 0.05), (0.33, 0.27))):
        out += [(-xi, -yi, z), (xi, -yi, z), (xi, yi, z), (-xi, yi, z)]
        out += [(-xo, 0.0, z), (xo, 0.0, z), (0.0, -yo, z), (0.0, yo, z)]
    return out


EXP1_HOLD_S = 5.0
PUSH_OUT_M = 0.22


@dataclass
class TargetPlan:
    index: int
    T_world: Pose              # where the target is (true world)
    inside_view: bool
    hold_start: float
    hold_end: float


@dataclass
class Plan:
    """The session timeline (seconds from the start) and what the user was asked to do."""

    scenario: str
    path: str
    trial: int
    keys: list[KeyPose]
    t_fix: float               # CM1: the CG object is fixed
    t_align: float             # CM1: the user has aligned the phone with it
    t_cm2: float               # CM2 moment (phone still, marker in view)
    task_start: float
    task_end: float
    end: float
    cm1_key_index: int         # index in ``keys`` of the aligned pose (filled once VIO is known)
    targets: list[TargetPlan] = field(default_factory=list)
    waypoints_world: np.ndarray | None = None
    closed: bool = True
    recorded: object | None = None   # (window, facing, centre_world): record sim --motion (phonepose.record.sim.recorded)


def check_choice(scenario: str, path: str | None, trial: int) -> None:
    if scenario not in SCENARIOS:
        raise ConfigError(f"unknown scenario {scenario!r}: choose one of {', '.join(SCENARIOS)}")
    if scenario == "exp2" and path not in PATHS:
        raise ConfigError(f"{{path}} must be one of {', '.join(PATHS)} for exp2, got {path!r}", parameter="path",
                          value=path, expected=f"one of {', '.join(PATHS)}")
    if trial not in TRIALS:
        raise ConfigError(f"{{trial}} must be 1, 2 or 3, got {trial!r}", parameter="trial", value=trial,
                          expected="1, 2 or 3")


def check_seed(seed: int) -> None:
    """A seed the session can record and numpy accepts (a negative one is numpy's ValueError)."""
    from phonepose.numbers import SEED_MAX, check_number
    check_number("seed", seed, 0, SEED_MAX, integer=True)


class _Posing:
    """Turns camera-frame positions into world key poses with a human's orientation variation."""

    def __init__(self, world: World, cfg: SimConfig, rng: np.random.Generator):
        self.world, self.cfg, self.rng = world, cfg, rng
        self.T_wc = world.T_world_camera

    def to_world(self, p_cam) -> np.ndarray:
        return self.T_wc.apply(np.asarray(p_cam, dtype=float))

    def facing(self, p_world: np.ndarray, vary_deg: float | None = None) -> Rotation:
        base = look_at_rotation(p_world, self.T_wc.translation)
        v = self.cfg.human.orientation_variation_deg if vary_deg is None else vary_deg
        # turns about the body's x and y (the screen turning away) and a smaller roll
        angles = self.rng.uniform(-1, 1, 3) * np.array([v, v, v / 2])
        return base * Rotation.from_euler("xyz", angles, degrees=True)

    def key(self, t: float, p_cam, vary_deg: float | None = None) -> KeyPose:
        p = self.to_world(p_cam)
        return KeyPose(t, p, self.facing(p, vary_deg))


def _segment_times(points: np.ndarray, total: float, rng: np.random.Generator, variation: float,
                   slow: np.ndarray | None = None, slow_factor: float = 1.0) -> np.ndarray:
    """Durations of moves along ``points`` that sum to ``total``: longer moves take longer
    (about length^0.75, as in reaching), with a per-move pace variation; moves flagged in
    ``slow`` take ``slow_factor`` times longer."""
    lengths = np.linalg.norm(np.diff(points, axis=0), axis=1)
    w = np.maximum(lengths, 1e-3) ** 0.75 * np.clip(1 + variation * rng.normal(size=len(lengths)), 0.5, 1.5)
    if slow is not None:
        w = np.where(slow, w * slow_factor, w)
    return w / w.sum() * total


def _tick_count_outside(world: World, cfg: SimConfig, keys: list[KeyPose], t0: float, t1: float) -> int:
    traj = Trajectory(keys, *_no_osc())
    ticks = t0 + np.arange(int(round((t1 - t0) * TICK_HZ))) / TICK_HZ
    T_cam_ctrl = world.T_world_camera.inv() @ traj.base(ticks)
    return int(np.sum(~marker_in_view(world, T_cam_ctrl, cfg.marker.size_m)))


def _no_osc():
    z = np.random.default_rng(0)
    return make_oscillations(z, 0.0, 0.0, 0.0, 0.0)


def build_plan(world: World, cfg: SimConfig, scenario: str, path: str | None, trial: int, rng_for,
               motion=None) -> Plan:
    """The timeline: a still start (CM1 fix), the CM1 alignment, the CM2 hold, then the task.

    The CM1 aligned pose is a placeholder here: the simulation replaces ``keys[cm1_key_index]``
    once it knows where the VIO put the fixed CG object.
    """
    check_choice(scenario, path, trial)
    rng = rng_for(f"plan_trial{trial}")   # the same world (seed) gives different human motion per trial
    pose = _Posing(world, cfg, rng)
    pace = 1 + cfg.human.speed_variation * rng.normal()
    keys: list[KeyPose] = []
    # Calibration phase: start still in view; the CG object is fixed at t_fix; the user moves
    # the phone onto it and holds (t_align); then holds the phone in view for CM2.
    start = pose.key(0.0, (0.0, 0.03, 0.30), vary_deg=10.0)
    t_fix = 1.0
    keys += [start, KeyPose(1.3, start.position, start.rotation)]
    t = 1.3 + 1.6 * pace
    cm1_index = len(keys)
    keys.append(KeyPose(t, start.position, start.rotation))           # replaced by the aligned pose
    t_align = t + 0.6
    t += 1.2
    keys.append(KeyPose(t, start.position, start.rotation))           # replaced as well (hold)
    t += 1.2 * pace
    cm2 = pose.key(t, (0.02, -0.01, 0.28), vary_deg=0.0)
    # CM2 wants a well-conditioned marker view: turn the screen ~20 deg off frontal.
    cm2.rotation = cm2.rotation * Rotation.from_euler("xy", [12.0, -16.0], degrees=True)
    keys.append(cm2)
    t_cm2 = t + 0.75
    t += 1.5
    keys.append(KeyPose(t, cm2.position, cm2.rotation))
    plan = Plan(scenario=scenario, path=path or "", trial=trial, keys=keys, t_fix=t_fix, t_align=t_align,
                t_cm2=t_cm2, task_start=0.0, task_end=0.0, end=0.0, cm1_key_index=cm1_index)
    if motion is not None:
        _plan_recorded(plan, pose, t, motion)
    elif scenario == "exp2":
        assert path is not None   # check_choice above: exp2 names a path
        _plan_exp2(plan, world, cfg, pose, rng, t, path, trial)
    else:
        _plan_exp1(plan, world, cfg, pose, rng, t)
    return plan


def _plan_exp2(plan: Plan, world: World, cfg: SimConfig, pose: _Posing, rng, t: float, path: str, trial: int):
    total_frames, outside_frames = TABLE4[path][trial - 1]
    task_s = total_frames / TICK_HZ
    base_pts, push = _PATHS[path]
    base_pts = np.array(base_pts, dtype=float)
    # The human does not hit the way points exactly.
    human_pts = base_pts + rng.normal(size=base_pts.shape) * 0.005
    orient = [pose.facing(pose.to_world(p)) for p in base_pts]
    seg_rng_state = rng.integers(1 << 31)
    move_s = 1.2
    task_start = t + move_s + 0.3

    n_pts = len(base_pts)
    # moves that start or end at a pushed vertex (the closed path returns to vertex 0)
    seg_from, seg_to = np.arange(n_pts), (np.arange(n_pts) + 1) % n_pts
    slow = np.isin(seg_from, push) | np.isin(seg_to, push)
    pts = human_pts.copy()
    pts[push, 0] += PUSH_OUT_M
    world_pts = pose.to_world(np.vstack([pts, pts[:1]]))

    def keys_for(slow_factor: float) -> list[KeyPose]:
        durations = _segment_times(world_pts, task_s, np.random.default_rng(seg_rng_state), cfg.human.speed_variation,
                                   slow, slow_factor)
        out = [KeyPose(t + move_s, world_pts[0], orient[0]), KeyPose(task_start, world_pts[0], orient[0])]
        tk = task_start
        for i, d in enumerate(durations):
            tk += d
            out.append(KeyPose(tk, world_pts[i + 1], orient[(i + 1) % len(orient)]))
        return out

    factor = 1.0
    if push:
        # Solve the pace so the number of 20 Hz frames outside the view matches Table 4: the
        # phone crosses the edge of the view while moving, so tremor barely changes the count.
        lo, hi = np.log(0.05), np.log(20.0)
        for _ in range(40):
            mid = (lo + hi) / 2
            n = _tick_count_outside(world, cfg, plan.keys + keys_for(np.exp(mid)), task_start, task_start + task_s)
            if n < outside_frames:
                lo = mid
            else:
                hi = mid
        factor = np.exp(hi)
    task_keys = keys_for(factor)
    plan.keys += task_keys
    plan.task_start, plan.task_end = task_start, task_start + task_s
    end_key = task_keys[-1]
    plan.keys.append(KeyPose(plan.task_end + 0.8, end_key.position, end_key.rotation))
    plan.end = plan.task_end + 0.8
    way = base_pts.copy()
    way[push, 0] += PUSH_OUT_M
    plan.waypoints_world = pose.to_world(way)
    plan.closed = True


def _plan_recorded(plan: Plan, pose: _Posing, t: float, motion) -> None:
    """The task is a recorded window (phonepose.record.sim.recorded): move to its first pose, hold, play it."""
    from phonepose.record.sim.recorded import HOLD_S, MOVE_S, load_window, placed

    window = load_window(motion)
    centre = pose.to_world(motion.centre)
    facing = look_at_rotation(centre, pose.T_wc.translation)
    first = placed(window, facing, centre)[0]
    plan.keys += [KeyPose(t + MOVE_S, first.translation, first.rotation),
                  KeyPose(t + MOVE_S + HOLD_S, first.translation, first.rotation)]
    plan.task_start = t + MOVE_S + HOLD_S
    plan.task_end = plan.task_start + float(window.t[-1])
    plan.end = plan.task_end + 0.8
    plan.keys.append(KeyPose(plan.end, first.translation, first.rotation))   # unused: the window's end is held
    plan.path = f"motion:{motion.name}"
    plan.closed = False
    plan.recorded = (window, facing, centre)


def _plan_exp1(plan: Plan, world: World, cfg: SimConfig, pose: _Posing, rng, t: float):
    cam_targets = np.array(_exp1_targets_cam())
    order = rng.permutation(len(cam_targets))
    task_start: float | None = None   # the first target's hold start
    prev = pose.to_world((0.02, -0.01, 0.28))
    for idx in order:
        p_world = pose.to_world(cam_targets[idx])
        target_rot = look_at_rotation(p_world, pose.T_wc.translation)
        T_target = Pose(target_rot, p_world)
        dist = np.linalg.norm(p_world - prev)
        move = (0.9 + 2.5 * dist) * (1 + cfg.human.speed_variation * rng.normal() / 2)
        held = KeyPose(t + move, p_world + rng.normal(size=3) * 0.004, pose.facing(p_world))
        hold_start = held.t
        if task_start is None:
            task_start = plan.task_start = hold_start
        plan.keys += [held, KeyPose(hold_start + EXP1_HOLD_S, held.position, held.rotation)]
        T_cam_target = world.T_world_camera.inv() @ T_target
        inside = bool(marker_in_view(world, T_cam_target, cfg.marker.size_m)[0])
        plan.targets.append(TargetPlan(int(idx), T_target, inside, hold_start, hold_start + EXP1_HOLD_S))
        t = hold_start + EXP1_HOLD_S
        prev = p_world
    plan.task_end = t
    plan.keys.append(KeyPose(t + 0.8, plan.keys[-1].position, plan.keys[-1].rotation))
    plan.end = t + 0.8
