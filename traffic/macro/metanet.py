"""METANET second-order macroscopic freeway model, written once for numpy floats and CasADi symbols.

The model follows Messmer & Papageorgiou (1990) in the discrete form of Hegyi (2004, PhD thesis,
ch. 3) and Hegyi, De Schutter & Hellendoorn (2005, Transp. Res. C 13(3)):

    q_i     = rho_i v_i lanes_i                                                  [veh/h]
    rho_i+  = rho_i + T/(L_i lanes_i) (q_in_i - q_i)                             [veh/km/lane]
    v_i+    = v_i + T/tau (V(rho_i) - v_i)                       relaxation       [km/h]
                  + T/L_i v_i (v_up - v_i)                       convection
                  - nu T/(tau L_i) (rho_down - rho_i)/(rho_i + kappa)  anticipation
                  - delta T q_o v_i / (L_i lanes_i (rho_i + kappa))    on-ramp merge
                  - phi T dlanes rho_i v_i^2 / (L_i lanes_i rho_crit)  lane drop
    V(rho)  = v_free exp(-(1/a) (rho/rho_crit)^a)
    q_o     = min(d + w/T, r C, C (rho_max - rho_i)/(rho_max - rho_crit))  origin outflow
    w+      = w + T (d - q_o)                                                    [veh]

The network is a flat list of segments with an upstream and downstream neighbour each (-1 marks a
boundary), so a freeway stretch and a two-direction ring are the same data. Off-ramps are static
turning fractions at a segment's downstream end. Origins (mainstream entries and on-ramps) feed a
segment; an origin's demand is a disturbance, optionally multiplied by a route-guidance split
(share ``s`` of a demand source takes one loop, ``1 - s`` the other), see ``MetanetNetwork``.

Vectors (all flat, column-shaped for CasADi):
    x = [rho (n_seg), v (n_seg), w (n_orig)]
    u = [r (n_metered, fraction 0..1 of ramp capacity), s (n_split, share on the "a" origin)]
    d = [demand (n_sources) [veh/h], rho_dest (n_dest) [veh/km/lane] downstream boundary densities]
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import casadi as ca
import numpy as np

_CASADI_TYPES = (ca.SX, ca.MX, ca.DM)


def _is_sym(*xs: Any) -> bool:
    """True when any argument is a CasADi matrix (then CasADi operators must be used)."""
    return any(isinstance(x, _CASADI_TYPES) for x in xs)


def fmin(a: Any, b: Any) -> Any:
    """Minimum that dispatches to CasADi for symbols and to numpy for numbers."""
    return ca.fmin(a, b) if _is_sym(a, b) else np.minimum(a, b)


def fmax(a: Any, b: Any) -> Any:
    """Maximum that dispatches to CasADi for symbols and to numpy for numbers."""
    return ca.fmax(a, b) if _is_sym(a, b) else np.maximum(a, b)


def sqrt(a: Any) -> Any:
    """Square root that dispatches to CasADi for symbols and to numpy for numbers."""
    return ca.sqrt(a) if _is_sym(a) else np.sqrt(a)


def smooth_min(a: Any, b: Any, eps: float) -> Any:
    """min(a, b) for eps == 0, else the smooth (a + b - sqrt((a - b)^2 + eps^2)) / 2 (error <= eps/2).

    The smooth form is what the MPC's prediction model uses: IPOPT stalls on the exact kinks.
    """
    if eps <= 0.0:
        return fmin(a, b)
    return 0.5 * (a + b - sqrt((a - b) ** 2 + eps**2))


def smooth_max(a: Any, b: Any, eps: float) -> Any:
    """max(a, b) for eps == 0, else its smooth counterpart (see ``smooth_min``)."""
    return -smooth_min(-a, -b, eps)


def exp(a: Any) -> Any:
    """Exponential that dispatches to CasADi for symbols and to numpy for numbers."""
    return ca.exp(a) if _is_sym(a) else np.exp(a)


def vcat(items: list[Any]) -> Any:
    """Stack scalars into a column: a CasADi column when any item is symbolic, else a 1-D array."""
    if _is_sym(*items):
        return ca.vertcat(*items)
    return np.array([float(i) for i in items], dtype=float)


@dataclass(frozen=True)
class MetanetParams:
    """Network-wide METANET parameters (defaults: Hegyi et al. 2005 benchmark values)."""

    step_h: float = 10.0 / 3600.0  # model step T [h]
    tau_h: float = 18.0 / 3600.0  # relaxation time tau [h]
    nu_km2ph: float = 60.0  # anticipation constant nu (often eta) [km^2/h]
    kappa: float = 40.0  # anticipation/merge regulariser [veh/km/lane]
    delta: float = 0.0122  # on-ramp merge coefficient [-]
    phi: float = 2.98  # lane-drop coefficient [-] (Hegyi 2004; from memory, unused without drops)
    smooth_vph: float = 0.0  # >0: smooth min/max of width [veh/h] in origin flows (MPC prediction only)
    smooth_rho: float = 0.0  # >0: smooth min/max of width [veh/km/lane] at destinations (MPC only)
    # >0: the equilibrium speed takes the smooth positive part of the density, width [veh/km/lane]
    # (MPC only): the NLP's state iterates may hold negative densities, where (rho / rho_crit)^a is NaN
    smooth_pos_rho: float = 0.0


@dataclass(frozen=True, eq=False)
class MetanetNetwork:
    """Flat segment/origin description of a METANET network (see module docstring for vectors).

    Per segment (length n_seg): ``length_km``, ``lanes``, fundamental diagram (``v_free_kmh``,
    ``rho_crit``, ``a``, ``rho_max``), ``up``/``down`` neighbour indices (-1 = boundary: upstream
    boundary takes its speed from the segment itself, downstream boundary is a destination whose
    density is ``max(min(rho_i, rho_crit_i), rho_dest)``), ``exit_frac`` (share of the segment's
    outflow that leaves by an off-ramp at its downstream end).
    Per origin (length n_orig): ``orig_seg`` (segment fed), ``orig_cap_vph``, ``orig_metered``,
    ``orig_onramp`` (merge term applies; False for a mainstream entry), ``orig_source`` (index of
    its demand in d), ``orig_split`` (index of its route-guidance split or -1), ``orig_split_a``
    (True: demand x s, False: demand x (1 - s)), ``orig_storage_veh`` (queue storage, inf if none).
    Splits (length n_split): ``split_default`` (no-guidance share), ``split_lo``/``split_hi``.
    """

    name: str
    length_km: np.ndarray
    lanes: np.ndarray
    v_free_kmh: np.ndarray
    rho_crit: np.ndarray
    a: np.ndarray
    rho_max: np.ndarray
    up: np.ndarray
    down: np.ndarray
    exit_frac: np.ndarray
    orig_seg: np.ndarray
    orig_cap_vph: np.ndarray
    orig_metered: np.ndarray
    orig_onramp: np.ndarray
    orig_source: np.ndarray
    orig_split: np.ndarray
    orig_split_a: np.ndarray
    orig_storage_veh: np.ndarray
    n_sources: int
    split_default: np.ndarray = field(default_factory=lambda: np.zeros(0))
    split_lo: np.ndarray = field(default_factory=lambda: np.zeros(0))
    split_hi: np.ndarray = field(default_factory=lambda: np.zeros(0))
    params: MetanetParams = field(default_factory=MetanetParams)
    seg_labels: tuple[str, ...] = ()
    orig_labels: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        """Check sizes, indices and the CFL condition v_free T <= L (else the scheme is unstable)."""
        n, no = self.n_seg, self.n_orig
        for name in ("lanes", "v_free_kmh", "rho_crit", "a", "rho_max", "up", "down", "exit_frac"):
            if len(getattr(self, name)) != n:
                raise ValueError(f"{self.name}: {name} has length {len(getattr(self, name))}, expected {n}")
        for name in ("orig_cap_vph", "orig_metered", "orig_onramp", "orig_source", "orig_split",
                     "orig_split_a", "orig_storage_veh"):
            if len(getattr(self, name)) != no:
                raise ValueError(f"{self.name}: {name} has length {len(getattr(self, name))}, expected {no}")
        cfl = self.v_free_kmh * self.params.step_h / self.length_km
        if np.any(cfl > 1.0):
            raise ValueError(f"{self.name}: CFL violated (v_free*T/L up to {cfl.max():.2f} > 1)")
        if np.any((self.orig_split >= 0) & (self.orig_split >= self.n_split)):
            raise ValueError(f"{self.name}: orig_split index out of range")

    @property
    def n_seg(self) -> int:
        return len(self.length_km)

    @property
    def n_orig(self) -> int:
        return len(self.orig_seg)

    @property
    def n_split(self) -> int:
        return len(self.split_default)

    @cached_property
    def metered_idx(self) -> np.ndarray:
        """Indices of metered origins, in the order of the meter rates in u."""
        return np.flatnonzero(self.orig_metered)

    @property
    def n_metered(self) -> int:
        return len(self.metered_idx)

    @cached_property
    def dest_idx(self) -> np.ndarray:
        """Indices of segments that end in a destination, in the order of rho_dest in d."""
        return np.flatnonzero(self.down < 0)

    @property
    def nx(self) -> int:
        return 2 * self.n_seg + self.n_orig

    @property
    def nu(self) -> int:
        return self.n_metered + self.n_split

    @property
    def nd(self) -> int:
        return self.n_sources + len(self.dest_idx)

    def lane_km(self) -> np.ndarray:
        """Lane-kilometres of each segment [lane km]: density x this = vehicles."""
        return self.length_km * self.lanes

    def default_u(self) -> np.ndarray:
        """Inputs meaning 'no control': meters fully open, route splits at their default share."""
        return np.concatenate([np.ones(self.n_metered), self.split_default])

    def split_x(self, x: Any) -> tuple[Any, Any, Any]:
        """Return (rho, v, w) views of a state vector."""
        n = self.n_seg
        return x[0:n], x[n:2 * n], x[2 * n:2 * n + self.n_orig]

    @cached_property
    def function(self) -> ca.Function:
        """The step as a compiled CasADi Function F(x, u, d) -> (x_next, q_seg, q_orig)."""
        x, u, d = ca.SX.sym("x", self.nx), ca.SX.sym("u", self.nu), ca.SX.sym("d", self.nd)
        x_next, q_seg, q_orig = step_with_flows(x, u, d, self)
        return ca.Function("metanet", [x, u, d], [x_next, q_seg, q_orig],
                           ["x", "u", "d"], ["x_next", "q_seg", "q_orig"])


def equilibrium_speed(rho: Any, v_free_kmh: Any, rho_crit: Any, a: Any) -> Any:
    """V(rho) = v_free exp(-(1/a)(rho/rho_crit)^a) [km/h]; rho in [veh/km/lane]."""
    return v_free_kmh * exp(-(1.0 / a) * (rho / rho_crit) ** a)


def origin_flow(demand_vph: Any, queue_veh: Any, rate: Any, cap_vph: float, rho_seg: Any,
                rho_max: float, rho_crit: float, step_h: float, smooth_vph: float = 0.0) -> Any:
    """Origin outflow [veh/h]: min(demand + queue/T, rate C, C (rho_max - rho)/(rho_max - rho_crit))."""
    supply = cap_vph * (rho_max - rho_seg) / (rho_max - rho_crit)
    return smooth_min(smooth_min(demand_vph + queue_veh / step_h, rate * cap_vph, smooth_vph), supply, smooth_vph)


def _origin_demands(u: Any, d: Any, net: MetanetNetwork) -> list[Any]:
    """Demand of each origin [veh/h]: its source's demand times the route split share if any."""
    out = []
    for j in range(net.n_orig):
        dem = d[int(net.orig_source[j])]
        g = int(net.orig_split[j])
        if g >= 0:
            s = u[net.n_metered + g]
            dem = dem * s if net.orig_split_a[j] else dem * (1.0 - s)
        out.append(dem)
    return out


