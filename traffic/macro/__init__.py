"""Macroscopic traffic: the METANET model and what the traffic centre knows per segment.

``metanet`` (the model, numpy and CasADi), ``metanet_networks`` (the Hegyi freeway, the beltway
ring), ``metanet_backend`` (METANET as a scenario backend), ``calibrate`` (the fundamental-diagram fit
from SUMO loops), ``loop_state`` (loop readings -> METANET state, calibration and station-map
files), ``station_map`` (station scale <-> segment mean), ``fusion`` + ``fusion_component`` (the
per-segment Kalman filter of loops and UAV cameras) and ``segment_truth`` (SUMO's ground truth as a
``segment_estimate`` provider).
"""
