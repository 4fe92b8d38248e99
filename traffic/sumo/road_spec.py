"""The road as data: the SUMO backend's ``Params`` (network: generated, or a user's own files with
``sumo_files``; demand; SUMO options and the SUMO output files a run writes into its batch folder).

A scenario gives it as the backend entry ``backends.road = {type: sumo, params: {...}}`` or, the same
thing, with the loader's shorthand ``road: {...}``; errors name the field as the file spelled it
(``road.demand.flows.ramp.flow_vph: must be >= 0``).  ``road_spec(scenario)`` is how other road
components read it from a validated scenario.
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, Field, SerializeAsAny, ValidationError, field_validator, model_validator

from corridor.errors import clip
from corridor.scenario import MAX_DT_S, MIN_DT_S, NestedParamsError, Strict, key_text, resolving_files

MAX_FLOW_VPH = 20_000.0  # per flow (scale included); a 10-lane freeway carries ~ 22 000 veh/h
# SUMO options that change the simulation but write no file (anything else is refused: an option such
# as --fcd-output PATH would overwrite PATH)
SUMO_ALLOWED_OPTIONS = ("--lateral-resolution", "--max-depart-delay", "--ignore-junction-blocker",
                        "--step-method.ballistic", "--extrapolate-departpos", "--ignore-route-errors",
                        "--junction-taz")  # the last two: for a user's own routes (OSM networks, TAZ trips)
SUMO_ALLOWED_PREFIXES = ("--time-to-teleport", "--collision.", "--default.")


class NetworkSpec(Strict):
    """A network: a builder of ``corridor.traffic.networks.registry.BUILDERS`` and its params, validated
    into that builder's own typed params model (errors name ``network.params.<field>``)."""

    type: str = "highway_onramp"
    params: SerializeAsAny[BaseModel] = Field(default=None, validate_default=True)  # the builder's model

    @field_validator("type")
    @classmethod
    def _known_builder(cls, kind: str) -> str:
        from corridor.traffic.networks.registry import params_model

        try:
            params_model(kind)
        except KeyError as exc:
            raise ValueError(clip(exc.args[0], 200)[1:-1]) from None
        return kind

    @model_validator(mode="before")
    @classmethod
    def _builder_params(cls, data: Any) -> Any:
        """``params`` (a mapping in the YAML) becomes the builder's typed params model."""
        from corridor.traffic.networks.registry import params_model

        if not isinstance(data, dict):
            return data
        kind = data.get("type", "highway_onramp")
        try:
            model = params_model(kind) if isinstance(kind, str) else None
        except KeyError:
            return data  # the type's own validator reports it
        raw = data.get("params")
        if model is None or isinstance(raw, model):
            return data
        if raw is None:
            raw = {}
        if not isinstance(raw, dict):
            raise ValueError(f"params: must be a mapping of {kind} network parameters")
        try:
            return {**data, "params": model.model_validate(raw)}
        except ValidationError as exc:
            raise NestedParamsError("params", exc, model) from None


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
    speed_mode: int | None = Field(None, ge=0, le=127)  # TraCI speed mode set when a vehicle departs
    #   (None: SUMO's own, 31); Flow's humans drive "obey_safe_speed" = 1 (no right-of-way checks)
    preset: str | None = None  # a driver preset of corridor.traffic.sumo.driver_presets: its values are the
    #   defaults of this type, the fields given beside it override them (lc / extra key by key)

    @model_validator(mode="before")
    @classmethod
    def _apply_preset(cls, data: Any) -> Any:
        if not isinstance(data, dict) or data.get("preset") is None:
            return data
        from corridor.traffic.sumo.driver_presets import preset_values

        return preset_values(data["preset"], data)


class FlowSpec(Strict):
    route: str  # a route name of the network (e.g. main, ramp)
    vtype: str = "car"
    flow_vph: float | None = Field(None, ge=0, le=MAX_FLOW_VPH, json_schema_extra={"unit": "veh/h"})  # constant rate
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
            if any(p[1] > MAX_FLOW_VPH for p in self.profile):
                raise ValueError(f"profile rates must be <= {MAX_FLOW_VPH:.0f} veh/h")
        return self

    def max_rate(self) -> float:
        return self.flow_vph if self.profile is None else max((r for _, r in self.profile), default=0.0)

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
                raise ValueError(f"flows.{key_text(name)}: flow names cannot contain '.'")
            if fl.vtype not in self.vehicle_types:
                raise ValueError(f"flows.{key_text(name)}.vtype: unknown vehicle type {clip(fl.vtype)}")
            if fl.max_rate() * self.scale > MAX_FLOW_VPH:
                raise ValueError(f"flows.{key_text(name)}: rate x scale = {fl.max_rate() * self.scale:.4g} veh/h, "
                                 f"must be <= {MAX_FLOW_VPH:.0f} veh/h")
        return self


# SUMO's own outputs a scenario may ask for (``road.sumo.outputs``) and the options that write them;
# the file is always ``<batch folder>/sumo/<run_id>/<kind>.xml``
SUMO_OUTPUT_OPTIONS: dict[str, tuple[str, ...]] = {
    "fcd": ("--fcd-output",),
    "tripinfo": ("--tripinfo-output",),
    "summary": ("--summary-output",),
    "ssm": ("--device.ssm.probability", "1", "--device.ssm.file"),  # every vehicle carries the SSM device
}
SumoOutput = Literal["fcd", "tripinfo", "summary", "ssm"]


