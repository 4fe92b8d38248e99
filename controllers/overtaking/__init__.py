"""STL-constrained overtaking: the hybrid controller with its modes (``controller``), the CasADi MPC
(``mpc``), a standalone world for tests and benchmarks (``sim``); the engine component (``components``)."""
