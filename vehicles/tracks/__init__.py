"""What a vehicle knows of the others: Kalman tracks fed by delayed, lossy messages, and prediction.

``agent`` (``TrackedAgent``: another aircraft as the ego's link and tracker see it).
"""
