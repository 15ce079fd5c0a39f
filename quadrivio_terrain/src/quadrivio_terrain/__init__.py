"""The ground the vehicle drives on, shared by the simulator and the planner: flat, a DEM
image, a surveyed DEM GeoTIFF or procedural rough ground (:mod:`.terrain`), and surveyed
rasters resampled into the site's local frame (:mod:`.georaster`). ROS-free."""
