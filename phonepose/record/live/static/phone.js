// phonepose phone page: shows the fiducial marker full-screen at a known physical size and streams
// the phone's WebXR 6DoF pose, anchors and DeviceMotion IMU samples to `phonepose record live`
// over a WebSocket (link.js: the connection, its clock pings, the error line). Plain JavaScript, no
// build step, no external resources (the phone may be on a network without Internet access).
// Protocol reference: docs/phone-page.md.
'use strict';

(function () {
  const MM_PER_INCH = 25.4;
  const M_PER_INCH = 0.0254;
  const DEG_TO_RAD = Math.PI / 180; // same constant as Python's math.radians
  const RULER_MM = 50;
  const PPI_KEY = 'phonepose.ppi';
  const NOT_AVAILABLE = 'WebXR immersive-ar is not available in this browser';

  const { token, params, $, showError, clearError, nowMs, AccessDenied, fetchChecked } = window.PhoneposeLink;

  const state = {
    config: null, // {"marker": {"dictionary": str, "id": int}}
    marker: null, // {bits: 2D array of 0/1 (1 = black) or null, image, bbox}
    markerMsg: null, // the last marker message computed (sent on connect and when it changes)
    markerMsgSent: '',
    ppi: 0,
    ppiSource: 'guess', // 'url' | 'saved' | 'input' | 'guess'
    xr: null, // {ok: bool, message: str}
    xrSession: null,
    xrRefSpace: null,
    xrGl: null,
    anchorRequested: false,
    anchors: [],
    counts: { imu: 0, pose: 0, anchor: 0, motionWithoutData: 0 },
  };
  const link = new window.PhoneposeLink.Link({
    role: 'phone',
    hello: () => ({
      type: 'hello',
      user_agent: navigator.userAgent,
      webxr: Boolean(state.xr && state.xr.ok),
      message: state.xr ? state.xr.message : '',
    }),
    onOpen: () => sendMarker(true),
    onMessage: onServerMessage,
    setConn,
  });
  // For debugging on the phone (chrome://inspect) and for the headless test.
  window.phonepose = { state, link };

  function setConn(text) {
    $('conn').textContent = text;
  }

  // ---------------------------------------------------------------- time (link.js: nowMs)
  function eventTimeMs(ev) {
    const ts = ev.timeStamp;
    // Chrome gives event.timeStamp relative to timeOrigin; very old engines gave epoch ms.
    if (typeof ts === 'number' && ts > 0 && ts < 1e12) return performance.timeOrigin + ts;
    return nowMs();
  }

  // ---------------------------------------------------------------- server messages (link.js: ping, error)
  function onServerMessage(msg) {
    if (msg.type === 'status') {
      const yn = (v) => (v ? 'yes' : 'no');
      $('server-status').textContent =
        'recording: ' + yn(msg.recording) + ' · anchor: ' + (msg.anchor ? 'set' : 'not set') +
        ' · marker seen: ' + yn(msg.marker_seen);
    }
  }

  // ---------------------------------------------------------------- screen ppi
  function validPpi(v) {
    return Number.isFinite(v) && v >= 50 && v <= 2000;
  }

  function guessPpi() {
    // Android Chrome sets devicePixelRatio = density bucket / 160, so a CSS px is about 1/160 in
    // on phones (1/96 in on desktops). Only a guess: real panels differ by up to ~20 %.
    const mobile = /Android|iPhone|iPad|Mobile/i.test(navigator.userAgent);
    return Math.round((mobile ? 160 : 96) * (window.devicePixelRatio || 1));
  }

  function initialPpi() {
    const fromUrl = parseFloat(params.get('ppi'));
    if (validPpi(fromUrl)) return [fromUrl, 'url'];
    let saved = NaN;
    try {
      saved = parseFloat(localStorage.getItem(PPI_KEY));
    } catch (e) {
      // storage disabled: no remembered value
    }
    if (validPpi(saved)) return [saved, 'saved'];
    return [guessPpi(), 'guess'];
  }

  function setPpi(ppi, source) {
    state.ppi = ppi;
    state.ppiSource = source;
    $('ppi').value = String(ppi);
    $('ppi-warning').hidden = source !== 'guess';
    if (source === 'guess') $('settings').hidden = false;
    const dpr = window.devicePixelRatio || 1;
    // The ruler: 50 mm = 50 / 25.4 in = 50 / 25.4 * ppi device px = that / dpr CSS px.
    $('ruler').style.width = (RULER_MM / MM_PER_INCH) * ppi / dpr + 'px';
    layoutMarker();
  }

  // While the user types ("3", "35", "350") only the last value counts: it is applied when the
  // field changes (Enter, leaving it) or after a pause in typing.
  let ppiTimer = null;

  function onPpiTyping() {
    clearTimeout(ppiTimer);
    ppiTimer = setTimeout(onPpiInput, 700);
  }

  function onPpiInput() {
    clearTimeout(ppiTimer);
    const v = parseFloat($('ppi').value);
    if (!validPpi(v)) return;
    try {
      localStorage.setItem(PPI_KEY, String(v));
    } catch (e) {
      // not remembered; still used on this page
    }
    setPpi(v, 'input');
  }

  // ---------------------------------------------------------------- the marker
  async function loadMarker() {
    const blob = await (await fetchChecked('/marker.png')).blob();
    const url = URL.createObjectURL(blob);
    const img = new Image();
    try {
      img.src = url;
      await img.decode();
    } finally {
      URL.revokeObjectURL(url);
    }
    const c = document.createElement('canvas');
    c.width = img.naturalWidth;
    c.height = img.naturalHeight;
    const ctx = c.getContext('2d', { willReadFrequently: true });
    ctx.drawImage(img, 0, 0);
    const data = ctx.getImageData(0, 0, c.width, c.height).data;
    const dark = (x, y) => {
      const i = 4 * (y * c.width + x);
      return 0.299 * data[i] + 0.587 * data[i + 1] + 0.114 * data[i + 2] < 128;
    };
    // The black marker square is the bounding box of the dark pixels: an ArUco marker's outer
    // border is entirely black, and everything around it in the PNG is the white quiet zone,
    // whatever its width. The quiet zone of the PNG is therefore discarded and redrawn here.
    let x0 = c.width, y0 = c.height, x1 = -1, y1 = -1;
    for (let y = 0; y < c.height; y++) {
      for (let x = 0; x < c.width; x++) {
        if (dark(x, y)) {
          if (x < x0) x0 = x;
          if (x > x1) x1 = x;
          if (y < y0) y0 = y;
          if (y > y1) y1 = y;
        }
      }
    }
    if (x1 < 0) throw new Error('/marker.png has no dark pixels');
    const bbox = { x: x0, y: y0, w: x1 - x0 + 1, h: y1 - y0 + 1 };
    // Read the marker's cell grid, so it is redrawn with every cell an exact whole number of
    // device pixels (sharp edges at any devicePixelRatio). The cell count is the first candidate
    // whose every cell is uniformly black or white in the PNG: for "DICT_NXN_M" first N + 2, N + 4,
    // N + 6 (black border of 1, 2, 3 cells), then any count from 3 to 32. If none fits, the PNG's
    // marker square is scaled as it is (nearest neighbour).
    const grid = readGrid(dark, bbox, state.config.marker.dictionary);
    return { bits: grid ? grid.bits : null, cells: grid ? grid.cells : 0, image: c, bbox };
  }

  const SAMPLES = [0.2, 0.35, 0.5, 0.65, 0.8]; // where each cell is probed, as fractions of a cell

  function readGrid(dark, bbox, dictionary) {
    const candidates = [];
    const m = /^DICT_(\d+)X\1_\d+$/.exec(dictionary || '');
    if (m) candidates.push(Number(m[1]) + 2, Number(m[1]) + 4, Number(m[1]) + 6);
    for (let cells = 3; cells <= 32; cells++) candidates.push(cells);
    for (const cells of candidates) {
      if (bbox.w / cells < 4) continue;
      const bits = [];
      let uniform = true;
      for (let r = 0; r < cells && uniform; r++) {
        const row = [];
        for (let k = 0; k < cells && uniform; k++) {
          let black = 0;
          for (const fy of SAMPLES) {
            for (const fx of SAMPLES) {
              const x = Math.floor(bbox.x + (k + fx) * bbox.w / cells);
              const y = Math.floor(bbox.y + (r + fy) * bbox.h / cells);
              if (dark(x, y)) black += 1;
            }
          }
          uniform = black === 0 || black === SAMPLES.length * SAMPLES.length;
          row.push(black ? 1 : 0);
        }
        bits.push(row);
      }
      if (uniform) return { cells, bits };
    }
    return null;
  }

  // Lays the marker out as large as the marker area allows, keeping a white quiet zone of at
  // least one cell on every side, and computes its true size:
  //   side_dev = the black square's width in device pixels (a whole multiple of the cell count)
  //   W        = side_dev / devicePixelRatio   (its width in CSS px: the canvas's CSS width)
  //   size_m   = W * devicePixelRatio / ppi * 0.0254
  function layoutMarker() {
    const m = state.marker;
    if (!m || !state.ppi) return;
    const area = $('marker-area');
    const canvas = $('marker');
    const dpr = window.devicePixelRatio || 1;
    const areaW = Math.floor(area.clientWidth * dpr);
    const areaH = Math.floor(area.clientHeight * dpr);
    const avail = Math.min(areaW, areaH);
    let side;
    if (m.cells) {
      const cellPx = Math.floor(avail / (m.cells + 2));
      side = cellPx * m.cells;
    } else {
      side = Math.floor(avail * 0.8); // unknown grid: a 10 % quiet zone on each side
    }
    if (side <= 0) return;
    // Pinch zoom (possible despite user-scalable=no with Android's "force enable zoom") magnifies
    // the marker without changing devicePixelRatio: its size would be wrong, so say so.
    const zoom = window.visualViewport ? window.visualViewport.scale : 1;
    if (Math.abs(zoom - 1) > 0.01) {
      showError('The page is zoomed in (×' + zoom.toFixed(2) + '): pinch back out, or the marker size is wrong.', 'zoom');
    } else {
      clearError('zoom');
    }
    canvas.width = side;
    canvas.height = side;
    // Placed on whole device pixels (the marker area starts at the viewport's corner), so one
    // canvas pixel maps onto one device pixel with no resampling.
    canvas.style.width = side / dpr + 'px';
    canvas.style.height = side / dpr + 'px';
    canvas.style.left = Math.floor((areaW - side) / 2) / dpr + 'px';
    canvas.style.top = Math.floor((areaH - side) / 2) / dpr + 'px';
    const ctx = canvas.getContext('2d');
    ctx.fillStyle = '#fff';
    ctx.fillRect(0, 0, side, side);
    ctx.fillStyle = '#000';
    if (m.bits) {
      const cellPx = side / m.cells;
      for (let r = 0; r < m.cells; r++) {
        for (let k = 0; k < m.cells; k++) {
          if (m.bits[r][k]) ctx.fillRect(k * cellPx, r * cellPx, cellPx, cellPx);
        }
      }
    } else {
      ctx.imageSmoothingEnabled = false;
      ctx.drawImage(m.image, m.bbox.x, m.bbox.y, m.bbox.w, m.bbox.h, 0, 0, side, side);
    }
    const sizeM = side / state.ppi * M_PER_INCH;
    canvas.dataset.devicePx = String(side);
    canvas.dataset.cells = String(m.cells);
    canvas.dataset.sizeM = String(sizeM);
    $('marker-size').textContent =
      'marker: ' + (sizeM * 1000).toFixed(1) + ' mm (' + side + ' device px at ' + state.ppi +
      ' ppi, devicePixelRatio ' + dpr + ')';
    state.markerMsg = {
      type: 'marker',
      dictionary: state.config.marker.dictionary,
      id: state.config.marker.id,
      size_m: sizeM,
      ppi: state.ppi,
      device_pixel_ratio: dpr,
    };
    sendMarker(false);
  }

  function sendMarker(force) {
    if (!state.markerMsg) return;
    const text = JSON.stringify(state.markerMsg);
    if (!force && text === state.markerMsgSent) return;
    if (link.send(state.markerMsg)) state.markerMsgSent = text;
  }

  // ---------------------------------------------------------------- IMU (DeviceMotion)
  // Axes: DeviceMotionEvent uses the device frame x = right, y = up along the screen, z = out of
  // the screen (towards the user), right-handed; this is also Android's sensor frame, so values
  // pass through without sign changes.
  //   gyro  = [rotationRate.beta, rotationRate.gamma, rotationRate.alpha] * pi/180: beta is the
  //           rate about x, gamma about y, alpha about z, in deg/s by the spec -> rad/s.
  //   accel = accelerationIncludingGravity [x, y, z] in m/s^2, as an accelerometer reads it
  //           (specific force: about +9.81 on z when the phone lies face up on a table).
  //           Older iOS Safari versions report the opposite sign; this page does not correct it.
  function onDeviceMotion(ev) {
    const r = ev.rotationRate;
    const a = ev.accelerationIncludingGravity;
    if (!r || !a || r.alpha == null || r.beta == null || r.gamma == null ||
        a.x == null || a.y == null || a.z == null) {
      // Chrome fires one event with null fields when the device has no such sensor.
      state.counts.motionWithoutData += 1;
      return;
    }
    const sent = link.sendSample({
      type: 'imu',
      t: eventTimeMs(ev),
      gyro: [r.beta * DEG_TO_RAD, r.gamma * DEG_TO_RAD, r.alpha * DEG_TO_RAD],
      accel: [a.x, a.y, a.z],
    });
    if (sent) state.counts.imu += 1;
  }

  // ---------------------------------------------------------------- WebXR
  function checkWebXR() {
    return window.PhoneposeLink.checkWebXR('immersive-ar', {
      notAvailable: NOT_AVAILABLE,
      hint: ': use Chrome on an ARCore phone; streaming IMU only',
      available: 'WebXR immersive-ar is available: tap "Start AR" to stream the 6DoF pose',
    });
  }

  async function startAR() {
    // The DOM overlay keeps #app (marker and controls) on screen above the camera image during
    // the immersive-ar session: without it the phone would show only the camera image and the
    // webcam would lose the marker. 'anchors' lets the anchor button create an XR anchor too.
    // The base layer is cleared to transparent every frame (alpha), so the screen shows the camera
    // image under the DOM overlay (the marker).
    const init = { requiredFeatures: ['local'], optionalFeatures: ['dom-overlay', 'anchors'], domOverlay: { root: $('app') } };
    const started = await window.PhoneposeLink.startXRSession(state.xrSession, 'immersive-ar', init, { alpha: true }, 'AR', () => {
      state.xrSession = null;
      state.xrRefSpace = null;
      state.anchorRequested = false;
      state.anchors = [];
      $('btn-ar').textContent = 'Start AR';
      $('btn-anchor').disabled = true;
    });
    if (!started) return;
    const session = started.session;
    state.xrSession = session;
    state.xrGl = started.gl;
    if (!session.domOverlayState) {
      showError('This browser started AR without the DOM overlay: the marker is hidden during the AR session.', 'xr');
    }
    state.xrRefSpace = await session.requestReferenceSpace('local');
    $('btn-ar').textContent = 'Stop AR';
    $('btn-anchor').disabled = false;
    session.requestAnimationFrame(onXRFrame);
  }

  function onXRFrame(time, frame) {
    const session = frame.session;
    session.requestAnimationFrame(onXRFrame);
    const gl = state.xrGl;
    gl.bindFramebuffer(gl.FRAMEBUFFER, session.renderState.baseLayer.framebuffer);
    gl.clearColor(0, 0, 0, 0);
    gl.clear(gl.COLOR_BUFFER_BIT);
    const pose = frame.getViewerPose(state.xrRefSpace);
    if (!pose) return; // tracking lost: nothing to send (a pending anchor waits for tracking)
    const tr = pose.transform;
    const p = [tr.position.x, tr.position.y, tr.position.z];
    const q = [tr.orientation.x, tr.orientation.y, tr.orientation.z, tr.orientation.w];
    // `time` is the frame's DOMHighResTimeStamp, on the same clock as performance.now().
    const t = performance.timeOrigin + time;
    if (link.sendSample({ type: 'pose', t, p, q })) state.counts.pose += 1;
    if (state.anchorRequested) {
      state.anchorRequested = false;
      // The message carries the viewer pose of the first frame after the tap.
      link.send({ type: 'anchor', t, p, q });
      state.counts.anchor += 1;
      if (typeof frame.createAnchor === 'function') {
        frame.createAnchor(new XRRigidTransform(tr.position, tr.orientation), state.xrRefSpace)
          .then((a) => state.anchors.push(a))
          .catch(() => {});
      }
    }
  }

  // ---------------------------------------------------------------- screen, permissions, UI
  let wakeLock = null;

  async function requestWakeLock() {
    if (!('wakeLock' in navigator) || wakeLock !== null || document.visibilityState !== 'visible') return;
    try {
      wakeLock = await navigator.wakeLock.request('screen');
      wakeLock.addEventListener('release', () => {
        wakeLock = null;
      });
    } catch (e) {
      // refused (battery saver, no user gesture yet): retried on the next tap
    }
  }

  let firstTapDone = false;

  function onFirstTap() {
    requestWakeLock();
    if (firstTapDone) return;
    firstTapDone = true;
    // iOS 13+ delivers devicemotion only after this permission, which needs a user gesture.
    if (typeof DeviceMotionEvent !== 'undefined' && typeof DeviceMotionEvent.requestPermission === 'function') {
      DeviceMotionEvent.requestPermission()
        .then((answer) => {
          if (answer !== 'granted') showError('Motion sensor access was refused: no IMU samples will be sent.', 'imu');
        })
        .catch((e) => showError('Motion sensor permission failed: ' + e.message, 'imu'));
    }
  }

  function toggleFullscreen() {
    if (document.fullscreenElement) {
      document.exitFullscreen().catch(() => {});
    } else if (document.documentElement.requestFullscreen) {
      document.documentElement.requestFullscreen({ navigationUI: 'hide' }).catch(() => {});
    }
  }

  function setControlsHidden(hidden) {
    $('app').classList.toggle('hidden-controls', hidden);
    $('btn-show').hidden = !hidden;
  }

  function updateCounts() {
    const c = state.counts;
    $('counts').textContent = 'imu ' + c.imu + ' · pose ' + c.pose + ' · anchors ' + c.anchor +
      (link.dropped ? ' · dropped ' + link.dropped : '');
  }

  function wireUi() {
    document.addEventListener('click', onFirstTap, true);
    document.addEventListener('visibilitychange', () => {
      if (document.visibilityState === 'visible') requestWakeLock();
    });
    $('btn-ar').addEventListener('click', startAR);
    $('btn-anchor').addEventListener('click', () => {
      if (state.xrSession) state.anchorRequested = true;
    });
    $('btn-fullscreen').addEventListener('click', toggleFullscreen);
    $('btn-settings').addEventListener('click', () => {
      $('settings').hidden = !$('settings').hidden;
    });
    $('btn-hide').addEventListener('click', () => setControlsHidden(true));
    $('btn-show').addEventListener('click', () => setControlsHidden(false));
    $('ppi').addEventListener('change', onPpiInput);
    $('ppi').addEventListener('input', onPpiTyping);
    // Taps on the controls during the AR session are page input, not XR "select" events.
    $('controls').addEventListener('beforexrselect', (ev) => ev.preventDefault());
    window.addEventListener('resize', layoutMarker);
    if (window.visualViewport) window.visualViewport.addEventListener('resize', layoutMarker);
    if (typeof ResizeObserver === 'function') new ResizeObserver(layoutMarker).observe($('marker-area'));
    window.addEventListener('devicemotion', onDeviceMotion);
    setInterval(updateCounts, 250);
  }

  async function main() {
    wireUi();
    const [ppi, source] = initialPpi();
    setPpi(ppi, source);
    const xrCheck = checkWebXR();
    if (!token) {
      showError('This link has no ?token=…: open the URL or QR code printed by `phonepose record live`.', 'access');
    } else {
      try {
        state.config = await (await fetchChecked('/config')).json();
        state.marker = await loadMarker();
        layoutMarker();
      } catch (e) {
        if (e instanceof AccessDenied) {
          link.deny();
        } else {
          showError('Could not load the marker: ' + e.message, 'marker');
        }
      }
    }
    state.xr = await xrCheck;
    window.PhoneposeLink.finishStart(link, state.xr, 'btn-ar');
  }

  main();
})();
