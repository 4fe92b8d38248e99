"""Sensors: a UAV's downward camera counting road vehicles (``camera``, pure numpy) and as an engine
component (``camera_sensor``), and a car's side-looking range sensors (``range_sensors``).
"""
