"""Fixtures for tests, benchmarks and the docs' examples: never imported by production code.

* :mod:`phonepose.testing.sample`: a tiny session with one message of every type.
* :mod:`phonepose.testing.playback_session`: a small hand-made session to play back
  (``write_test_session``: a display looking at the controller's marker, VIO with a known anchor
  error, exact ground truth; every stream optional). Handy to try a tracker of your own on
  (docs/writing-a-tracker.md).
* :mod:`phonepose.testing.marker_images`: a small supersampled renderer of one marker seen by a
  pinhole camera, with exactly known corners and poses.

tests/test_imports.py checks that no module outside this package imports it.
"""