def _origin_flows(x: Any, u: Any, d: Any, net: MetanetNetwork) -> tuple[list[Any], list[Any]]:
    """(demands, outflows) of all origins [veh/h]; unmetered origins use rate 1."""
    rho, _, w = net.split_x(x)
    meter_pos = {int(j): k for k, j in enumerate(net.metered_idx)}
    demands = _origin_demands(u, d, net)
    flows = []
    for j in range(net.n_orig):
        i = int(net.orig_seg[j])
        rate = u[meter_pos[j]] if j in meter_pos else 1.0
        flows.append(origin_flow(demands[j], w[j], rate, float(net.orig_cap_vph[j]), rho[i],
                                 float(net.rho_max[i]), float(net.rho_crit[i]), net.params.step_h,
                                 net.params.smooth_vph))
    return demands, flows


def _downstream_density(rho: Any, d: Any, i: int, net: MetanetNetwork) -> Any:
    """Density seen downstream of segment i: next segment, or the destination boundary."""
    j = int(net.down[i])
    if j >= 0:
        return rho[j]
    k = int(np.flatnonzero(net.dest_idx == i)[0])
    eps = net.params.smooth_rho
    return smooth_max(smooth_min(rho[i], float(net.rho_crit[i]), eps), d[net.n_sources + k], eps)


