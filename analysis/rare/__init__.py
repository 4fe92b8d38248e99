"""Rare-event statistics over a scenario's randomized inputs (the runs are the batch runner's).

Every method is an *ask/tell* object in the standard-normal space of the inputs
(``corridor.distributions``): ``ask()`` gives the next stage's points (rows of ``z``; None when done),
``tell(level, fail)`` takes the runs' level values (smaller is closer to failure) and failure flags in
the same order, ``result()`` gives a JSON-able summary.  Stage ``k``'s points depend only on the seed,
``k`` and the values told before, so a resumed estimate asks for the same runs again.

- ``ce``: cross-entropy adaptive importance sampling (``ce.py``);
- ``splitting``: subset simulation with preconditioned Crank-Nicolson moves (``splitting.py``);
- ``falsify``: minimisation of the level (CMA-ES, ``falsify.py``).
"""
