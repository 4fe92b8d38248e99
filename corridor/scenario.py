"""Scenario schema (pydantic v2, frozen) and loader.

A scenario is pure data, validated once at load.  Errors are one line naming the file and the field
path (``scenarios/x.yaml: road.demand.flows.ramp.flow_vph: must be >= 0``).  ``extends: base.yaml``
reuses a file (deep merge); ``--set a.b=c`` overrides any field; ``sweep`` variants and ``randomize``
draws are overrides of the same kind, applied per run.
"""

from __future__ import annotations

import copy
import difflib
import math
import os
import re
import stat
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from contextvars import ContextVar
from pathlib import Path
from typing import Annotated, Any

import yaml
from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    field_validator,
    model_validator,
)

from corridor.channel import ChannelConfig
from corridor.errors import ScenarioError, clip

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


def _key(name: Any) -> str:
    """A user-chosen key inside a field path: as is when short and printable, else clipped."""
    text = str(name)
    return text if len(text) <= 40 and text.isprintable() else clip(text, 40)


key_text = _key  # for components' own params validators


class NestedParamsError(ValueError):
    """A nested params mapping failed its own model.

    Raised by a component's params validator that checked a free-form mapping (``where``, e.g.
    ``params`` of a network) against another model: the loader reports the inner field's path
    (``road.network.params.lanes: must be >= 1``) and the hints of ``model``.
    """

    def __init__(self, where: str, error: ValidationError, model: type[BaseModel]) -> None:
        super().__init__(str(error).splitlines()[0])
        self.where, self.error, self.model = where, error, model


def _check_name(value: str, what: str) -> str:
    if not NAME_PATTERN.fullmatch(value) or ".." in value:
        raise ValueError(f"{what} {clip(value)} must be 1-64 letters, digits, '_', '-' or '.', start with a "
                         "letter or digit and not contain '..' (it names files)")
    return value


# ---------------------------------------------------------------- files a scenario names
# The folder of the scenario file being validated (set by ``load`` and by a run, see ``scenario_dir``):
# relative paths of ``ScenarioFile`` fields are taken from it.  Unset (a report re-reading a
# scenario), a relative path is kept as written and not checked.
_SCENARIO_DIR: ContextVar[Path | None] = ContextVar("corridor_scenario_dir", default=None)
_NAMED_FILES: ContextVar[set[str] | None] = ContextVar("corridor_named_files", default=None)


@contextmanager
def scenario_dir(folder: str | Path | None) -> Iterator[set[str]]:
    """Validate inside this block with relative ``ScenarioFile`` paths taken from ``folder``.

    Yields:
        The set of the files resolved in it (absolute paths).
    """
    named: set[str] = set()
    token = _SCENARIO_DIR.set(Path(folder).resolve() if folder is not None else None)
    files_token = _NAMED_FILES.set(named)
    try:
        yield named
    finally:
        _NAMED_FILES.reset(files_token)
        _SCENARIO_DIR.reset(token)


def file_stamps(files: set[str]) -> dict[str, list[int]]:
    """Size [B] and modification time [ns] of each file a scenario names: path -> [size, mtime].

    A batch folder records them: ``--resume`` after one changed is refused.
    """
    out: dict[str, list[int]] = {}
    for f in sorted(files):
        try:
            st = os.stat(f)
        except OSError:
            continue
        out[f] = [st.st_size, st.st_mtime_ns]
    return out


def resolving_files() -> bool:
    """True inside ``scenario_dir``: files a scenario names are resolved and must exist.

    A validator that reads them checks them only then.
    """
    return _SCENARIO_DIR.get() is not None


def _scenario_file(text: str) -> str:
    """The absolute path of a file named by a scenario, relative to the scenario file's folder.

    It must be an existing file (refused at load, one line).
    """
    base = _SCENARIO_DIR.get()
    path = Path(text).expanduser()
    if not text or "\0" in text:
        raise ValueError(f"{clip(text)} is not a file path")
    if base is None:
        return str(path)
    full = path if path.is_absolute() else base / path
    try:
        found = full.is_file()
    except OSError:  # a name too long for the file system, ...
        found = False
    if not found:
        where = "" if path.is_absolute() else f" (relative to the scenario's folder {clip(str(base), 80)[1:-1]})"
        what = "not a regular file" if os.path.lexists(full) else "no such file"
        raise ValueError(f"{what}: {clip(text, 80)}{where}")
    resolved = str(full.resolve())
    named = _NAMED_FILES.get()
    if named is not None:
        named.add(resolved)
    return resolved


