// The rehearsal's emulated device (phonepose/record/rehearse): injected into the real phone or headset
// page after IWER (iwer.min.js, Meta's Immersive Web Emulation Runtime) by Playwright's
// add_init_script, before the page's own scripts run. It installs IWER's WebXR runtime and plays
// pose tables that the Python side computed from a simulated session:
//
//   window.__rehearsal.load({mode: 'phone'|'headset', viewer, right, left, imu})   tables on sim time
//   window.__rehearsal.start(t0Ms)   sim time 0 = page time t0Ms (performance.timeOrigin + now, ms)
//
// The device holds IWER's default pose (1.6 m standing height) until the page has its reference space,
// then plays the tables at every XR frame.
//
// Pose keying: IWER takes the frame's time (performance.now()) and then, in its device's private
// onFrameStart, copies the device and controller poses into the frame's spaces; pose setters called
// at any other moment land on whichever frame comes next. So onFrameStart is wrapped: every XR frame
// gets the table's pose at exactly that frame's time (the `time` the page's callback receives).
// IWER keeps onFrameStart and the frame's time behind Symbol-keyed private fields; they are found by
// their descriptions ('@iwer/xr-device', '@iwer/xr-frame'; iwer 2.5's lib/private.js).
//
// DeviceMotion: IWER emulates none, so on the phone page a timer dispatches `devicemotion` events
// with the simulated IMU interpolated at the event's time (gyro -> rotationRate beta/gamma/alpha in
// deg/s about x/y/z, accel -> accelerationIncludingGravity), which the page reads as from a phone.
'use strict';

