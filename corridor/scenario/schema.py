"""The scenario schema: frozen pydantic v2 models of a scenario file and the loader's limits.

A scenario is pure data, validated once at load: unknown fields, mutation and non-finite numbers are
refused.  ``Scenario`` is the whole file; ``ComponentSpec`` one backend, controller or monitor;
``Distribution`` one ``randomize`` entry.
"""

from __future__ import annotations

import math
import re
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from corridor.channel import ChannelConfig
from corridor.errors import clip

# ---------------------------------------------------------------- limits of the loader and the schema
MAX_FILE_BYTES = 1_000_000  # a scenario file (and each file it extends)
MAX_YAML_DEPTH = 64  # nesting levels of a YAML document
MAX_YAML_NODES = 200_000  # YAML nodes after alias expansion (a "billion laughs" file stops here)
MAX_STEPS = 100_000_000  # duration / dt
MAX_DURATION_S = 30 * 86400.0  # 30 days
MIN_DT_S, MAX_DT_S = 1e-3, 10.0
MAX_SEED = 2**32 - 1  # numpy SeedSequence / SUMO --seed
NAME_PATTERN = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}")  # scenario and variant names become file names
# Top-level shorthands of the loader: ``KEY: X`` is ``backends.KEY = {type: TYPE, params: X}``.  Only a
# name table (no import): ``road: {...}`` is the SUMO backend entry ``backends.road`` (type ``sumo``).
SHORTHANDS: dict[str, str] = {"road": "sumo"}


class Strict(BaseModel):
    """Base of the scenario models: unknown fields, mutation and non-finite numbers are refused."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


def _check_name(value: str, what: str) -> str:
    if not NAME_PATTERN.fullmatch(value) or ".." in value:
        raise ValueError(f"{what} {clip(value)} must be 1-64 letters, digits, '_', '-' or '.', start with a "
                         "letter or digit and not contain '..' (it names files)")
    return value


# ---------------------------------------------------------------- components, specs, batches
class ComponentSpec(Strict):
    """One entry of ``backends``, ``controllers`` or ``monitors``: its type, period [s] and params."""

    type: str  # a registry name (BACKENDS, CONTROLLERS or MONITORS)
    period: float | None = Field(None, gt=0, le=MAX_DURATION_S, json_schema_extra={"unit": "s"})  # None: default
    params: dict[str, Any] = Field(default_factory=dict)


class SpecDecl(Strict):
    """An STL specification over the run's recorded signals, e.g. ``G[0,600](min_ttc > 1.5)``."""

    name: str
    formula: str


class Distribution(Strict):
    """One ``randomize`` entry, of exactly one kind (uniform, normal, integers, choice, truncnormal, ...).

    ``draw`` is the nominal sampler (the numbers of the first four kinds are those corridor always
    drew); ``corridor.distributions`` (which imports this module, never the other way) gives every
    kind a density and a map from the standard normal, for importance sampling and splitting.
    """

    uniform: tuple[float, float] | None = None
    normal: tuple[float, float] | None = None  # (mean, std)
    integers: tuple[int, int] | None = None  # inclusive
    choice: list[Any] | None = None
    truncnormal: tuple[float, float, float, float] | None = None  # (mean, std, low, high)
    lognormal: tuple[float, float] | None = None  # (mu, sigma) of log(x): median exp(mu)
    beta: tuple[float, float, float, float] | None = None  # (a, b, low, high): low + (high - low) Beta(a, b)

    @model_validator(mode="after")
    def _exactly_one(self) -> Distribution:
        if sum(getattr(self, k) is not None for k in KINDS) != 1:
            raise ValueError(f"give exactly one of {', '.join(KINDS)}")
        if self.uniform is not None:
            lo, hi = self.uniform
            if not lo <= hi or not math.isfinite(hi - lo):
                raise ValueError(f"uniform: [low, high] needs finite low <= high, got [{lo:.6g}, {hi:.6g}]")
        if self.normal is not None and not 0 <= self.normal[1] < 1e300:
            raise ValueError(f"normal: [mean, std] needs std >= 0, got std {self.normal[1]:.6g}")
        if self.integers is not None:
            lo, hi = self.integers
            if not -2**62 <= lo <= hi <= 2**62:
                raise ValueError(f"integers: [low, high] needs low <= high (inclusive, |x| <= 2**62), "
                                 f"got [{clip(lo, 24)[1:-1]}, {clip(hi, 24)[1:-1]}]")
        if self.choice is not None and not 1 <= len(self.choice) <= 10_000:
            raise ValueError(f"choice: needs 1 to 10000 options, got {len(self.choice)}")
        if self.truncnormal is not None:
            mean, std, lo, hi = self.truncnormal
            if not (0 < std < 1e300 and lo < hi and math.isfinite(hi - lo)):
                raise ValueError(f"truncnormal: [mean, std, low, high] needs std > 0 and finite low < high, "
                                 f"got [{mean:.6g}, {std:.6g}, {lo:.6g}, {hi:.6g}]")
        if self.lognormal is not None and not 0 < self.lognormal[1] < 1e3:
            raise ValueError(f"lognormal: [mu, sigma] needs 0 < sigma < 1000, got sigma {self.lognormal[1]:.6g}")
        if self.beta is not None:
            a, b, lo, hi = self.beta
            if not (0 < a < 1e6 and 0 < b < 1e6 and lo < hi and math.isfinite(hi - lo)):
                raise ValueError(f"beta: [a, b, low, high] needs a, b > 0 and finite low < high, "
                                 f"got [{a:.6g}, {b:.6g}, {lo:.6g}, {hi:.6g}]")
        return self

    @property
    def kind(self) -> str:
        """The entry's kind, e.g. ``"uniform"``."""
        return next(k for k in KINDS if getattr(self, k) is not None)

    def extremes(self) -> list[Any]:
        """Values a draw can take at the edges (checked against the schema at load)."""
        if self.uniform is not None:
            return list(self.uniform)
        if self.normal is not None:
            return [self.normal[0]]
        if self.integers is not None:
            return list(self.integers)
        if self.truncnormal is not None:
            return list(self.truncnormal[2:])
        if self.lognormal is not None:
            return [math.exp(self.lognormal[0])]
        if self.beta is not None:
            return list(self.beta[2:])
        return list((self.choice or [])[:20])  # choice: the one kind left

    def draw(self, rng: Any) -> Any:
        """One value drawn with the generator ``rng`` (a ``numpy.random.Generator``)."""
        if self.uniform is not None:
            return float(rng.uniform(*self.uniform))
        if self.normal is not None:
            return float(rng.normal(*self.normal))
        if self.integers is not None:
            return int(rng.integers(self.integers[0], self.integers[1] + 1))
        if self.choice is not None:
            return self.choice[int(rng.integers(len(self.choice)))]
        return float(self.frozen().rvs(random_state=rng))  # scipy-backed kinds: sampled by their own rvs

    def frozen(self) -> Any:
        """The ``scipy.stats`` frozen distribution of a continuous kind (scipy imported on first use).

        Raises:
            ValueError: a discrete kind (``integers``, ``choice``).
        """
        from scipy import stats

        if self.uniform is not None:
            lo, hi = self.uniform
            return stats.uniform(loc=lo, scale=hi - lo)
        if self.normal is not None:
            return stats.norm(loc=self.normal[0], scale=self.normal[1])
        if self.truncnormal is not None:
            mean, std, lo, hi = self.truncnormal
            return stats.truncnorm((lo - mean) / std, (hi - mean) / std, loc=mean, scale=std)
        if self.lognormal is not None:
            return stats.lognorm(s=self.lognormal[1], scale=math.exp(self.lognormal[0]))
        if self.beta is not None:
            a, b, lo, hi = self.beta
            return stats.beta(a, b, loc=lo, scale=hi - lo)
        raise ValueError(f"{self.kind} is discrete: it has no scipy frozen continuous distribution")


