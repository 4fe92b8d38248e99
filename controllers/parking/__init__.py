"""Parking: a trajectory planner (Hybrid A* + Reeds–Shepp search, CasADi/IPOPT optimisation), the TPCAP
benchmark entry point and an independent trajectory checker. Algorithm modules import no engine code."""
