"""Parking: a trajectory planner (Hybrid A* + Reeds–Shepp search, CasADi/IPOPT optimisation), the TPCAP
benchmark entry point and an independent trajectory checker; the manoeuvre automaton and path following
(``manoeuvre``, ``tracking``), spot detection (``spot_detection``), clearance geometry (``clearance``)
and the engine component (``components``). Algorithm modules import no engine code."""
