"""The simulated session: world + plan + motion + sensor models, as a recorder :class:`Source`.

Everything derives from the seed through named random sub-streams
(``np.random.default_rng([seed, crc32(name)])``): changing one model's draws never shifts
another's, and the same seed and config give a byte-identical file. No wall clock is read;
the session starts at a fixed display-clock time :data:`T0_NS`.
"""

from __future__ import annotations

import heapq
import zlib
from collections import deque
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from typing import overload

import numpy as np
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.Log_pb2 import Log
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from scipy.spatial.transform import Rotation

from phonepose import __version__
from phonepose.geometry import Pose
from phonepose.record.sim.config import SimConfig, default_config
from phonepose.record.sim.imu import simulate_imu
from phonepose.record.sim.motion import Trajectory, make_oscillations
from phonepose.record.sim.render import Renderer
from phonepose.record.sim.scenarios import Plan, build_plan
from phonepose.record.sim.vio import VioErrorModel, VioErrorParams, arrival_times
from phonepose.record.sim.world import (
    HEIGHT,
    T_DISPLAY_CAMERA,
    WIDTH,
    World,
    build_world,
    marker_corners_in_marker,
    marker_in_view,
)
from phonepose.record.source import Record
from phonepose.schemas import phonepose_pb2 as pb
from phonepose.schemas.topics import Frame, Topic
from phonepose.session.codec import encode_pose, frame_transform, pose_in_frame

T0_NS = 1_700_000_000_000_000_000   # session start on the display's clock (fixed: no wall clock)
IMAGE_LOOKAHEAD = 2                 # frames rendered ahead while earlier ones are JPEG-encoded


@overload
def ns(t_s: float) -> int: ...
@overload
def ns(t_s: np.ndarray) -> np.ndarray: ...
def ns(t_s: float | np.ndarray) -> np.ndarray | int:
    """Seconds from the session start -> absolute display-clock nanoseconds."""
    if np.ndim(t_s) == 0:
        return T0_NS + int(round(float(t_s) * 1e9))
    return T0_NS + np.rint(np.asarray(t_s, dtype=float) * 1e9).astype(np.int64)


def rng_factory(seed: int):
    def rng_for(name: str) -> np.random.Generator:
        return np.random.default_rng([int(seed), zlib.crc32(name.encode())])
    return rng_for


def _grid(rate_hz: float, start: float, end: float, phase: float = 0.0) -> np.ndarray:
    n = int(np.floor((end - start - phase) * rate_hz)) + 1
    return start + phase + np.arange(max(n, 0)) / rate_hz


