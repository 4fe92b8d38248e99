"""Scenario schema (pydantic v2, frozen) and loader.

A scenario is pure data, validated once at load.  Errors are one line naming the file and the field
path (``scenarios/x.yaml: road.demand.flows.ramp.flow_vph: must be >= 0``).  ``extends: base.yaml``
reuses a file (deep merge); ``--set a.b=c`` overrides any field; ``sweep`` variants and ``randomize``
draws are overrides of the same kind, applied per run.
"""

from __future__ import annotations

import copy
import difflib
from pathlib import Path
from typing import Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from corridor.channel import ChannelConfig
from corridor.errors import ScenarioError


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


# ---------------------------------------------------------------- road
class NetworkSpec(Strict):
    type: str = "highway_onramp"  # a builder of corridor.traffic.network.BUILDERS
    params: dict[str, Any] = Field(default_factory=dict)


class VehicleTypeSpec(Strict):
    """A SUMO vehicle type; units SI.  ``lc`` holds lane-change model attributes (lcCooperative, ...)."""

    car_following: Literal["Krauss", "IDM", "EIDM", "ACC", "CACC"] = "Krauss"
    accel: float = Field(2.6, gt=0)  # [m/s²]
    decel: float = Field(4.5, gt=0)  # [m/s²] comfortable
    emergency_decel: float = Field(9.0, gt=0)  # [m/s²]
    sigma: float = Field(0.5, ge=0, le=1)  # driver imperfection
    tau: float = Field(1.0, gt=0)  # [s] desired headway
    length: float = Field(5.0, gt=0)  # [m]
    width: float = Field(1.8, gt=0)  # [m]
    min_gap: float = Field(2.5, ge=0)  # [m]
    max_speed: float = Field(50.0, gt=0)  # [m/s]
    speed_factor: float = Field(1.0, gt=0)
    speed_dev: float = Field(0.1, ge=0)
    lc: dict[str, float] = Field(default_factory=dict)
    extra: dict[str, str | float] = Field(default_factory=dict)  # any other SUMO vType attribute


class FlowSpec(Strict):
    route: str  # a route name of the network (e.g. main, ramp)
    vtype: str = "car"
    flow_vph: float | None = Field(None, ge=0)  # constant rate [veh/h]
    profile: list[tuple[float, float]] | None = None  # [(t_s, veh/h)], piecewise linear
    arrivals: Literal["poisson", "uniform"] = "poisson"
    connected_share: float = Field(0.0, ge=0, le=1)  # share of connected/automated vehicles
    depart_lane: str = "best"
    depart_speed: str = "max"

    @model_validator(mode="after")
    def _one_rate(self) -> FlowSpec:
        if (self.flow_vph is None) == (self.profile is None):
            raise ValueError("give exactly one of flow_vph or profile")
        if self.profile is not None:
            ts = [p[0] for p in self.profile]
            if any(b < a for a, b in zip(ts, ts[1:])) or any(p[1] < 0 for p in self.profile):
                raise ValueError("profile times must increase and rates be >= 0")
        return self

    def rate_profile(self, duration_s: float, scale: float) -> list[tuple[float, float]]:
        if self.profile is None:
            return [(0.0, self.flow_vph * scale), (duration_s, self.flow_vph * scale)]
        return [(t, r * scale) for t, r in self.profile]


class DemandSpec(Strict):
    vehicle_types: dict[str, VehicleTypeSpec] = Field(default_factory=lambda: {"car": VehicleTypeSpec()})
    flows: dict[str, FlowSpec] = Field(default_factory=dict)
    scale: float = Field(1.0, ge=0)  # multiplies every flow (handy for randomize)

    @model_validator(mode="after")
    def _types_exist(self) -> DemandSpec:
        for name, fl in self.flows.items():
            if "." in name:
                raise ValueError(f"flows.{name}: flow names cannot contain '.'")
            if fl.vtype not in self.vehicle_types:
                raise ValueError(f"flows.{name}.vtype: unknown vehicle type {fl.vtype!r}")
        return self


class SumoOptions(Strict):
    step_length: float = Field(0.1, gt=0)  # [s]
    collision_action: Literal["warn", "teleport", "remove", "none"] = "warn"
    collision_check_junctions: bool = True
    time_to_teleport: float = 300.0  # [s]; < 0 disables
    extra_args: list[str] = Field(default_factory=list)


class RoadSpec(Strict):
    backend: Literal["sumo"] = "sumo"
    network: NetworkSpec = Field(default_factory=NetworkSpec)
    demand: DemandSpec = Field(default_factory=DemandSpec)
    sumo: SumoOptions = Field(default_factory=SumoOptions)


# ---------------------------------------------------------------- components, specs, batches
class ComponentSpec(Strict):
    type: str  # a registry name (BACKENDS, CONTROLLERS or MONITORS)
    period: float | None = Field(None, gt=0)  # [s]; None = the component's default
    params: dict[str, Any] = Field(default_factory=dict)


class SpecDecl(Strict):
    """An STL specification over the run's recorded signals, e.g. ``G[0,600](min_ttc > 1.5)``."""

    name: str
    formula: str