ScenarioFile = Annotated[str, AfterValidator(_scenario_file)]  # a component's params field naming a file


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
    drew); ``corridor.distributions`` gives every kind a density and a map from the standard normal,
    for importance sampling and splitting.
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
        return list(self.choice[:20])

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
        from corridor.distributions import frozen  # scipy-backed kinds: sampled by their own rvs

        return float(frozen(self).rvs(random_state=rng))


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
    sweep: dict[str, dict[str, Any]] = Field(default_factory=lambda: {"default": {}})
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


# ---------------------------------------------------------------- loading
class _LimitError(yaml.MarkedYAMLError):
    """A loader limit or a duplicate key; its ``problem`` holds no file content beyond what it names."""


class _Loader(yaml.SafeLoader):
    """``yaml.SafeLoader`` with limits.

    A nesting limit, an alias-expansion limit (nodes counted as if every alias were a copy), no
    recursive aliases and no duplicate keys.
    """

    def __init__(self, stream: str) -> None:
        super().__init__(stream)
        self._depth = 0
        self._nodes = 0
        self._sizes: dict[int, int] = {}  # id(node) -> its size once expanded (set when composed)
        self.root_key_lines: dict[Any, int] | None = None  # the document's top-level keys -> line (0-based)

    def _count(self, n: int, mark: Any) -> None:
        self._nodes += n
        if self._nodes > MAX_YAML_NODES:
            raise _LimitError(problem=f"more than {MAX_YAML_NODES} values once aliases are expanded", problem_mark=mark)

    def compose_node(self, parent: Any, index: Any) -> Any:
        if self.check_event(yaml.AliasEvent):
            event = self.peek_event()
            node = self.anchors.get(event.anchor)
            if node is not None:
                if id(node) not in self._sizes:
                    raise _LimitError(problem="an alias inside its own anchor (recursive data)",
                                      problem_mark=event.start_mark)
                self._count(self._sizes[id(node)], event.start_mark)
            return super().compose_node(parent, index)
        mark = self.peek_event().start_mark
        self._depth += 1
        if self._depth > MAX_YAML_DEPTH:
            raise _LimitError(problem=f"nested deeper than {MAX_YAML_DEPTH} levels", problem_mark=mark)
        start = self._nodes
        self._count(1, mark)
        node = super().compose_node(parent, index)
        self._depth -= 1
        self._sizes[id(node)] = self._nodes - start
        return node

    def construct_mapping(self, node: Any, deep: bool = False) -> Any:
        if isinstance(node, yaml.MappingNode):
            first: dict[Any, int] = {}
            for key_node, _ in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge":
                    continue
                key = self.construct_object(key_node, deep=True)
                try:
                    line = first.get(key)
                except TypeError:  # unhashable: the base class says so
                    continue
                if line is not None:
                    raise _LimitError(problem=f"duplicate key {clip(key, 40)} (lines {line + 1} and "
                                              f"{key_node.start_mark.line + 1})", problem_mark=key_node.start_mark)
                first[key] = key_node.start_mark.line
            if self.root_key_lines is None:  # the root mapping is constructed first
                self.root_key_lines = first
        return super().construct_mapping(node, deep=deep)


def _yaml_load(text: str) -> Any:
    return _yaml_load_lines(text)[0]


def _yaml_load_lines(text: str) -> tuple[Any, dict[Any, int]]:
    """The document and the lines of its top-level keys."""
    loader = _Loader(text)
    try:
        return loader.get_single_data(), loader.root_key_lines or {}
    finally:
        loader.dispose()


_QUOTED = re.compile(r"'[^']*'|\"[^\"]*\"")  # what PyYAML quotes in a problem: a token name or the file's text
_HARMLESS = re.compile(r"[^A-Za-z0-9\s]{1,3}|<[a-z ]+>")  # ':' or '<block end>' say no more than the syntax


