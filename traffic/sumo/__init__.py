"""SUMO: the libsumo backend (``backend``, the only module that imports libsumo), the road as data
(``road_spec``), route files (``demand``), the commands controllers hand the backend (``commands``:
speed / lane change, ``meters``: ramp meters and route guidance) and trip bookkeeping (``trips``:
the ``trips`` monitor and ``road_frame``).
"""
