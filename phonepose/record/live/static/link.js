// phonepose pages' link to `phonepose record live`, shared by the phone page (phone.js) and the
// headset page (headset.js): the token, the page clock, the error line, and the WebSocket with its
// reconnect rule and the ping/pong clock-offset protocol (docs/phone-page.md). Plain JavaScript,
// loaded before the page's own script; it defines window.PhoneposeLink and nothing else.
'use strict';

(function () {
  // Above this many bytes waiting in the socket, samples are dropped rather than queued
  // (a stalled Wi-Fi link must not grow the page's memory without bound).
  const MAX_BUFFERED = 1 << 20;

  const params = new URLSearchParams(location.search);
  const token = params.get('token') || '';
  const $ = (id) => document.getElementById(id);

  // ---------------------------------------------------------------- messages on the page
  // One error line (#error); each message has a source, so clearing one source leaves another's.
  let errorSource = null;

  function showError(message, source) {
    const el = $('error');
    el.textContent = message;
    el.hidden = false;
    errorSource = source || 'page';
  }

  function clearError(source) {
    if (errorSource === source) {
      $('error').hidden = true;
      $('error').textContent = '';
      errorSource = null;
    }
  }

  // ---------------------------------------------------------------- time
  // Every `t` sent is in ms on the page's clock: performance.timeOrigin + a DOMHighResTimeStamp
  // (performance.now(), an event's timeStamp or an XR frame's time, which share that clock).
  function nowMs() {
    return performance.timeOrigin + performance.now();
  }

  // ---------------------------------------------------------------- HTTP
  class AccessDenied extends Error {}

  async function fetchChecked(path) {
    const r = await fetch(path + '?token=' + encodeURIComponent(token), { cache: 'no-store' });
    if (r.status === 403) throw new AccessDenied(path);
    if (!r.ok) throw new Error(path + ' answered HTTP ' + r.status);
    return r;
  }

  // The integer fields of a ping are echoed from the raw text, not through a JS number: a
  // nanosecond clock such as time.time_ns() (~1.7e18) is larger than 2^53 and would lose digits.
  function rawInt(text, key) {
    const m = new RegExp('"' + key + '"\\s*:\\s*(-?\\d+)').exec(text);
    return m ? m[1] : null;
  }

  // ---------------------------------------------------------------- WebXR availability
  // Whether this browser offers a WebXR session of `mode` ('immersive-ar' on the phone,
  // 'immersive-vr' on the headset): {ok, message}. Every "no" message starts with
  // `texts.notAvailable` and ends with `texts.hint`; `texts.available` is the "yes" message.
  async function checkWebXR(mode, texts) {
    const { notAvailable, hint, available } = texts;
    if (!window.isSecureContext) {
      return { ok: false, message: notAvailable + ' (the page is not a secure context: open it over https://)' + hint };
    }
    if (!navigator.xr) return { ok: false, message: notAvailable + hint };
    try {
      const supported = await Promise.race([
        navigator.xr.isSessionSupported(mode),
        new Promise((resolve) => setTimeout(() => resolve(false), 5000)),
      ]);
      if (supported) return { ok: true, message: available };
      return { ok: false, message: notAvailable + hint };
    } catch (e) {
      return { ok: false, message: notAvailable + ' (' + e.message + ')' + hint };
    }
  }
  // ---------------------------------------------------------------- WebXR session start
  // Start a WebXR session of `mode` with `init` (its required/optional features), or end the one
  // running (`running`, the page's current session or null; the button toggles). On success the
  // session has a WebGL base layer (frames run only with one; `glOptions` for the context) and
  // `onEnd` is called when it ends: resolves to {session, gl}, or null if it ended one or failed
  // (then the error line says why, as `label`: "AR", "VR").
  async function startXRSession(running, mode, init, glOptions, label, onEnd) {
    if (running) {
      await running.end();
      return null;
    }
    let session;
    try {
      session = await navigator.xr.requestSession(mode, init);
    } catch (e) {
      showError('Could not start the ' + label + ' session: ' + e.message, 'xr');
      return null;
    }
    clearError('xr');
    session.addEventListener('end', onEnd);
    const gl = document.createElement('canvas').getContext('webgl', Object.assign({ xrCompatible: true }, glOptions));
    session.updateRenderState({ baseLayer: new XRWebGLLayer(session, gl) });
    return { session, gl };
  }


  // The end of a page's start: the WebXR check's message on the page (#xr-message), the XR button
  // enabled only with WebXR, then the connection (unless the token was refused).
  function finishStart(link, xr, buttonId) {
    const msg = $('xr-message');
    msg.textContent = xr.message;
    msg.hidden = false;
    msg.className = xr.ok ? 'status' : 'warning';
    document.body.dataset.webxr = String(xr.ok);
    $(buttonId).disabled = !xr.ok;
    if (token && !link.accessDenied) link.connect();
    document.body.dataset.ready = 'true';
  }

  // ---------------------------------------------------------------- the WebSocket
  // options: role ('phone' | 'headset'), hello() -> the hello message, onOpen(), onMessage(msg)
  // for server messages other than ping, setConn(text), onDenied().
  class Link {
    constructor(options) {
      this.options = options;
      this.ws = null;
      this.reconnectDelay = 500;
      this.accessDenied = false;
      this.dropped = 0;
    }

    get open() {
      return this.ws !== null && this.ws.readyState === WebSocket.OPEN;
    }

    send(obj) {
      if (!this.open) return false;
      this.ws.send(JSON.stringify(obj));
      return true;
    }

    // Streams (pose, imu, xrframe) are dropped, not queued, when the link is congested.
    sendSample(obj) {
      if (!this.open || this.ws.bufferedAmount > MAX_BUFFERED) {
        this.dropped += 1;
        return false;
      }
      this.ws.send(JSON.stringify(obj));
      return true;
    }

    url() {
      const scheme = location.protocol === 'https:' ? 'wss://' : 'ws://';
      const role = this.options.role === 'phone' ? '' : '&role=' + encodeURIComponent(this.options.role);
      return scheme + location.host + '/ws?token=' + encodeURIComponent(token) + role;
    }

    deny() {
      this.accessDenied = true;
      showError('Access denied (HTTP 403): this link\'s token is wrong or out of date. Open the URL or QR code that `phonepose record live` prints now.', 'access');
      this.options.setConn('not connected');
      if (this.options.onDenied) this.options.onDenied();
    }

    connect() {
      if (this.accessDenied) return;
      const o = this.options;
      o.setConn('connecting…');
      let ws;
      try {
        ws = new WebSocket(this.url());
      } catch (e) {
        showError('Cannot open the WebSocket: ' + e.message, 'ws');
        return;
      }
      this.ws = ws;
      ws.onopen = () => {
        this.reconnectDelay = 500;
        o.setConn('connected');
        clearError('ws');
        this.send(o.hello());
        if (o.onOpen) o.onOpen();
      };
      ws.onmessage = (ev) => this.onServerMessage(ev.data);
      ws.onclose = (ev) => {
        if (this.ws !== ws) return;
        this.ws = null;
        if (ev.code === 1000) {
          // A normal close comes from the server on purpose: the recording finished, or another
          // page connected and replaced this one. Reconnecting would take the session back from it.
          o.setConn('closed by the laptop');
          showError('The laptop closed this connection' + (ev.reason ? ' (' + ev.reason + ')' : '') +
            ': the recording finished or another page took over. Reload this page to connect again.', 'ws');
          return;
        }
        const delay = this.reconnectDelay;
        this.reconnectDelay = Math.min(delay * 2, 8000);
        o.setConn('disconnected, retrying in ' + (delay / 1000).toFixed(1) + ' s');
        showError('Lost the connection to the laptop (is `phonepose record live` still running, and this device on the same network?); reconnecting…', 'ws');
        setTimeout(() => this.reconnect(), delay);
      };
    }

    // Before reconnecting, a refused token (a new recording has a new token) ends the attempts.
    async reconnect() {
      try {
        await fetchChecked('/config');
      } catch (e) {
        if (e instanceof AccessDenied) {
          this.deny();
          return;
        }
        // laptop unreachable: the WebSocket attempt below fails too and schedules the next one
      }
      this.connect();
    }

    onServerMessage(text) {
      let msg;
      try {
        msg = JSON.parse(text);
      } catch (e) {
        return;
      }
      if (!msg || typeof msg !== 'object') return;
      if (msg.type === 'ping') {
        const id = rawInt(text, 'id');
        const ns = rawInt(text, 'server_ns');
        if (id === null || ns === null || !this.open) return;
        this.ws.send('{"type":"pong","id":' + id + ',"server_ns":' + ns + ',"t":' + nowMs() + '}');
      } else if (msg.type === 'error') {
        showError(String(msg.message), 'server');
      } else {
        this.options.onMessage(msg);
      }
    }
  }

  window.PhoneposeLink = {
    token, params, $, showError, clearError, nowMs, AccessDenied, fetchChecked, checkWebXR, startXRSession, finishStart, Link,
  };
})();
