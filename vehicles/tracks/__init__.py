"""What a vehicle knows of the others: Kalman tracks fed by delayed, lossy messages, and prediction.

``table`` (one filterpy filter per remote entity), ``stack`` (every receiver-source pair at once),
``pool`` (the merging controller's V2X tracks), ``predictor`` (sensed road vehicles along the road)
and ``agent`` (``TrackedAgent``: another aircraft as the ego's link and tracker see it).
"""
