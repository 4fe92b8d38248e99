"""corridor.vehicles: what rides on the road and flies above it (imports the kernel and traffic).

``air/`` JSBSim aircraft and corridor's autopilots; ``mavlink/`` the MAVLink 2 dialect, link and the
engine's air link; ``tracks/`` Kalman tracks of other vehicles and prediction; ``sensors/`` cameras and
range sensors; ``ground/`` the bicycle model, the ego car in SUMO and highway-env's parking lot;
``geodesy`` ENU <-> geodetic conversions.
"""
