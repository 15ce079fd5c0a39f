"""What the guard, the local obstacle layer and the planner share about the vehicle's
surroundings: the scanners' mounts from ``/tf_static`` and the scenario's known terrain.

* :class:`StaticFrames` keeps every transform of ``/tf_static`` (robot_state_publisher's
  fixed joints: the lasers' mounts) and chains them to ``base_link``. A frame that is not
  on it has no mount: the guard stops for it, the layer drops its scans.
* :func:`site_frame`: the map frame's datum from ``/site`` (the launch files load it), which
  places georeferenced maps and DEMs (GeoTIFFs).
* :func:`scenario_terrain` builds the heights of a scenario's ``sim: terrain:`` (flat, procedural
  or a DEM, the same seed as the simulator's), or None without a scenario (the real vehicle
  without a survey): with it, the planner costs slopes and the guard and the layer take
  returns on it for the ground.
"""

from __future__ import annotations

from typing import Callable, Dict, Optional, Tuple

import numpy as np
import rospy

from quadrivio_config import ConfigError, replace_nested
from quadrivio_description.frames import matrix_from_quaternion
from quadrivio_runtime.ros.params import fatal, run_seed

Mount = Tuple[np.ndarray, np.ndarray]  # translation (3,), rotation 3 x 3 of a frame in the base frame


class StaticFrames:
    def __init__(self, base_frame: str = "base_link") -> None:
        from tf2_msgs.msg import TFMessage

        self.base = base_frame
        self.static: Dict[str, object] = {}  # child frame -> geometry_msgs/TransformStamped
        self.mounts: Dict[str, Mount] = {}
        rospy.Subscriber("/tf_static", TFMessage, self._on_tf_static, queue_size=10)

    def _on_tf_static(self, m) -> None:
        for t in m.transforms:
            self.static[t.child_frame_id] = t
        self.mounts = {}

    def mount(self, frame: str) -> Optional[Mount]:
        """``frame`` in the base frame, chained through ``/tf_static``; None if it is not on it."""
        if frame in self.mounts:
            return self.mounts[frame]
        R, t, f = np.eye(3), np.zeros(3), frame
        for _ in range(32):
            if f == self.base:
                self.mounts[frame] = (t, R)
                return t, R
            tr = self.static.get(f)
            if tr is None:
                return None
            q, p = tr.transform.rotation, tr.transform.translation
            Rp = np.array(matrix_from_quaternion(q.x, q.y, q.z, q.w))
            R, t = Rp @ R, Rp @ t + np.array([p.x, p.y, p.z])
            f = tr.header.frame_id
        return None


def site_frame():
    """The site's :class:`~quadrivio_description.geodesy.LocalFrame` from ``/site``
    (``config/site.yaml``'s when the parameter is not set)."""
    from quadrivio_config import from_mapping
    from quadrivio_description.site import SiteParams, load_site

    if rospy.has_param("/site"):
        try:
            return from_mapping(SiteParams, rospy.get_param("/site"), "/site").local_frame()
        except ConfigError as exc:
            fatal(f"bad /site: {exc}")
    return load_site().local_frame()


def scenario_terrain(who: str, enabled: bool = True) -> Optional[Callable[[np.ndarray, np.ndarray], np.ndarray]]:
    """The scenario's terrain heights ``z(x, y)`` [m] (map frame), or None without one."""
    hf = scenario_heightfield(who, enabled)
    return None if hf is None else hf.heights


def scenario_heightfield(who: str, enabled: bool = True):
    """The scenario's :class:`quadrivio_terrain.terrain.Heightfield` (map frame), or None without one."""
    key = "/scenario/sim/terrain"
    if not (enabled and rospy.has_param(key)):
        return None
    from quadrivio_terrain.terrain import TerrainParams, known_heightfield

    try:
        tp = replace_nested(TerrainParams(), rospy.get_param(key), key)
        if tp.image:  # relative to the scenario's folder, as the simulator reads it
            from dataclasses import replace

            from ..maps import resolve_map_file

            tp = replace(tp, image=resolve_map_file(tp.image, rospy.get_param("/scenario/source", "")))
        hf = known_heightfield(tp, np.random.default_rng(run_seed()), site_frame() if tp.kind == "geotiff" else None)
    except ConfigError as exc:
        fatal(f"bad scenario terrain: {exc}")
    if hf is None:
        return None
    rospy.loginfo("%s: the scenario's %s terrain is known (a DEM)", who, tp.kind)
    return hf