def _yaml_problem(exc: Exception) -> str:
    """Where and what of a YAML error, without the file's text.

    PyYAML quotes the offending characters (and ``str(exc)`` the offending line), which for a file
    that is not a scenario (``extends: /etc/shadow``) is its content.  Keeps the line/column and the
    generic part of the reason.
    """
    if isinstance(exc, yaml.reader.ReaderError):
        return f"position {exc.position}: {exc.reason}"
    if not isinstance(exc, yaml.MarkedYAMLError):
        return "a value cannot be read (e.g. an invalid date or a too long number)"
    mark = exc.problem_mark
    where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark else ""
    problem = exc.problem or "syntax error"
    if not isinstance(exc, _LimitError):
        problem = _QUOTED.sub(lambda m: m[0] if _HARMLESS.fullmatch(m[0][1:-1]) else "…", problem)
    return f"{where}{clip(problem, 120)[1:-1]}"


def _show(path: Path | str) -> str:
    text = str(path)
    return text if len(text) <= 120 and text.isprintable() else clip(text, 120)


def read_text(path: Path) -> str:
    """A scenario file's text: a regular UTF-8 file of at most ``MAX_FILE_BYTES``."""
    try:
        st = path.stat()
    except ValueError:
        raise ScenarioError(f"{_show(path)}: a path cannot contain a NUL byte") from None
    except FileNotFoundError:
        raise ScenarioError(f"{_show(path)}: no such file") from None
    except (OSError, RuntimeError) as exc:  # symlink loop, name too long, permission denied, ...
        raise ScenarioError(f"{_show(path)}: cannot read ({getattr(exc, 'strerror', None) or 'symlink loop'})") from None
    if stat.S_ISDIR(st.st_mode):
        raise ScenarioError(f"{_show(path)}: is a directory, not a scenario file")
    if not stat.S_ISREG(st.st_mode):
        raise ScenarioError(f"{_show(path)}: not a regular file")
    if st.st_size > MAX_FILE_BYTES:
        raise ScenarioError(f"{_show(path)}: larger than {MAX_FILE_BYTES // 1000} kB, not a scenario file")
    try:
        with open(path, "rb") as f:
            raw = f.read(MAX_FILE_BYTES + 1)
    except OSError as exc:
        raise ScenarioError(f"{_show(path)}: cannot read ({exc.strerror or 'I/O error'})") from None
    if len(raw) > MAX_FILE_BYTES:
        raise ScenarioError(f"{_show(path)}: larger than {MAX_FILE_BYTES // 1000} kB, not a scenario file")
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ScenarioError(f"{_show(path)}: not a UTF-8 text file (byte {exc.start})") from None


def read_yaml(path: Path) -> dict[str, Any]:
    """The raw mapping of a scenario file, read with the safe loader's limits.

    Raises:
        ScenarioError: one line: invalid YAML, not a mapping, or not a scenario file (its keys are
            not echoed).
    """
    text = read_text(path)
    try:
        data, lines = _yaml_load_lines(text)
    except (yaml.YAMLError, ValueError, OverflowError, RecursionError) as exc:
        raise ScenarioError(f"{_show(path)}: invalid YAML: {_yaml_problem(exc)}") from None
    if not isinstance(data, dict):
        raise ScenarioError(f"{_show(path)}: a scenario must be a YAML mapping, got {type(data).__name__}")
    fields = [*Scenario.model_fields, *SHORTHANDS, "extends"]
    for key in data:  # a mapping of other keys is some other file (/etc/shadow is one): do not echo it
        if key in fields or isinstance(key, str) and difflib.get_close_matches(key[:80], fields, n=1, cutoff=0.75):
            continue  # a field, or a typo of one that validation names with a hint
        raise ScenarioError(f"{_show(path)}: not a scenario file: the top-level key at line "
                            f"{lines.get(key, -1) + 1} is not a scenario field")
    return data