class Distribution(Strict):
    uniform: tuple[float, float] | None = None
    normal: tuple[float, float] | None = None  # (mean, std)
    integers: tuple[int, int] | None = None  # inclusive
    choice: list[Any] | None = None

    @model_validator(mode="after")
    def _exactly_one(self) -> Distribution:
        if sum(v is not None for v in (self.uniform, self.normal, self.integers, self.choice)) != 1:
            raise ValueError("give exactly one of uniform, normal, integers, choice")
        return self

    def draw(self, rng: Any) -> Any:
        if self.uniform is not None:
            return float(rng.uniform(*self.uniform))
        if self.normal is not None:
            return float(rng.normal(*self.normal))
        if self.integers is not None:
            return int(rng.integers(self.integers[0], self.integers[1] + 1))
        return self.choice[int(rng.integers(len(self.choice)))]


class Origin(Strict):
    lat: float = Field(48.137, ge=-90, le=90)  # [deg]
    lon: float = Field(11.575, ge=-180, le=180)  # [deg]
    alt: float = 0.0  # [m]


class Outputs(Strict):
    signals: bool = True  # keep per-run time series (signals/<run_id>.npz)
    rerun_period: float = Field(0.2, gt=0)  # [s] between Rerun frames


class Scenario(Strict):
    name: str
    description: str = ""
    seed: int = Field(0, ge=0)
    duration: float = Field(600.0, gt=0)  # [s]
    dt: float = Field(0.1, gt=0)  # [s] base tick
    warmup: float = Field(0.0, ge=0)  # [s] metrics ignore vehicles departing before this
    origin: Origin = Field(default_factory=Origin)
    road: RoadSpec | None = None
    backends: dict[str, ComponentSpec] = Field(default_factory=dict)  # more dynamics (e.g. jsbsim_fleet)
    controllers: dict[str, ComponentSpec] = Field(default_factory=dict)
    monitors: dict[str, ComponentSpec] = Field(default_factory=dict)
    channels: dict[str, ChannelConfig] = Field(default_factory=dict)
    specs: list[SpecDecl] = Field(default_factory=list)
    metrics: list[str] = Field(default_factory=list)  # key metric columns for the summary table
    sweep: dict[str, dict[str, Any]] = Field(default_factory=lambda: {"default": {}})
    randomize: dict[str, Distribution] = Field(default_factory=dict)
    outputs: Outputs = Field(default_factory=Outputs)

    @model_validator(mode="after")
    def _consistent(self) -> Scenario:
        if self.warmup >= self.duration:
            raise ValueError("warmup must be shorter than duration")
        if not self.sweep:
            raise ValueError("sweep needs at least one variant")
        return self


# ---------------------------------------------------------------- loading
def read_yaml(path: Path) -> dict[str, Any]:
    if not path.exists():
        raise ScenarioError(f"{path}: no such file")
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise ScenarioError(f"{path}: invalid YAML: {where}{problem}") from None
    if not isinstance(data, dict):
        raise ScenarioError(f"{path}: a scenario must be a YAML mapping, got {type(data).__name__}")
    return data


