"""Parking: the manoeuvre automaton and path following (``manoeuvre``, ``tracking``), spot detection
(``spot_detection``), clearance geometry (``clearance``); the engine component (``components``)."""
