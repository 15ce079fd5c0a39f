"""map_server: a map_server-format map (YAML + PGM/PNG) on ``map``, latched.

Debian has no map_server package; this node reads the same files (see
:mod:`quadrivio_navigation.maps`) and offers the same interface.

Parameters (private, ``config/map_server.yaml``; a scenario's ``map:`` section
overrides): ``~file`` (str, the map's YAML; relative to the scenario file's folder when
it comes from a scenario; empty: no map, the node waits idle), ``~frame_id`` (str,
"map"). The simulator reads the same ``map:`` section to build the obstacles.

Publishes: ``map`` (nav_msgs/OccupancyGrid, latched), ``map_metadata``
(nav_msgs/MapMetaData, latched). Services: ``static_map`` (nav_msgs/GetMap).
A missing or malformed map stops the node at start-up with a message naming the file
and the problem.
"""

from __future__ import annotations

import time

import numpy as np
import rospy
from nav_msgs.msg import MapMetaData, OccupancyGrid
from nav_msgs.srv import GetMap, GetMapResponse

from quadrivio_runtime.ros import init_node
from quadrivio_runtime.ros.params import fatal, node_params, with_scenario

from ..maps import MapError, MapParams, OccupancyGrid as Grid, load_map, resolve_map_file
from .site_inputs import site_frame
from .conversions import pose_stamped


def grid_msg(grid: Grid, frame_id: str, stamp: rospy.Time) -> OccupancyGrid:
    msg = OccupancyGrid()
    msg.header.stamp, msg.header.frame_id = stamp, frame_id
    info = msg.info
    info.map_load_time = stamp
    info.resolution = float(grid.resolution)
    info.width, info.height = grid.width, grid.height
    info.origin = pose_stamped(*grid.origin, frame_id, stamp).pose
    msg.data = np.ascontiguousarray(grid.data, dtype=np.int8).ravel().tolist()
    return msg


def map_file_param(p: MapParams) -> str:
    """The map file, resolved against the scenario's folder (``/scenario/source``)."""
    return resolve_map_file(p.file, rospy.get_param("/scenario/source", ""))


class MapServer:
    def __init__(self) -> None:
        self.p: MapParams = with_scenario(node_params(MapParams), "map")
        path = map_file_param(self.p)
        if not path:
            rospy.loginfo("map_server: no map file (~file, or the scenario's map: section): nothing to publish")
            return
        t = time.monotonic()
        try:
            grid = load_map(path, site_frame())
        except MapError as exc:
            fatal(f"cannot load the map: {exc}")
        rospy.loginfo("%s", grid.summary)
        for warning in grid.warnings:
            rospy.logwarn("%s", warning)
        stamp = rospy.Time.now()
        self.msg = grid_msg(grid, self.p.frame_id, stamp)
        self.pub = rospy.Publisher("map", OccupancyGrid, queue_size=1, latch=True)
        self.pub_meta = rospy.Publisher("map_metadata", MapMetaData, queue_size=1, latch=True)
        self.pub_meta.publish(self.msg.info)
        self.pub.publish(self.msg)
        rospy.Service("static_map", GetMap, lambda _req: GetMapResponse(self.msg))
        occ = float(np.mean(grid.data >= 65))
        unknown = float(np.mean(grid.data < 0))
        rospy.loginfo("map_server: %s, %d x %d cells of %.3f m (%.0f m x %.0f m), %.1f %% occupied, %.1f %% unknown, "
                      "loaded in %.2f s", path, grid.width, grid.height, grid.resolution, *grid.size, 100 * occ,
                      100 * unknown, time.monotonic() - t)


def main() -> None:
    init_node("map_server")  # joins lockstep when sim.launch lockstep:=true
    MapServer()
    rospy.spin()