(function () {
  const RAD_TO_DEG = 180 / Math.PI;
  const IMU_PERIOD_MS = 5; // the simulator's IMU rate (200 Hz)
  const device = new IWER.XRDevice(IWER.metaQuest3);
  device.position.set(0, 1.6, 0); // scene.PHONE_HOME: where 'local' is, until the drive starts
  device.quaternion.set(0, 0, 0, 1);
  device.installRuntime({ forceInstall: true });

  const state = { tables: null, t0: null, frames: 0, driven: 0, imu: 0, mode: '', lastS: NaN, spaces: [] };

  // The device moves only once the page has its reference space: IWER makes 'local' the viewer's pose
  // at that moment, which must be the home pose (scene.PHONE_HOME) the tables are expressed against.
  const requestSession = navigator.xr.requestSession.bind(navigator.xr);
  navigator.xr.requestSession = async function (...args) {
    const session = await requestSession(...args);
    const requestReferenceSpace = session.requestReferenceSpace.bind(session);
    session.requestReferenceSpace = async function (type) {
      const space = await requestReferenceSpace(type);
      state.spaces.push(type);
      return space;
    };
    return session;
  };

  // IWER has no DOM overlay: during a session its canvas covers the page, so taps would land on it. A
  // phone's DOM overlay keeps the page's controls on top; here the canvas lets taps through instead.
  document.addEventListener('DOMContentLoaded', () => {
    const style = document.createElement('style');
    style.textContent = '[data-webxr_runtime] { pointer-events: none !important; }';
    document.head.appendChild(style);
  });

  const symbol = (obj, description) =>
    Object.getOwnPropertySymbols(obj).find((s) => s.description === description);
  const P_DEVICE = symbol(device, '@iwer/xr-device');
  const internals = device[P_DEVICE];

  // ---------------------------------------------------------------- tables
  function find(t, s) {
    // index i with t[i] <= s < t[i + 1], clamped to the table
    let lo = 0, hi = t.length - 1;
    if (s <= t[0]) return 0;
    if (s >= t[hi]) return hi;
    while (hi - lo > 1) {
      const mid = (lo + hi) >> 1;
      if (t[mid] <= s) lo = mid; else hi = mid;
    }
    return lo;
  }

  function slerp(a, b, u) {
    let dot = a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3];
    const sign = dot < 0 ? -1 : 1;
    dot = Math.abs(dot);
    let wa = 1 - u, wb = u;
    if (dot < 0.9999995) {
      const th = Math.acos(dot);
      const s = Math.sin(th);
      wa = Math.sin((1 - u) * th) / s;
      wb = Math.sin(u * th) / s;
    }
    const q = [0, 1, 2, 3].map((k) => wa * a[k] + sign * wb * b[k]);
    const n = Math.hypot(q[0], q[1], q[2], q[3]);
    return q.map((v) => v / n);
  }

  function poseAt(table, s) {
    const t = table.t;
    const i = find(t, s);
    if (i >= t.length - 1 || s <= t[0]) return { p: table.p[i], q: table.q[i] };
    const u = (s - t[i]) / (t[i + 1] - t[i]);
    const p0 = table.p[i], p1 = table.p[i + 1];
    return { p: [0, 1, 2].map((k) => p0[k] + u * (p1[k] - p0[k])), q: slerp(table.q[i], table.q[i + 1], u) };
  }

  function vectorAt(t, rows, s) {
    const i = find(t, s);
    if (i >= t.length - 1 || s <= t[0]) return rows[i];
    const u = (s - t[i]) / (t[i + 1] - t[i]);
    return [0, 1, 2].map((k) => rows[i][k] + u * (rows[i + 1][k] - rows[i][k]));
  }

  function place(target, pose) {
    target.position.set(pose.p[0], pose.p[1], pose.p[2]);
    target.quaternion.set(pose.q[0], pose.q[1], pose.q[2], pose.q[3]);
  }

  const simTime = (pageMs) => (pageMs - state.t0) / 1000;

  // ---------------------------------------------------------------- every XR frame
  const onFrameStart = internals.onFrameStart;
  internals.onFrameStart = function (frame) {
    state.frames += 1;
    if (state.tables !== null && state.t0 !== null && state.spaces.length > 0) {
      const P_FRAME = symbol(frame, '@iwer/xr-frame');
      const s = simTime(performance.timeOrigin + frame[P_FRAME].predictedDisplayTime);
      state.lastS = s;
      const tb = state.tables;
      place(device, poseAt(tb.viewer, s));
      if (tb.right) place(device.controllers.right, poseAt(tb.right, s));
      if (tb.left) place(device.controllers.left, poseAt(tb.left, s));
      state.driven += 1;
    }
    return onFrameStart.call(this, frame);
  };

  // ---------------------------------------------------------------- DeviceMotion (phone)
  function imuTick() {
    const imu = state.tables && state.tables.imu;
    if (!imu || state.t0 === null) return;
    const now = performance.now();
    const s = simTime(performance.timeOrigin + now);
    if (s < imu.t[0] || s > imu.t[imu.t.length - 1]) return;
    const g = vectorAt(imu.t, imu.gyro, s);
    const a = vectorAt(imu.t, imu.accel, s);
    window.dispatchEvent(new DeviceMotionEvent('devicemotion', {
      accelerationIncludingGravity: { x: a[0], y: a[1], z: a[2] },
      rotationRate: { alpha: g[2] * RAD_TO_DEG, beta: g[0] * RAD_TO_DEG, gamma: g[1] * RAD_TO_DEG },
      interval: IMU_PERIOD_MS,
    }));
    state.imu += 1;
  }

  window.__rehearsal = {
    state,
    device,
    load(tables) {
      state.mode = tables.mode;
      state.tables = tables;
      if (tables.imu) setInterval(imuTick, IMU_PERIOD_MS);
    },
    start(t0Ms) {
      state.t0 = t0Ms;
    },
    gripOffset(hand) {
      return Array.from(IWER.metaQuest3.controllerConfig.layout[hand].gripOffsetMatrix);
    },
    nowMs() {
      return performance.timeOrigin + performance.now();
    },
  };
})();
