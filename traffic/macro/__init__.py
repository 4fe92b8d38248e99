"""Macroscopic traffic: the METANET model and what the traffic centre knows per segment.

``loop_state`` (loop-station readings -> METANET state: space-mean speed, the direct mapping, the
calibration and station-map files).
"""
