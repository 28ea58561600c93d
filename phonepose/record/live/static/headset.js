// phonepose headset page: the ground truth of a live recording (the paper's L-sensor). In an
// immersive-vr session it sends, every XR frame, the viewer's pose and every controller's grip pose
// (inputSource.gripSpace, with its handedness) in one stationary reference space ('local-floor',
// else 'local'), stamped with the XR frame's time, to `phonepose record live` (link.js: the
// connection and its clock pings). The numbers are WebXR's own (right-handed, y up, -z forward,
// quaternions x, y, z, w): the recorder converts them (phonepose/record/live/webxr.py).
// Protocol reference: docs/phone-page.md ("The headset page").
'use strict';

(function () {
  const NOT_AVAILABLE = 'WebXR immersive-vr is not available in this browser';
  const { token, $, showError, clearError, AccessDenied, fetchChecked } = window.PhoneposeLink;

  const state = {
    gtHand: 'right', // the controller fixed to the phone (/config, `record live --gt-controller`)
    xr: null, // {ok: bool, message: str}
    session: null,
    refSpace: null,
    spaceName: '',
    gl: null,
    counts: { frames: 0, sent: 0, viewerLost: 0 },
    tracked: false, // the phone's controller had a grip pose in the last frame
    lost: 0, // times it lost tracking (a pose, then none)
    everTracked: false,
    handsSeen: [],
  };
  const link = new window.PhoneposeLink.Link({
    role: 'headset',
    hello: () => ({
      type: 'hello',
      user_agent: navigator.userAgent,
      webxr: Boolean(state.xr && state.xr.ok),
      message: state.xr ? state.xr.message : '',
    }),
    onOpen: () => {
      if (state.session) sendSessionState('started', 'reconnected during the session');
    },
    onMessage: (msg) => {
      if (msg.type === 'status') {
        $('server-status').textContent = 'recording: ' + (msg.recording ? 'yes' : 'no');
      }
    },
    setConn: (text) => {
      $('conn').textContent = text;
    },
  });
  // For debugging (the headset browser's remote inspector) and for the headless test.
  window.phonepose = { state, link };

  // ---------------------------------------------------------------- WebXR
  function checkWebXR() {
    return window.PhoneposeLink.checkWebXR('immersive-vr', {
      notAvailable: NOT_AVAILABLE,
      hint: ': open this link in the browser of a WebXR headset (Meta Quest, Pico, ...)',
      available: 'WebXR immersive-vr is available: press "Enter VR" to stream the ground truth',
    });
  }

  function sendSessionState(sessionState, message) {
    link.send({ type: 'xrsession', state: sessionState, space: state.spaceName, message: message || '' });
  }

  async function enterVR() {
    const started = await window.PhoneposeLink.startXRSession(state.session, 'immersive-vr', { optionalFeatures: ['local-floor'] }, {}, 'VR', () => {
      state.session = null;
      state.refSpace = null;
      sendSessionState('ended', '');
      $('btn-vr').textContent = 'Enter VR';
      showTracking();
    });
    if (!started) return;
    const session = started.session;
    state.session = session;
    state.gl = started.gl;
    // One stationary space for every pose: 'local-floor' (y = 0 on the floor) where the device has
    // it, else 'local' (origin at the headset's pose at session start), said once.
    let note = '';
    try {
      state.refSpace = await session.requestReferenceSpace('local-floor');
      state.spaceName = 'local-floor';
    } catch (e) {
      state.refSpace = await session.requestReferenceSpace('local');
      state.spaceName = 'local';
      note = 'no local-floor reference space (' + e.message + '): poses are in local';
      showError('Note: ' + note, 'space');
    }
    sendSessionState('started', note);
    $('btn-vr').textContent = 'Exit VR';
    session.requestAnimationFrame(onXRFrame);
  }

  function poseOf(transform) {
    return {
      p: [transform.position.x, transform.position.y, transform.position.z],
      q: [transform.orientation.x, transform.orientation.y, transform.orientation.z, transform.orientation.w],
    };
  }

  function onXRFrame(time, frame) {
    const session = frame.session;
    session.requestAnimationFrame(onXRFrame);
    state.counts.frames += 1;
    const viewer = frame.getViewerPose(state.refSpace);
    if (!viewer) state.counts.viewerLost += 1;
    const controllers = [];
    const hands = [];
    let tracked = false;
    for (const source of session.inputSources) {
      // A gaze or screen input has no body to track; a tracked hand (source.hand, Quest hand
      // tracking when the controllers are put down) is not the controller on the phone.
      if (!source.gripSpace || source.hand) continue;
      hands.push(source.handedness);
      const grip = frame.getPose(source.gripSpace, state.refSpace);
      const entry = { hand: source.handedness };
      if (grip) Object.assign(entry, poseOf(grip.transform));
      if (grip && source.handedness === state.gtHand) tracked = true;
      controllers.push(entry);
    }
    if (state.tracked && !tracked) state.lost += 1;
    state.tracked = tracked;
    state.everTracked = state.everTracked || tracked;
    state.handsSeen = hands;
    // `time` is the frame's DOMHighResTimeStamp, on the same clock as performance.now().
    const msg = { type: 'xrframe', t: performance.timeOrigin + time, viewer: viewer ? poseOf(viewer.transform) : null, controllers };
    if (link.sendSample(msg)) state.counts.sent += 1;
    // What the wearer sees: green while the phone's controller is tracked, red while it is not.
    const gl = state.gl;
    gl.bindFramebuffer(gl.FRAMEBUFFER, session.renderState.baseLayer.framebuffer);
    if (tracked) gl.clearColor(0.0, 0.35, 0.1, 1.0);
    else gl.clearColor(0.45, 0.0, 0.0, 1.0);
    gl.clear(gl.COLOR_BUFFER_BIT);
  }

  // The page's line about the controllers (read after leaving VR, and by the tests).
  function showTracking() {
    const el = $('tracking');
    const c = state.counts;
    let text;
    if (!c.frames) {
      text = '';
    } else if (!state.handsSeen.length && !state.everTracked) {
      text = 'No controllers in the VR session: turn on the ' + state.gtHand + ' controller (fixed to the phone) or press one of its buttons.';
    } else if (!state.everTracked) {
      text = 'No ' + state.gtHand + ' controller in the VR session (only ' + state.handsSeen.join(', ') + '): the controller fixed to the phone must be the ' + state.gtHand + ' one (`record live --gt-controller`).';
    } else if (state.lost) {
      text = 'The ' + state.gtHand + ' controller lost tracking ' + state.lost + ' time(s): the ground truth has gaps there (keep it in the headset\'s view).';
    } else {
      text = 'The ' + state.gtHand + ' controller was tracked in every frame.';
    }
    el.textContent = text;
    el.className = state.everTracked && !state.lost ? 'status' : (c.frames ? 'warning' : 'status');
  }

  function updateCounts() {
    const c = state.counts;
    $('counts').textContent = 'frames ' + c.frames + ' · sent ' + c.sent + (link.dropped ? ' · dropped ' + link.dropped : '') +
      (state.session ? ' · ' + state.gtHand + ' controller ' + (state.tracked ? 'tracked' : 'NOT tracked') : '');
    showTracking();
  }

  async function main() {
    $('btn-vr').addEventListener('click', enterVR);
    setInterval(updateCounts, 250);
    const xrCheck = checkWebXR();
    if (!token) {
      showError('This link has no ?token=…: open the URL or QR code printed by `phonepose record live`.', 'access');
    } else {
      try {
        const config = await (await fetchChecked('/config')).json();
        if (config.gt_controller === 'left' || config.gt_controller === 'right') state.gtHand = config.gt_controller;
      } catch (e) {
        if (e instanceof AccessDenied) link.deny();
        else showError('Could not reach the laptop: ' + e.message, 'config');
      }
    }
    $('gt-hand').textContent = state.gtHand;
    state.xr = await xrCheck;
    window.PhoneposeLink.finishStart(link, state.xr, 'btn-vr');
  }

  main();
})();
