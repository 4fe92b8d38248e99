"""Scenario schema (pydantic v2, frozen) and loader.

A scenario is pure data, validated once at load.  Errors are one line naming the file and the field
path (``scenarios/x.yaml: road.demand.flows.ramp.flow_vph: must be >= 0``).  ``extends: base.yaml``
reuses a file (deep merge); ``--set a.b=c`` overrides any field; ``sweep`` variants and ``randomize``
draws are overrides of the same kind, applied per run.

The package's modules, each importing only those above it::

    schema      the frozen models (Scenario, ComponentSpec, Distribution, ...) and the limits
    files       files a scenario names (ScenarioFile), relative to the scenario's folder
    messages    error formatting: one line with the file, the field path and a hint
    yaml_load   the safe YAML loader with limits, and the extends: chain
    overrides   --set parsing and applying, sweep variants and draws, shorthands
    loader      load, validate, resolve_scenario

Everything a user or a component needs is importable from ``corridor.scenario`` itself::

    from corridor.scenario import load, Scenario
"""

from __future__ import annotations

from corridor.scenario.files import ScenarioFile, file_stamps, resolving_files, scenario_dir
from corridor.scenario.loader import check_randomize, load, load_with_files, resolve_scenario, validate
from corridor.scenario.messages import NestedParamsError, format_error, key_text, show_path
from corridor.scenario.overrides import (
    apply_overrides,
    canonical_path,
    expand_shorthands,
    load_raw,
    parse_value,
    respell,
    set_overrides,
    set_path,
)
from corridor.scenario.schema import (
    KINDS,
    MAX_DT_S,
    MAX_DURATION_S,
    MAX_FILE_BYTES,
    MAX_SEED,
    MAX_STEPS,
    MAX_YAML_DEPTH,
    MAX_YAML_NODES,
    MIN_DT_S,
    NAME_PATTERN,
    SHORTHANDS,
    ComponentSpec,
    Distribution,
    Origin,
    Outputs,
    Scenario,
    SpecDecl,
    Strict,
)
from corridor.scenario.yaml_load import (
    MAX_EXTENDS,
    deep_merge,
    load_yaml_text,
    read_text,
    read_yaml,
    resolve_extends,
)

__all__ = [
    "KINDS", "MAX_DT_S", "MAX_DURATION_S", "MAX_EXTENDS", "MAX_FILE_BYTES", "MAX_SEED", "MAX_STEPS",
    "MAX_YAML_DEPTH", "MAX_YAML_NODES", "MIN_DT_S", "NAME_PATTERN", "SHORTHANDS",
    "ComponentSpec", "Distribution", "NestedParamsError", "Origin", "Outputs", "Scenario", "ScenarioFile",
    "SpecDecl", "Strict",
    "apply_overrides", "canonical_path", "check_randomize", "deep_merge", "expand_shorthands", "file_stamps",
    "format_error", "key_text", "load", "load_raw", "load_yaml_text", "load_with_files", "parse_value", "read_text", "read_yaml",
    "resolve_extends", "resolve_scenario", "resolving_files", "respell", "scenario_dir", "set_overrides",
    "set_path", "show_path", "validate",
]