class SimSession:
    """All streams of one simulated session, precomputed except the images (rendered on demand)."""

    def __init__(self, scenario: str = "exp2", path: str | None = "TRI1", trial: int = 1, seed: int = 0,
                 config: SimConfig | None = None, motion=None):
        self.cfg = cfg = config if config is not None else default_config()
        self.scenario, self.path, self.trial, self.seed = scenario, (path or "") if scenario == "exp2" else "", trial, seed
        rng_for = self.rng_for = rng_factory(seed)
        self.world: World = build_world(cfg, rng_for)
        self.plan: Plan = build_plan(self.world, cfg, scenario, path, trial, rng_for, motion)
        if motion is not None:
            self.path = self.plan.path
        w, plan = self.world, self.plan
        h = cfg.human
        self.oscillations = make_oscillations(rng_for(f"tremor_trial{trial}"), h.tremor_m, h.tremor_deg, h.sway_m, h.sway_deg)
        end = plan.end
        self.duration_s = end

        # ---- controller VIO (its own capture clock phase) and the CM1 alignment
        cv = cfg.controller_vio
        r = rng_for("controller_vio_clock")
        self.t_cvio = _grid(cv.rate_hz, 0.0, end, r.uniform(0, 1 / cv.rate_hz))
        self.cvio_model = VioErrorModel(
            VioErrorParams(cv.jitter_m, cv.tilt_jitter_deg, cv.tilt_jitter_deg, cv.drift_m_per_sqrt_s,
                           cv.drift_per_path_length, cv.yaw_drift_deg_per_sqrt_s, cv.scale_error_sigma,
                           cv.jump_rate_per_min, cv.jump_median_m),
            end, rng_for("controller_vio"))
        white_c = rng_for("controller_vio_white").normal(size=(len(self.t_cvio), 6))
        self.T_map = w.T_dvio_anchor_resolved @ w.T_cvio_anchor_resolved.inv()   # cvio -> dvio via the anchors
        traj0 = self._trajectory()
        self.cvio_model.set_path(self._cvio_base_on_grid(traj0))
        j_fix = int(np.argmin(np.abs(self.t_cvio - plan.t_fix)))
        fix_mapped = self.T_map @ self._cvio_estimate(traj0, self.t_cvio[j_fix:j_fix + 1], white_c[j_fix:j_fix + 1])[0]
        # The user puts the real phone where the CG object is (the fixed, anchor-mapped VIO pose).
        ra = rng_for(f"cm1_alignment_trial{trial}")
        human = Pose(Rotation.from_rotvec(ra.normal(size=3) * np.deg2rad(h.cm1_alignment_deg)),
                     ra.normal(size=3) * h.cm1_alignment_m)
        T_world_aligned = w.T_world_dvio @ fix_mapped @ human
        for k in (plan.cm1_key_index, plan.cm1_key_index + 1):
            plan.keys[k].position = T_world_aligned.translation.copy()
            plan.keys[k].rotation = T_world_aligned.rotation
        self.traj = traj = self._trajectory()
        self.cvio_model.set_path(self._cvio_base_on_grid(traj))
        self.T_cvio_ctrl = self._cvio_estimate(traj, self.t_cvio, white_c)
        self.j_fix = j_fix
        self.j_align = int(np.argmin(np.abs(self.t_cvio - plan.t_align)))
        net = cfg.network
        self.arrive_cvio = arrival_times(self.t_cvio, net.controller_latency_s, net.wifi_jitter_s, rng_for("wifi_vio"))

        # ---- display VIO (tripod: nearly still)
        dv = cfg.display_vio
        self.t_dvio = _grid(dv.rate_hz, 0.0, end)
        dmodel = VioErrorModel(VioErrorParams(dv.jitter_m, dv.jitter_deg, dv.jitter_deg, dv.drift_m_per_sqrt_s, 0.0,
                                              dv.yaw_drift_deg_per_sqrt_s, 0.0),
                               end, rng_for("display_vio"))
        T_dvio_display_true = w.T_world_dvio.inv() @ w.T_world_display
        n = len(self.t_dvio)
        true_stack = Pose(Rotation.concatenate([T_dvio_display_true.rotation] * n),
                          np.tile(T_dvio_display_true.translation, (n, 1)))
        white_d = rng_for("display_vio_white").normal(size=(n, 6))
        self.T_dvio_display = dmodel.apply(self.t_dvio, true_stack, white=white_d)

        # ---- anchors (each device reports its resolved anchor periodically)
        self.t_anchor = _grid(cfg.anchor.rate_hz, 0.0, end)
        r = rng_for("controller_anchor_clock")
        self.t_canchor = _grid(cfg.anchor.rate_hz, 0.0, end, r.uniform(0, 1 / cfg.anchor.rate_hz))
        self.arrive_canchor = arrival_times(self.t_canchor, net.controller_latency_s, net.wifi_jitter_s,
                                            rng_for("wifi_anchor"))

        # ---- IMU
        im = cfg.imu
        r = rng_for("imu_clock")
        t = _grid(im.rate_hz, 0.0, end, r.uniform(0, 1 / im.rate_hz))
        self.t_imu = t[rng_for("imu_drops").random(len(t)) >= im.drop_rate]
        self.gyro, self.accel, self.imu_bias = simulate_imu(traj, self.t_imu, im, rng_for("imu"))
        self.arrive_imu = arrival_times(self.t_imu, net.controller_latency_s, net.wifi_jitter_s, rng_for("wifi_imu"))

        # ---- motion capture (its clock is off by mocap.clock_offset_s)
        mc = cfg.mocap
        off = mc.clock_offset_s
        self.t_gt = _grid(mc.rate_hz, max(0.0, -off), min(end, end - off))
        rn = rng_for("mocap_noise")
        T_world_ctrl = traj(self.t_gt)
        m = len(self.t_gt)
        noise_c = Pose(Rotation.from_rotvec(rn.normal(size=(m, 3)) * np.deg2rad(mc.noise_deg)),
                       rn.normal(size=(m, 3)) * mc.noise_m)
        self.gt_ctrl = T_world_ctrl @ Pose(Rotation.concatenate([w.hand_eye.rotation] * m),
                                           np.tile(w.hand_eye.translation, (m, 1))) @ noise_c
        noise_d = Pose(Rotation.from_rotvec(rn.normal(size=(m, 3)) * np.deg2rad(mc.noise_deg)),
                       rn.normal(size=(m, 3)) * mc.noise_m)
        self.gt_display = Pose(Rotation.concatenate([w.T_world_display.rotation] * m),
                               np.tile(w.T_world_display.translation, (m, 1))) @ noise_d
        self.log_gt = self.t_gt + off

        # ---- camera frames
        cam = cfg.camera
        r = rng_for("camera_clock")
        t = _grid(cam.rate_hz, 0.0, end)
        t = t + r.normal(size=len(t)) * cam.frame_jitter_s
        t = np.maximum.accumulate(np.clip(t, 0.0, end))
        keep = rng_for("camera_drops").random(len(t)) >= cam.drop_rate
        self.t_cam = t[keep]
        T_cw = w.T_world_camera.inv()
        self.T_cam_ctrl = T_cw @ traj(self.t_cam)
        self.in_view = marker_in_view(w, self.T_cam_ctrl, cfg.marker.size_m)
        self.blur = None
        if cfg.render.motion_blur and cfg.render.exposure_s > 0:
            e = cfg.render.exposure_s / 2
            c0 = self._marker_center_px(T_cw @ traj(self.t_cam - e))
            c1 = self._marker_center_px(T_cw @ traj(self.t_cam + e))
            self.blur = c1 - c0
        rb = rng_for("brightness")
        ph = rb.uniform(0, 2 * np.pi, 2)
        a = cfg.render.brightness_variation
        self.gain = 1.0 + a * (0.6 * np.sin(2 * np.pi * self.t_cam / 7.0 + ph[0]) +
                               0.4 * np.sin(2 * np.pi * self.t_cam / 13.0 + ph[1]))
        cm2 = int(np.argmin(np.abs(self.t_cam - plan.t_cm2)))
        self.t_cm2 = float(self.t_cam[cm2])
        self._renderer: Renderer | None = None
        self._R_cam_ctrl: np.ndarray | None = None

    # ------------------------------------------------------------------ helpers
    def _trajectory(self):
        """The simulated hand (key poses, tremor, sway), or it until the task and then a recorded window."""
        keyed = Trajectory(self.plan.keys, *self.oscillations)
        if self.plan.recorded is None:
            return keyed
        from phonepose.record.sim.recorded import MotionTrajectory
        window, facing, centre = self.plan.recorded
        return MotionTrajectory(keyed, self.plan.task_start, window, facing, centre, self.plan.end)

    def _cvio_base_on_grid(self, traj: Trajectory) -> np.ndarray:
        grid = self.cvio_model.grid
        return (self.world.T_world_cvio.inv() @ traj.base(np.clip(grid, traj.start, traj.end))).translation

    def _cvio_estimate(self, traj: Trajectory, t: np.ndarray, white: np.ndarray) -> Pose:
        true = self.world.T_world_cvio.inv() @ traj(t)
        return self.cvio_model.apply(t, true, white=white)

    def _marker_center_px(self, T_cam_ctrl: Pose) -> np.ndarray:
        p = T_cam_ctrl.apply(self.world.T_controller_marker.translation)
        z = np.maximum(p[:, 2:3], 1e-3)
        return p[:, :2] / z * np.diag(self.world.camera.K)[:2]

    @property
    def renderer(self) -> Renderer:
        if self._renderer is None:
            self._renderer = Renderer(self.cfg, self.world.camera, self.rng_for("render_setup"))
        return self._renderer

    def mapped_controller(self) -> Pose:
        """Anchor-mapped controller VIO poses in display_vio at ``t_cvio`` (what T1 uses)."""
        return self.T_map @ self.T_cvio_ctrl

    def true_controller_in_dvio(self, t: np.ndarray) -> Pose:
        return self.world.T_world_dvio.inv() @ self.traj(t)

    def marker_corners_px(self, i: int) -> np.ndarray:
        """The true marker corners (TL, TR, BR, BL; distorted pixels) in camera frame ``i``."""
        T_cm = self.T_cam_ctrl[i] @ self.world.T_controller_marker
        return self.world.camera.project(T_cm.apply(marker_corners_in_marker(self.cfg.marker.size_m)))

    def render_frame(self, i: int, rng: np.random.Generator) -> np.ndarray:
        if self._R_cam_ctrl is None:
            self._R_cam_ctrl = self.T_cam_ctrl.rotation.as_matrix()
        blur = None if self.blur is None else self.blur[i]
        return self.renderer.render((self._R_cam_ctrl[i], self.T_cam_ctrl.translation[i]), blur, float(self.gain[i]), rng)

    @property
    def task_frames_20hz(self) -> int:
        return int(round((self.plan.task_end - self.plan.task_start) * 20.0))


