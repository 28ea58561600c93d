"""What a person sees of a session, in Rerun and in Foxglove.

- :mod:`~phonepose.viewer.style`: one colour per tracker (and for the ground truth and the task),
  used on every entity and plot, readable on the viewers' light and dark themes.
- :mod:`~phonepose.viewer.entities`: the one Rerun entity tree that the recorder's and the
  playback's Rerun output share (``/world`` is display_vio in both).
- :mod:`~phonepose.viewer.sink`: the one Rerun sink set-up (file or spawned viewer, recording id
  and name, no wall-clock timeline) and the column buffer every stage logger sends rows through.
- :mod:`~phonepose.viewer.frames`: the Foxglove ``FrameTransform`` tree written into every
  session, so that Rerun's and Foxglove's MCAP readers place the camera, the display and the
  phone in 3D without phonepose.
- :mod:`~phonepose.viewer.annotations`: marker detections as ``foxglove.ImageAnnotations``.

The Rerun loggers themselves live beside the stage they show: ``phonepose.record.rerun_log``
(what is recorded) and ``phonepose.playback.rerun_log`` (what the trackers did).
"""
