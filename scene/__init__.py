"""The scene: a plan's geometry with the frames observed in it, where the planner and the estimator meet.

``planner`` knows orbits, stations and frames of reference; ``inference`` knows ISAR frames and
attitudes in a frame's own observation axes. A scene needs both: the target's trajectory over a
span seen from the radar places each frame's observation axes in the target's orbital frame
(LVLH) and in J2000, simulates the frames a pass would give, and fuses a pass's answers into one
attitude. This package imports ``planner`` and ``inference`` and never the app or a web or
database library (``tests/test_layout.py``); the service and the command line call it.

- ``scene.geometry``: ``Scene``, built once from the target's orbit, the station, the reading
  and a span; ``Placements`` of observation times as typed arrays; ``Window`` and ``choose_window``.
- ``scene.simulation``: ``PassOptions`` and the frames of a simulated pass.
- ``scene.reading``: frames through the networks, the fit and the checks.
- ``scene.fusion``: a pass's frames fused into one attitude in LVLH (``FusedPass``).
- ``scene.errors``: ``SceneError``, which names the field to fix.
"""

from scene.errors import SceneError
from scene.geometry import Placements, Scene, Window, choose_window

__all__ = ["Placements", "Scene", "SceneError", "Window", "choose_window"]
