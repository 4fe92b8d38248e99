"""Ramp metering: ALINEA (``alinea``), the METANET MPC with route guidance (``mpc``), the Hegyi benchmark
(``hegyi``); engine components for SUMO (``components``) and for the pure METANET model
(``metanet_components``)."""