class SimSource:
    """A :class:`phonepose.record.source.Source` over a :class:`SimSession`."""

    def __init__(self, session: SimSession):
        self.session = session
        self.start_ns = T0_NS
        self.duration_ns = int(round(session.duration_s * 1e9))

    def close(self) -> None:
        pass

    # ------------------------------------------------------------------ static part
    def static(self) -> list[Record]:
        s, cfg, w, plan = self.session, self.session.cfg, self.session.world, self.session.plan
        t0 = T0_NS
        info = pb.SessionInfo(source="sim", scenario=s.scenario, path=s.path, trial=s.trial, seed=s.seed,
                              phonepose_version=__version__, config_toml=cfg.to_toml(),
                              description=_describe(s), ground_truth_source="simulator")
        info.timestamp.FromNanoseconds(t0)
        info.task_start.FromNanoseconds(ns(plan.task_start))
        info.task_end.FromNanoseconds(ns(plan.task_end))
        K = w.camera.K
        calib = CameraCalibration(frame_id=Frame.DISPLAY_CAMERA, width=WIDTH, height=HEIGHT,
                                  distortion_model="plumb_bob", D=[float(v) for v in w.camera.D],
                                  K=[float(v) for v in K.ravel()], R=[1, 0, 0, 0, 1, 0, 0, 0, 1],
                                  P=[K[0, 0], 0, K[0, 2], 0, 0, K[1, 1], K[1, 2], 0, 0, 0, 1, 0])
        calib.timestamp.FromNanoseconds(t0)
        spec = pb.MarkerSpec(dictionary=cfg.marker.dictionary, id=cfg.marker.id, size_m=cfg.marker.size_m)
        spec.timestamp.FromNanoseconds(t0)
        encode_pose(w.T_controller_marker, spec.pose_in_body)
        out = [
            Record(Topic.SESSION_INFO, info, t0, t0),
            Record(Topic.CAMERA_CALIBRATION, calib, t0, t0),
            Record(Topic.CAMERA_EXTRINSICS, frame_transform(T_DISPLAY_CAMERA, Frame.DISPLAY, Frame.DISPLAY_CAMERA, t0), t0, t0),
            Record(Topic.CONTROLLER_MARKER, spec, t0, t0),
            Record(Topic.GT_CALIBRATION, frame_transform(w.T_world_dvio @ w.calibration_error, Frame.WORLD,
                                                         Frame.DISPLAY_VIO, t0), t0, t0),
        ]
        T_dvio_world = w.T_world_dvio.inv()
        if plan.targets:
            msg = pb.Targets(frame_id=Frame.DISPLAY_VIO, cube_size_m=0.02, select_radius_m=0.02)
            msg.timestamp.FromNanoseconds(t0)
            for tg in plan.targets:
                m = msg.targets.add(index=tg.index, inside_view=tg.inside_view)
                encode_pose(T_dvio_world @ tg.T_world, m.pose)
                m.hold_start.FromNanoseconds(ns(tg.hold_start))
                m.hold_end.FromNanoseconds(ns(tg.hold_end))
            out.append(Record(Topic.EXPERIMENT_TARGETS, msg, t0, t0))
        if plan.waypoints_world is not None:
            msg = pb.PathSpec(frame_id=Frame.DISPLAY_VIO, name=plan.path, trial=plan.trial, closed=plan.closed)
            msg.timestamp.FromNanoseconds(t0)
            for p in T_dvio_world.apply(plan.waypoints_world):
                msg.waypoints.add(x=float(p[0]), y=float(p[1]), z=float(p[2]))
            out.append(Record(Topic.EXPERIMENT_PATH, msg, t0, t0))
        return out

    # ------------------------------------------------------------------ streams
    def __iter__(self) -> Iterator[Record]:
        s = self.session
        streams = [self._images(), self._poses(Topic.DISPLAY_VIO_POSE, Frame.DISPLAY_VIO, s.t_dvio, s.t_dvio,
                                               s.T_dvio_display),
                   self._constant(Topic.DISPLAY_ANCHOR, Frame.DISPLAY_VIO, s.t_anchor, s.t_anchor,
                                  s.world.T_dvio_anchor_resolved),
                   self._poses(Topic.CONTROLLER_VIO_POSE, Frame.CONTROLLER_VIO,
                               s.t_cvio + s.cfg.network.controller_clock_offset_s, s.arrive_cvio, s.T_cvio_ctrl),
                   self._constant(Topic.CONTROLLER_ANCHOR, Frame.CONTROLLER_VIO,
                                  s.t_canchor + s.cfg.network.controller_clock_offset_s, s.arrive_canchor,
                                  s.world.T_cvio_anchor_resolved),
                   self._imu(),
                   self._poses(Topic.GT_CONTROLLER_POSE, Frame.WORLD, s.log_gt, s.log_gt, s.gt_ctrl),
                   self._poses(Topic.GT_DISPLAY_POSE, Frame.WORLD, s.log_gt, s.log_gt, s.gt_display),
                   self._events(), self._logs()]
        keyed = [((r.log_time_ns, k, i, r) for i, r in enumerate(st)) for k, st in enumerate(streams)]
        for _, _, _, rec in heapq.merge(*keyed, key=lambda x: x[:3]):
            yield rec

    def _images(self) -> Iterator[Record]:
        """Rendered frames; JPEG encoding (which releases the GIL) runs in a worker thread while
        the next frames render. Output is identical to encoding inline."""
        s = self.session
        rng = s.rng_for("render_frames")

        def record(i: int, jpeg: bytes) -> Record:
            t_ns = ns(s.t_cam[i])
            msg = CompressedImage(frame_id=Frame.DISPLAY_CAMERA, format="jpeg", data=jpeg)
            msg.timestamp.FromNanoseconds(t_ns)
            return Record(Topic.CAMERA_IMAGE, msg, t_ns, t_ns)

        with ThreadPoolExecutor(max_workers=1) as pool:
            pending: deque = deque()
            for i in range(len(s.t_cam)):
                pending.append((i, pool.submit(s.renderer.encode, s.render_frame(i, rng))))
                if len(pending) > IMAGE_LOOKAHEAD:
                    j, fut = pending.popleft()
                    yield record(j, fut.result())
            while pending:
                j, fut = pending.popleft()
                yield record(j, fut.result())

    @staticmethod
    def _poses(topic: str, frame: str, stamp_s: np.ndarray, log_s: np.ndarray, poses: Pose) -> Iterator[Record]:
        stamps, logs = ns(stamp_s), ns(log_s)
        trans = poses.translation
        quats = poses.rotation.as_quat()
        for i in range(len(stamps)):
            msg = PoseInFrame(frame_id=frame)
            msg.timestamp.FromNanoseconds(int(stamps[i]))
            p, q = msg.pose.position, msg.pose.orientation
            p.x, p.y, p.z = (float(v) for v in trans[i])
            q.x, q.y, q.z, q.w = (float(v) for v in quats[i])
            yield Record(topic, msg, int(logs[i]), int(logs[i]))

    def _constant(self, topic: str, frame: str, stamp_s, log_s, pose: Pose) -> Iterator[Record]:
        for st, lg in zip(ns(stamp_s), ns(log_s), strict=True):
            yield Record(topic, pose_in_frame(pose, frame, int(st)), int(lg), int(lg))

    def _imu(self) -> Iterator[Record]:
        s = self.session
        stamps = ns(s.t_imu + s.cfg.network.controller_clock_offset_s)
        logs = ns(s.arrive_imu)
        g, a = s.gyro, s.accel
        for i in range(len(stamps)):
            msg = pb.Imu(frame_id=Frame.CONTROLLER, gyro_x=g[i, 0], gyro_y=g[i, 1], gyro_z=g[i, 2],
                         accel_x=a[i, 0], accel_y=a[i, 1], accel_z=a[i, 2])
            msg.timestamp.FromNanoseconds(int(stamps[i]))
            yield Record(Topic.CONTROLLER_IMU, msg, int(logs[i]), int(logs[i]))

    def _events(self) -> Iterator[Record]:
        s = self.session
        mapped_fix = s.T_map @ s.T_cvio_ctrl[s.j_fix]
        mapped_align = s.T_map @ s.T_cvio_ctrl[s.j_align]
        cm1 = pb.CalibrationEvent(kind=pb.CalibrationEvent.CM1, frame_id=Frame.DISPLAY_VIO)
        cm1.timestamp.FromNanoseconds(ns(s.t_cvio[s.j_align]))
        cm1.fix_timestamp.FromNanoseconds(ns(s.t_cvio[s.j_fix]))
        encode_pose(mapped_fix, cm1.pose_fix_vio)
        encode_pose(mapped_align, cm1.pose_align_vio)
        cm2 = pb.CalibrationEvent(kind=pb.CalibrationEvent.CM2, frame_id=Frame.DISPLAY_VIO)
        cm2.timestamp.FromNanoseconds(ns(s.t_cm2))
        # the display makes the CM1 event when the aligned VIO pose has arrived
        out = [Record(Topic.CALIBRATION_EVENTS, cm1, int(ns(s.arrive_cvio[s.j_align])), int(ns(s.arrive_cvio[s.j_align]))),
               Record(Topic.CALIBRATION_EVENTS, cm2, ns(s.t_cm2), ns(s.t_cm2))]
        out.sort(key=lambda r: r.log_time_ns)
        yield from out

    def _logs(self) -> Iterator[Record]:
        s, plan = self.session, self.session.plan
        items = [(0.0, f"simulated session: {_describe(s)}"), (plan.task_start, "task start"), (plan.task_end, "task end")]
        for t, text in items:
            msg = Log(level=Log.INFO, message=text, name="phonepose.sim")
            msg.timestamp.FromNanoseconds(ns(t))
            yield Record(Topic.LOG, msg, ns(t), ns(t))


def _describe(s: SimSession) -> str:
    what = f"exp2 {s.path} trial {s.trial}" if s.scenario == "exp2" else f"exp1 trial {s.trial}"
    return f"{what}, seed {s.seed}, {s.duration_s:.1f} s"