class SumoOptions(Strict):
    step_length: float = Field(0.1, ge=MIN_DT_S, le=MAX_DT_S, json_schema_extra={"unit": "s"})
    outputs: list[SumoOutput] = Field(default_factory=list)  # SUMO's own files, in <out>/sumo/<run_id>/
    collision_action: Literal["warn", "teleport", "remove", "none"] = "warn"
    collision_check_junctions: bool = True
    time_to_teleport: float = 300.0  # [s]; < 0 disables
    emissions: bool = False  # read every vehicle's CO2 and fuel rate [mg/s] each step (SUMO's emission
    #   model of its vType emissionClass) into the road frame; off: nothing read, nothing costs
    extra_args: list[str] = Field(default_factory=list)  # SUMO_ALLOWED_OPTIONS / _PREFIXES only

    @field_validator("outputs")
    @classmethod
    def _once_each(cls, kinds: list[str]) -> list[str]:
        if len(set(kinds)) != len(kinds):
            raise ValueError("each output kind at most once")
        return kinds

    @field_validator("extra_args", mode="before")
    @classmethod
    def _numbers_as_text(cls, args: Any) -> Any:  # [--lateral-resolution, 0.8]: YAML reads 0.8 as a number
        if isinstance(args, list):
            return [str(a) if isinstance(a, int | float) and not isinstance(a, bool) else a for a in args]
        return args

    @field_validator("extra_args")
    @classmethod
    def _no_output_options(cls, args: list[str]) -> list[str]:
        expect_value = False
        for arg in args:
            is_option = arg.startswith("-") and not _is_number(arg)
            if not is_option:
                if not expect_value:
                    raise ValueError(f"{clip(arg)} is not an option (give ['--option', 'value', ...])")
                expect_value = False
                continue
            name = arg.split("=", 1)[0]
            ok = name in SUMO_ALLOWED_OPTIONS or (
                name.startswith(SUMO_ALLOWED_PREFIXES) and not name.endswith(("-output", "-log", ".output")))
            if not ok:
                allowed = " ".join(o[2:] for o in (*SUMO_ALLOWED_OPTIONS, *(p + "*" for p in SUMO_ALLOWED_PREFIXES)))
                raise ValueError(f"{clip(name, 30)} writes files; allowed (after --): {allowed}")
            expect_value = "=" not in arg
        return args


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


class RoadSpec(Strict):
    """The SUMO backend's params (``backends.road.params``, or the ``road:`` shorthand)."""

    backend: Literal["sumo"] = "sumo"
    network: NetworkSpec = Field(default_factory=NetworkSpec)
    demand: DemandSpec = Field(default_factory=DemandSpec)
    sumo: SumoOptions = Field(default_factory=SumoOptions)

    @model_validator(mode="after")
    def _some_demand(self) -> RoadSpec:
        """A user's network without route files needs the scenario's own flows."""
        files = getattr(self.network.params, "resolved", None)  # sumo_files: (net, routes, additional)
        if files is None or self.demand.flows or not resolving_files():
            return self  # (without the scenario's folder, e.g. in a report, the files are not read)
        if not files()[1]:
            raise ValueError("the network has no route files (network.params.routes): give them, or "
                             "demand.flows on its named routes")
        return self


def road_spec(scenario: Any) -> RoadSpec | None:
    """The road of a validated scenario: the params of its (first) ``sumo`` backend entry, or None."""
    for spec in getattr(scenario, "backends", {}).values():
        if spec.type == "sumo":
            return RoadSpec.model_validate(spec.params)
    return None


def require_landmarks(scenario: Any, model: type[BaseModel], who: str) -> None:
    """Load-time check of a component that needs landmarks of kind ``model`` (an on-ramp's merge
    point, a beltway's ramps): the road's network builder must report them, else one line naming
    what is needed and which networks have it (``check_scenario`` of the component calls this)."""
    from corridor.traffic.networks.landmarks import Landmarks
    from corridor.traffic.networks.registry import builder_names, landmarks_model

    road = road_spec(scenario)
    if road is None:
        return  # no road at all: the component's road need says so at build
    if issubclass(landmarks_model(road.network.type), model):
        return
    fields = [f for f in model.model_fields if f not in Landmarks.model_fields]
    named = ", ".join(fields[:4]) + (", ..." if len(fields) > 4 else "")
    # the builders that report them: every declared builder's module imported (only on this error path)
    kinds = sorted(k for k in builder_names() if issubclass(landmarks_model(k), model))
    raise ValueError(f"{who} needs the landmarks of a {' or '.join(kinds) or model.__name__} network ({named}); "
                     f"road.network type {road.network.type!r} has none")


def check_landmark_positions(scenario: Any, names: dict[str, str | None]) -> None:
    """Load-time check of named landmark positions (``{param: landmark}``, e.g. ``count_landmark:
    past_merge_x``): each must be a position (``*_x``) of the road network's landmarks."""
    from corridor.traffic.networks.registry import landmarks_model

    road = road_spec(scenario)
    if road is None:
        return
    fields = landmarks_model(road.network.type).model_fields
    xs = sorted(f for f in fields if f.endswith("_x"))
    for param, name in names.items():
        if name is not None and (name not in fields or not name.endswith("_x")):
            raise ValueError(f"params.{param}: network {road.network.type!r} has no landmark {clip(name, 40)}; "
                             f"positions: {', '.join(xs) or 'none'}")
