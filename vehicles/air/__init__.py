"""Aircraft: the engine's air backend (``backend``), a fleet of JSBSim aircraft (``jsbsim_fleet``, the
only module that imports jsbsim), corridor's FCS systems added to JSBSim's models (``jsbsim_models``,
data in ``jsbsim_data/``) and corridor's autopilots (``autopilot``).
"""