KINDS = ("uniform", "normal", "integers", "choice", "truncnormal", "lognormal", "beta")


class Origin(Strict):
    """The geodetic origin of the scenario's local ENU frame."""

    lat: float = Field(48.137, ge=-90, le=90)  # [deg]
    lon: float = Field(11.575, ge=-180, le=180)  # [deg]
    alt: float = 0.0  # [m]


class Outputs(Strict):
    """What a run keeps besides its row: the time series, the Rerun frame period [s]."""

    signals: bool = True  # keep per-run time series (signals/<run_id>.npz)
    rerun_period: float = Field(0.2, ge=MIN_DT_S, le=MAX_DURATION_S, json_schema_extra={"unit": "s"})  # between frames


class Scenario(Strict):
    """A validated scenario: the frozen model of a scenario file (see docs/getting-started.md)."""

    name: str
    description: str = ""
    seed: int = Field(0, ge=0, le=MAX_SEED)
    duration: float = Field(600.0, gt=0, le=MAX_DURATION_S, json_schema_extra={"unit": "s"})
    dt: float = Field(0.1, ge=MIN_DT_S, le=MAX_DT_S, json_schema_extra={"unit": "s"})  # base tick
    warmup: float = Field(0.0, ge=0)  # [s] metrics ignore vehicles departing before this
    origin: Origin = Field(default_factory=Origin)
    backends: dict[str, ComponentSpec] = Field(default_factory=dict)  # dynamics (sumo, jsbsim_fleet, ...)
    controllers: dict[str, ComponentSpec] = Field(default_factory=dict)
    monitors: dict[str, ComponentSpec] = Field(default_factory=dict)
    channels: dict[str, ChannelConfig] = Field(default_factory=dict)
    specs: list[SpecDecl] = Field(default_factory=list)
    metrics: list[str] = Field(default_factory=list)  # key metric columns for the summary table
    sweep: dict[str, dict[str, Any]] = Field(default_factory=lambda: {"default": dict[str, Any]()})
    randomize: dict[str, Distribution] = Field(default_factory=dict)
    outputs: Outputs = Field(default_factory=Outputs)

    @field_validator("name")
    @classmethod
    def _safe_name(cls, v: str) -> str:
        return _check_name(v, "name")

    @field_validator("sweep")
    @classmethod
    def _safe_variant_names(cls, v: dict[str, dict[str, Any]]) -> dict[str, dict[str, Any]]:
        for name in v:
            _check_name(name, "variant name")
        return v

    @model_validator(mode="after")
    def _consistent(self) -> Scenario:
        if self.warmup >= self.duration:
            raise ValueError("warmup must be shorter than duration")
        if not self.sweep:
            raise ValueError("sweep needs at least one variant")
        if self.duration / self.dt > MAX_STEPS:
            raise ValueError(f"duration / dt = {self.duration / self.dt:.3g} steps, must be <= {MAX_STEPS:.0e} "
                             "(raise dt or shorten duration)")
        return self