def deep_merge(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    out = copy.deepcopy(base)
    for k, v in over.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = deep_merge(out[k], v)
        else:
            out[k] = copy.deepcopy(v)
    return out


def resolve_extends(path: Path, seen: tuple[Path, ...] = ()) -> dict[str, Any]:
    path = path.resolve()
    if path in seen:
        raise ScenarioError(f"{path}: extends: cycle through {' -> '.join(p.name for p in seen)}")
    data = read_yaml(path)
    parent = data.pop("extends", None)
    if parent is None:
        return data
    return deep_merge(resolve_extends(path.parent / str(parent), (*seen, path)), data)


def parse_value(text: str) -> Any:
    """``--set`` values are YAML scalars/flows: ``3``, ``0.5``, ``true``, ``[1, 2]``, ``{a: 1}``."""
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError:
        return text


def set_path(data: dict[str, Any], dotted: str, value: Any) -> None:
    """Set ``a.b.0.c`` in nested dicts/lists, creating dicts on the way (validation catches typos)."""
    keys = dotted.split(".")
    node: Any = data
    for i, key in enumerate(keys):
        last = i == len(keys) - 1
        if isinstance(node, list):
            if not key.isdigit() or int(key) >= len(node):
                raise ScenarioError(f"{'.'.join(keys[:i + 1])}: no list item {key!r}")
            if last:
                node[int(key)] = value
            else:
                node = node[int(key)]
            continue
        if not isinstance(node, dict):
            raise ScenarioError(f"{'.'.join(keys[:i])}: is a value, cannot set {dotted!r} below it")
        if last:
            node[key] = value
        else:
            if not isinstance(node.get(key), dict | list):
                node[key] = {}
            node = node[key]


def apply_overrides(data: dict[str, Any], overrides: dict[str, Any]) -> dict[str, Any]:
    out = copy.deepcopy(data)
    for dotted, value in overrides.items():
        set_path(out, dotted, value)
    return out


def _field_names(model: type[BaseModel], loc: tuple[Any, ...]) -> list[str]:
    """The field names allowed at ``loc`` (for "did you mean" hints)."""
    cur: Any = model
    for part in loc:
        fields = getattr(cur, "model_fields", None)
        if fields is None or part not in fields:
            return []
        ann = fields[part].annotation
        cur = _model_in(ann)
        if cur is None:
            return []
    return list(getattr(cur, "model_fields", {}))


def _model_in(ann: Any) -> Any:
    if isinstance(ann, type) and issubclass(ann, BaseModel):
        return ann
    for arg in getattr(ann, "__args__", ()) or ():
        m = _model_in(arg)
        if m is not None:
            return m
    return None


def format_error(source: str, exc: ValidationError, model: type[BaseModel], prefix: str = "") -> str:
    """The first validation error as ``FILE: field.path: message (did you mean 'x'?)``."""
    err = exc.errors()[0]
    loc = tuple(err["loc"])
    path = ".".join(str(p) for p in loc)
    path = f"{prefix}.{path}" if prefix and path else (prefix or path)
    msg = err["msg"]
    if err["type"] == "extra_forbidden":
        allowed = _field_names(model, _model_path(model, loc[:-1]))
        close = difflib.get_close_matches(str(loc[-1]), allowed, n=1)
        msg = "unknown key" + (f" (did you mean {close[0]!r}?)" if close else
                               (f"; allowed: {', '.join(allowed)}" if allowed else ""))
    elif err["type"] in ("greater_than_equal", "greater_than", "less_than_equal", "less_than"):
        msg = msg.replace("Input should be", "must be")
    elif msg.startswith("Value error, "):
        msg = msg[len("Value error, "):]
    n = len(exc.errors())
    more = f" (+{n - 1} more)" if n > 1 else ""
    return f"{source}: {path}: {msg}{more}" if path else f"{source}: {msg}{more}"


def _model_path(model: type[BaseModel], loc: tuple[Any, ...]) -> tuple[Any, ...]:
    """Drop dict keys / list indices from a location so it walks model fields only."""
    out: list[Any] = []
    cur: Any = model
    for part in loc:
        fields = getattr(cur, "model_fields", None)
        if fields is not None and part in fields:
            out.append(part)
            cur = _model_in(fields[part].annotation)
    return tuple(out)


def validate(data: dict[str, Any], source: str) -> Scenario:
    """Validate raw scenario data, including each component's own ``params`` model."""
    try:
        sc = Scenario.model_validate(data)
    except ValidationError as exc:
        raise ScenarioError(format_error(source, exc, Scenario)) from None
    _validate_component_params(sc, source)
    return sc


def _validate_component_params(sc: Scenario, source: str) -> None:
    from corridor.registry import BACKENDS, CONTROLLERS, MONITORS

    for table, registry in (("backends", BACKENDS), ("controllers", CONTROLLERS), ("monitors", MONITORS)):
        for name, spec in getattr(sc, table).items():
            if spec.type not in registry:
                close = difflib.get_close_matches(spec.type, list(registry), n=1)
                hint = f" (did you mean {close[0]!r}?)" if close else f"; known: {', '.join(sorted(registry))}"
                raise ScenarioError(f"{source}: {table}.{name}.type: unknown {registry.what} {spec.type!r}{hint}")
            params_model = getattr(registry.get(spec.type), "Params", None)
            if params_model is not None:
                try:
                    params_model.model_validate(spec.params)
                except ValidationError as exc:
                    raise ScenarioError(format_error(source, exc, params_model, f"{table}.{name}.params")) from None
    if sc.road is not None:
        from corridor.traffic.network import params_model

        try:
            model = params_model(sc.road.network.type)
        except KeyError as exc:
            raise ScenarioError(f"{source}: road.network.type: {exc.args[0]}") from None
        try:
            model.model_validate(sc.road.network.params)
        except ValidationError as exc:
            raise ScenarioError(format_error(source, exc, model, "road.network.params")) from None


def load_raw(path: str | Path, sets: list[str] | None = None) -> dict[str, Any]:
    """Read a scenario file with ``extends`` resolved and ``--set a.b=c`` applied (not validated)."""
    data = resolve_extends(Path(path))
    for item in sets or []:
        key, eq, value = item.partition("=")
        if not eq or not key:
            raise ScenarioError(f"--set {item!r}: expected FIELD.PATH=VALUE")
        set_path(data, key.strip(), parse_value(value))
        _unrandomize(data, key.strip())
    return data


def _unrandomize(data: dict[str, Any], key: str) -> None:
    """A value the user ``--set`` wins over the scenario's ``randomize`` draw of that field (or of a
    field beneath it): otherwise every run of the batch would silently replace it with a draw."""
    rnd = data.get("randomize")
    if key.startswith("randomize.") or not isinstance(rnd, dict):
        return
    for path in [p for p in rnd if p == key or p.startswith(key + ".")]:
        del rnd[path]


def load(path: str | Path, sets: list[str] | None = None) -> tuple[Scenario, dict[str, Any]]:
    """Load, resolve, override and validate; returns the typed scenario and its raw data."""
    data = load_raw(path, sets)
    return validate(data, str(path)), data
