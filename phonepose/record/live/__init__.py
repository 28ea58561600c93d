"""``phonepose record live``: a webcam is the display camera, a phone's browser page the controller.

``camera`` (OpenCV VideoCapture: device or video file), ``clock`` (recorder clock, NTP-style page
clock offset), ``tls`` (the self-signed certificate), ``server`` (aiohttp HTTPS + WebSocket, the
protocol), ``session`` (:class:`LiveSession`: everything tied to the Recorder). The phone page
itself is in ``static/``. Guide: docs/recording-real-sessions.md.
"""

from phonepose.record.live.session import LiveResult, LiveSession

__all__ = ["LiveResult", "LiveSession"]