def deep_merge(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    """A copy of ``base`` with ``over`` merged in, mapping by mapping (``over`` wins)."""
    out = copy.deepcopy(base)
    for k, v in over.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = deep_merge(out[k], v)
        else:
            out[k] = copy.deepcopy(v)
    return out


MAX_EXTENDS = 16  # files in one extends chain


def resolve_extends(path: Path, seen: tuple[Path, ...] = ()) -> dict[str, Any]:
    """The raw data of a scenario file with its ``extends:`` chain merged (a cycle is an error)."""
    try:
        real = path.resolve()
    except (OSError, RuntimeError, ValueError):  # NUL byte, symlink loop (3.11 raises RuntimeError)
        read_text(path)  # raises the one-line reason
        raise ScenarioError(f"{_show(path)}: cannot resolve this path") from None
    if real in seen:
        raise ScenarioError(f"{_show(real)}: extends: cycle through {' -> '.join(_show(p.name) for p in seen)}")
    if len(seen) >= MAX_EXTENDS:
        raise ScenarioError(f"{_show(real)}: extends: more than {MAX_EXTENDS} files in the chain")
    data = read_yaml(real)
    parent = data.pop("extends", None)
    if parent is None:
        return data
    if not isinstance(parent, str) or not parent:
        raise ScenarioError(f"{_show(real)}: extends: must be a file path, got {type(parent).__name__}")
    return deep_merge(resolve_extends(real.parent / parent, (*seen, real)), data)


def parse_value(text: str) -> Any:
    """``--set`` values are YAML scalars/flows: ``3``, ``0.5``, ``true``, ``[1, 2]``, ``{a: 1}``."""
    try:
        return _yaml_load(text)
    except (yaml.YAMLError, ValueError, OverflowError, RecursionError):
        return text


def _keyed_by_paths(prefix: list[str]) -> bool:
    """``randomize`` and each ``sweep`` variant are maps keyed by whole dotted paths."""
    return prefix == ["randomize"] or (len(prefix) == 2 and prefix[0] == "sweep")


def set_path(data: dict[str, Any], dotted: str, value: Any) -> None:
    """Set ``a.b.0.c`` in nested dicts/lists, creating dicts on the way (validation catches typos).

    Below ``randomize`` and ``sweep.<variant>`` the keys are dotted paths themselves: the rest of the
    path is matched against them (``sweep.v2x_cps.controllers.merge.params.policy`` sets ``policy`` in
    the variant's ``controllers.merge`` entry) or becomes a new key (``sweep.v2x_cps.duration``).
    """
    keys = respell(data, dotted.split("."))
    if len(keys) > MAX_YAML_DEPTH:
        raise ScenarioError(f"{clip(dotted)}: more than {MAX_YAML_DEPTH} levels")
    node: Any = data
    i = 0
    while i < len(keys):
        key = keys[i]
        last = i == len(keys) - 1
        if isinstance(node, list):
            if not key.isdigit() or int(key) >= len(node):
                raise ScenarioError(f"{clip('.'.join(keys[:i + 1]))}: no list item {clip(key, 20)}")
            if last:
                node[int(key)] = value
            else:
                node = node[int(key)]
            i += 1
            continue
        if not isinstance(node, dict):
            raise ScenarioError(f"{clip('.'.join(keys[:i]))}: is a value, cannot set {clip(dotted)} below it")
        if _keyed_by_paths(keys[:i]):
            rest = keys[i:]
            match = max((k for k in node if isinstance(k, str) and k.split(".") == rest[:k.count(".") + 1]),
                        key=len, default=None)
            if match is None or match.count(".") + 1 == len(rest):
                node[match or ".".join(rest)] = value
                return
            node = node[match]
            i += match.count(".") + 1
            continue
        if last:
            node[key] = value
        else:
            if not isinstance(node.get(key), dict | list):
                node[key] = {}
            node = node[key]
        i += 1


def respell(data: Any, keys: list[str]) -> list[str]:
    """Spell a dotted path the way ``data`` spells its shorthands.

    A path through a shorthand reaches the same field whichever spelling ``data`` uses:
    ``road.demand.scale`` is ``backends.road.params.demand.scale`` when the data has no ``road:``
    key but a ``backends.road`` entry, and the other way round.
    """
    if not isinstance(data, dict):
        return keys
    if keys[:1] and keys[0] in SHORTHANDS and keys[0] not in data:
        backends = data.get("backends")
        if isinstance(backends, dict) and keys[0] in backends:
            return ["backends", keys[0], "params", *keys[1:]]
    if len(keys) >= 3 and keys[0] == "backends" and keys[1] in SHORTHANDS and keys[2] == "params" \
            and isinstance(data.get(keys[1]), dict):
        return [keys[1], *keys[3:]]
    return keys


def canonical_path(dotted: str) -> str:
    """The full spelling of an override path (``road.x`` -> ``backends.road.params.x``)."""
    keys = dotted.split(".")
    return ".".join(["backends", keys[0], "params", *keys[1:]]) if keys[0] in SHORTHANDS else dotted


def expand_shorthands(data: dict[str, Any], source: str) -> tuple[dict[str, Any], set[str]]:
    """Rewrite ``road: X`` as ``backends.road = {type: sumo, params: X}``, first among the backends.

    The backends' order is the order components are built and stepped in.

    Returns:
        The data and the names of the backend entries that came from a shorthand (their errors are
        reported in the shorthand).
    """
    if not any(k in data for k in SHORTHANDS):
        return data, set()
    data = dict(data)
    front: dict[str, Any] = {}
    for key, kind in SHORTHANDS.items():
        if key not in data:
            continue
        value = data.pop(key)
        if value is None:  # `road: null` (e.g. a variant removing the road): no such backend
            continue
        backends = data.get("backends")
        if isinstance(backends, dict) and key in backends:
            raise ScenarioError(f"{source}: {key}: is the shorthand of backends.{key}, which is given too; "
                                "use one of them")
        front[key] = {"type": kind, "params": value}
    backends = data.get("backends")
    data["backends"] = {**front, **backends} if isinstance(backends, dict) else (front if backends is None
                                                                                  else backends)
    return data, set(front)


def apply_overrides(data: dict[str, Any], overrides: dict[str, Any]) -> dict[str, Any]:
    """A copy of ``data`` with every ``dotted.path: value`` of ``overrides`` set (``--set``, variants, draws)."""
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


def _unit(model: type[BaseModel], loc: tuple[Any, ...]) -> str:
    """The ``unit`` a field declares (``json_schema_extra``), for bound messages."""
    cur: Any = model
    info = None
    for part in loc:
        fields = getattr(cur, "model_fields", None)
        if fields is None or part not in fields:
            continue
        info = fields[part]
        cur = _model_in(info.annotation)
    extra = getattr(info, "json_schema_extra", None)
    return f" {extra['unit']}" if isinstance(extra, dict) and "unit" in extra else ""


def format_error(source: str, exc: ValidationError, model: type[BaseModel], prefix: str = "",
                 shorthands: set[str] | frozenset[str] = frozenset()) -> str:
    """The first validation error as ``FILE: field.path: message (did you mean 'x'?)``.

    Paths into backend entries named in ``shorthands`` are shown as the shorthand spelled them
    (``road.x``).
    """
    err = exc.errors()[0]
    loc = tuple(err["loc"])
    nested = (err.get("ctx") or {}).get("error")
    if err["type"] == "value_error" and isinstance(nested, NestedParamsError):
        inner = ".".join(_key(p) for p in (*loc, nested.where))
        return format_error(source, nested.error, nested.model, f"{prefix}.{inner}" if prefix else inner,
                            shorthands)
    path = ".".join(_key(p) for p in loc)
    path = f"{prefix}.{path}" if prefix and path else (prefix or path)
    for name in shorthands:
        full = f"backends.{name}.params"
        if path == full or path.startswith(full + "."):
            path = name + path[len(full):]
    msg = err["msg"]
    if err["type"] == "extra_forbidden":
        allowed = _field_names(model, _model_path(model, loc[:-1]))
        if model is Scenario and len(loc) == 1:
            allowed += list(SHORTHANDS)
        close = difflib.get_close_matches(str(loc[-1])[:80], allowed, n=1)
        listed = ", ".join(allowed)
        listed = listed if len(listed) <= 120 else listed[:listed.rfind(", ", 0, 118)] + ", …"
        msg = "unknown key" + (f" (did you mean {close[0]!r}?)" if close else (f"; allowed: {listed}" if allowed else ""))
    elif err["type"] in ("greater_than_equal", "greater_than", "less_than_equal", "less_than"):
        msg = msg.replace("Input should be", "must be") + _unit(model, loc)
    elif err["type"] == "finite_number":
        msg = "must be a finite number"
    elif msg.startswith("Value error, "):
        msg = msg[len("Value error, "):]
    msg = msg if len(msg) <= 240 else msg[:239] + "…"
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


def _non_finite(data: Any, path: tuple[str, ...] = ()) -> tuple[str, ...] | None:
    """The path of the first NaN or infinite number anywhere in the raw data (component params too)."""
    if isinstance(data, float) and not math.isfinite(data):
        return path
    items = data.items() if isinstance(data, dict) else enumerate(data) if isinstance(data, list | tuple) else ()
    for k, v in items:
        found = _non_finite(v, (*path, _key(k)))
        if found is not None:
            return found
    return None


def validate(data: dict[str, Any], source: str) -> Scenario:
    """Validate raw scenario data, including each component's own ``params`` model."""
    source = _show(source)
    bad = _non_finite(data)
    if bad is not None:
        raise ScenarioError(f"{source}: {'.'.join(bad)}: must be a finite number")
    data, shorthands = expand_shorthands(data, source)
    try:
        sc = Scenario.model_validate(data)
    except ValidationError as exc:
        raise ScenarioError(format_error(source, exc, Scenario, shorthands=shorthands)) from None
    except RecursionError:
        raise ScenarioError(f"{source}: nested too deeply") from None
    _validate_component_params(sc, source, shorthands)
    return sc


def _validate_component_params(sc: Scenario, source: str, shorthands: set[str] = frozenset()) -> None:
    from corridor.registry import BACKENDS, CONTROLLERS, MONITORS

    for table, registry in (("backends", BACKENDS), ("controllers", CONTROLLERS), ("monitors", MONITORS)):
        for name, spec in getattr(sc, table).items():
            where = f"{table}.{_key(name)}"
            if spec.type not in registry:
                close = difflib.get_close_matches(spec.type[:80], list(registry), n=1)
                known = ", ".join(sorted(registry))  # bounded: the message must stay one short line
                known = known if len(known) <= 120 else known[:known.rfind(", ", 0, 118)] + ", …"
                hint = f" (did you mean {close[0]!r}?)" if close else f"; known: {known}"
                raise ScenarioError(f"{source}: {where}.type: unknown {registry.what} {clip(spec.type)}{hint}")
            cls = registry.get(spec.type)
            params_model = getattr(cls, "Params", None)
            params: Any = spec.params
            if params_model is not None:
                try:
                    params = params_model.model_validate(spec.params)
                except ValidationError as exc:
                    raise ScenarioError(format_error(source, exc, params_model, f"{where}.params",
                                                     shorthands if table == "backends" else frozenset())) from None
            _check_component(cls, params, sc, f"{source}: {where}")


def _check_component(cls: Any, params: Any, sc: Scenario, where: str) -> None:
    """Run a component's own load-time check of the scenario around it, if it has one.

    ``check_scenario(params, sc)`` is optional: a controller that needs landmarks the road's network
    does not have says so here.
    """
    check = getattr(cls, "check_scenario", None)
    if check is None:
        return
    try:
        check(params, sc)
    except ValueError as exc:
        raise ScenarioError(f"{where}: {str(exc).strip()}") from None


def check_randomize(sc: Scenario, data: dict[str, Any], source: str) -> None:
    """Check that each ``randomize`` path gives a valid scenario at the edges of its distribution.

    It must do so in at least one sweep variant that is valid by itself: a path or value no variant
    accepts is an error at load, not an error row in every run.
    """
    source = _show(source)
    bases = [over for over in sc.sweep.values() if _is_valid(apply_overrides(data, over))]
    for path, dist in sorted(sc.randomize.items()):
        for value in dist.extremes():
            errors = []
            for over in bases:
                try:
                    validate(apply_overrides(data, {**over, path: value}), source)
                    break
                except ScenarioError as exc:
                    errors.append(str(exc).removeprefix(f"{source}: "))
            else:
                if errors:
                    raise ScenarioError(f"{source}: randomize.{clip(path, 60)[1:-1]}: the draw {clip(value, 30)} "
                                        f"is invalid: {errors[0]}")


def _is_valid(data: dict[str, Any]) -> bool:
    try:
        validate(data, "")
    except ScenarioError:
        return False
    return True


def load_raw(path: str | Path, sets: list[str] | None = None) -> dict[str, Any]:
    """Read a scenario file with ``extends`` resolved and ``--set a.b=c`` applied (not validated)."""
    data = resolve_extends(Path(path))
    for item in sets or []:
        key, eq, value = item.partition("=")
        if not eq or not key.strip():
            raise ScenarioError(f"--set {clip(item)}: expected FIELD.PATH=VALUE")
        set_path(data, key.strip(), parse_value(value))
        _unrandomize(data, key.strip())
    return data


def _unrandomize(data: dict[str, Any], key: str) -> None:
    """Take a field the user ``--set`` (and the fields beneath it) out of ``randomize``.

    Otherwise every run of the batch would silently replace the set value with a draw.
    """
    rnd = data.get("randomize")
    if key.startswith("randomize.") or not isinstance(rnd, dict):
        return
    key = canonical_path(key)  # road.x and backends.road.params.x are one field
    for path in [p for p in rnd if canonical_path(p) == key or canonical_path(p).startswith(key + ".")]:
        del rnd[path]


_COMPONENT_TABLES = ("backends", "controllers", "monitors")


def _variant_hint(path: str | Path, sets: list[str], message: str) -> str:
    """Say how to set a field that exists only inside a sweep variant.

    When a ``--set`` below a component fails on the base scenario but works inside a sweep variant
    (merging.yaml: ``controllers.merge`` is ``v2x_merging`` only in the v2x variants, so its params
    cannot be set on the base), the hint names the variant path to set instead.
    """
    for item in sets:
        key = item.partition("=")[0].strip()
        parts = key.split(".")
        if len(parts) < 3 or parts[0] not in _COMPONENT_TABLES or f"{parts[0]}.{parts[1]}" not in message:
            continue
        rest = [s for s in sets if s is not item]
        sweep = load_raw(path, rest).get("sweep")
        works = []
        for variant in list(sweep)[:8] if isinstance(sweep, dict) else []:
            try:
                data = load_raw(path, [*rest, f"sweep.{variant}.{item}"])
                validate(apply_overrides(data, data["sweep"][variant]), "")
            except ScenarioError:
                continue
            works.append(_key(variant))
        if works:
            return (f"; {parts[0]}.{_key(parts[1])} is set per variant: use --set sweep.VARIANT.{clip(key, 60)[1:-1]}"
                    f"=VALUE (works for {clip(', '.join(works), 50)[1:-1]})")
    return ""


def set_overrides(sets: Sequence[str]) -> dict[str, Any]:
    """The ``--set`` values as overrides applied after a run's sweep variant.

    The command line wins over a variant that sets the same field (``sweep.`` and ``randomize.``
    paths are not re-applied: they edit the variants and draws themselves).
    """
    out: dict[str, Any] = {}
    for item in sets:
        key, _, value = item.partition("=")
        key = key.strip()
        if key.split(".")[0] not in ("sweep", "randomize"):
            out[key] = parse_value(value)
    return out


def load(path: str | Path, sets: list[str] | None = None) -> tuple[Scenario, dict[str, Any]]:
    """Load, resolve, override and validate; returns the typed scenario and its raw data.

    Files the scenario names (``ScenarioFile`` fields) are relative to the scenario file's folder.
    """
    sc, data, _ = load_with_files(path, sets)
    return sc, data


def load_with_files(path: str | Path, sets: list[str] | None = None) -> tuple[Scenario, dict[str, Any], set[str]]:
    """``load``, and the files the scenario names (``ScenarioFile`` fields of the base scenario)."""
    data = load_raw(path, sets)
    with scenario_dir(Path(path).parent) as named:
        sc, data = _load_validated(path, data, sets)
    return sc, data, named


def _load_validated(path: str | Path, data: dict[str, Any], sets: list[str] | None) -> tuple[Scenario, dict[str, Any]]:
    try:
        sc = validate(data, str(path))
    except ScenarioError as exc:
        hint = _variant_hint(path, sets or [], str(exc))
        if not hint:
            raise
        raise ScenarioError(re.sub("; allowed: .*", "", str(exc)) + hint) from None
    after = set_overrides(sets or [])
    for variant, over in sc.sweep.items():  # every variant is checked now, not in every run of the batch
        if over:
            validate(apply_overrides(data, {**over, **after}), f"{path} [sweep.{_key(variant)}]")
    check_randomize(sc, data, str(path))
    return sc, data