def _segment_speed_next(i: int, rho: Any, v: Any, d: Any, q_merge: Any, net: MetanetNetwork) -> Any:
    """Speed update of segment i (relaxation, convection, anticipation, merge, lane drop) [km/h]."""
    p, L, lanes = net.params, float(net.length_km[i]), float(net.lanes[i])
    T = p.step_h
    up = int(net.up[i])
    v_up = v[up] if up >= 0 else v[i]
    rho_eq = smooth_max(rho[i], 0.0, p.smooth_pos_rho) if p.smooth_pos_rho > 0.0 else rho[i]
    v_eq = equilibrium_speed(rho_eq, float(net.v_free_kmh[i]), float(net.rho_crit[i]), float(net.a[i]))
    rho_down = _downstream_density(rho, d, i, net)
    v_next = (v[i] + T / p.tau_h * (v_eq - v[i]) + T / L * v[i] * (v_up - v[i])
              - p.nu_km2ph * T / (p.tau_h * L) * (rho_down - rho[i]) / (rho[i] + p.kappa))
    if q_merge is not None:
        v_next = v_next - p.delta * T * q_merge * v[i] / (L * lanes * (rho[i] + p.kappa))
    j = int(net.down[i])
    drop = lanes - float(net.lanes[j]) if j >= 0 else 0.0
    if drop > 0:
        v_next = v_next - p.phi * T * drop * rho[i] * v[i] ** 2 / (L * lanes * float(net.rho_crit[i]))
    return fmax(v_next, 0.0)


