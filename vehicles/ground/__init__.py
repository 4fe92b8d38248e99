"""Ground vehicles: the kinematic bicycle model (``bicycle``, shared by simulator, MPC and
predictor), the ego car integrated by corridor inside SUMO (``ego_bicycle``) and highway-env's
parking lot as a backend (``highway_env_parking``).
"""