def step_with_flows(x: Any, u: Any, d: Any, net: MetanetNetwork) -> tuple[Any, Any, Any]:
    """One METANET step: returns (x_next, q_seg [veh/h], q_orig [veh/h]).

    Works on 1-D numpy arrays (returns arrays) and on CasADi SX/MX columns (returns columns).
    """
    rho, v, w = net.split_x(x)
    T = net.params.step_h
    q = [rho[i] * v[i] * float(net.lanes[i]) for i in range(net.n_seg)]
    demands, q_o = _origin_flows(x, u, d, net)
    inflow: list[Any] = [0.0] * net.n_seg
    merge: list[Any] = [None] * net.n_seg
    for i in range(net.n_seg):
        up = int(net.up[i])
        if up >= 0:
            inflow[i] = (1.0 - float(net.exit_frac[up])) * q[up]
    for j in range(net.n_orig):
        i = int(net.orig_seg[j])
        inflow[i] = inflow[i] + q_o[j]
        if net.orig_onramp[j]:
            merge[i] = q_o[j] if merge[i] is None else merge[i] + q_o[j]
    rho_next = [fmax(rho[i] + T / (float(net.length_km[i]) * float(net.lanes[i])) * (inflow[i] - q[i]), 0.0)
                for i in range(net.n_seg)]
    v_next = [_segment_speed_next(i, rho, v, d, merge[i], net) for i in range(net.n_seg)]
    # no clamp on w: q_o <= d + w/T already keeps w >= 0, and a kink there would stall IPOPT
    w_next = [w[j] + T * (demands[j] - q_o[j]) for j in range(net.n_orig)]
    return vcat(rho_next + v_next + w_next), vcat(q), vcat(q_o)


def step(x: Any, u: Any, d: Any, net: MetanetNetwork) -> Any:
    """One METANET step x_next = f(x, u, d) (see ``step_with_flows``)."""
    return step_with_flows(x, u, d, net)[0]


def total_time_spent_step(x: Any, net: MetanetNetwork) -> Any:
    """Vehicle-hours spent during one model step in state x: T (sum rho L lanes + sum w) [veh h]."""
    rho, _, w = net.split_x(x)
    lane_km = net.lane_km()
    veh = sum(rho[i] * float(lane_km[i]) for i in range(net.n_seg)) + sum(w[j] for j in range(net.n_orig))
    return net.params.step_h * veh


@dataclass(frozen=True)
class SimResult:
    """Trajectory of a pure-model run: states after each step and the flows during it."""

    x: np.ndarray  # (K+1, nx): x[0] initial, x[k+1] after step k
    q_seg_vph: np.ndarray  # (K, n_seg)
    q_orig_vph: np.ndarray  # (K, n_orig)
    u: np.ndarray  # (K, nu) applied inputs
    tts_veh_h: float  # total time spent, sum over k of T (vehicles in x[k+1]) [veh h]


def simulate(net: MetanetNetwork, x0: np.ndarray, u_seq: np.ndarray, d_seq: np.ndarray) -> SimResult:
    """Run the model open loop over K steps with inputs u_seq (K, nu) and disturbances d_seq (K, nd)."""
    f = net.function
    K = d_seq.shape[0]
    xs = np.zeros((K + 1, net.nx))
    qs, qo = np.zeros((K, net.n_seg)), np.zeros((K, net.n_orig))
    xs[0] = x0
    for k in range(K):
        xn, q, q_o = f(xs[k], u_seq[k], d_seq[k])
        xs[k + 1], qs[k], qo[k] = xn.full().ravel(), q.full().ravel(), q_o.full().ravel()
    tts = float(sum(total_time_spent_step(xs[k + 1], net) for k in range(K)))
    return SimResult(x=xs, q_seg_vph=qs, q_orig_vph=qo, u=np.asarray(u_seq, dtype=float), tts_veh_h=tts)


def steady_state(net: MetanetNetwork, rho: float | np.ndarray) -> np.ndarray:
    """A state with the given densities, equilibrium speeds and empty queues (a convenient x0)."""
    rho_arr = np.broadcast_to(np.asarray(rho, dtype=float), (net.n_seg,)).copy()
    v = equilibrium_speed(rho_arr, net.v_free_kmh, net.rho_crit, net.a)
    return np.concatenate([rho_arr, v, np.zeros(net.n_orig)])
