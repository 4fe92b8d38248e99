"""What applies to each sweep variant of a batch: its validated scenario, and whether collision
probabilities mean anything for it (the console summary and the report both ask).

Collision columns apply only when some variant has entities a collision monitor can see: a backend
whose class contributes rows to the world snapshot (it overrides ``Backend.snapshot_part``: road
vehicles, aircraft, the ego).  A macroscopic model (METANET) has no vehicles, so its runs'
``collisions = 0`` is no evidence of safety.  A run that did report a collision always counts.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # pragma: no cover
    import pandas as pd


def registries() -> dict[str, Any]:
    from corridor.registry import BACKENDS, CONTROLLERS, MONITORS

    return {"backends": BACKENDS, "controllers": CONTROLLERS, "monitors": MONITORS}


def variant_scenarios(scenario: Any) -> dict[str, Any]:
    """Each sweep variant's validated scenario (base + that variant's overrides, as a run builds it;
    draws not applied); None for a variant that does not validate, or when ``scenario`` is not a
    corridor ``Scenario`` (then nothing is left out of the report)."""
    sweep = getattr(scenario, "sweep", None)
    if not isinstance(sweep, dict) or not hasattr(scenario, "model_dump"):
        return {}
    from corridor.errors import CorridorError
    from corridor.scenario import apply_overrides, validate

    base = scenario.model_dump(exclude_unset=True)
    out: dict[str, Any] = {}
    for v, over in sweep.items():
        try:
            out[str(v)] = validate(apply_overrides(base, over), f"variant {v}")
        except (CorridorError, ValueError, TypeError):
            out[str(v)] = None
    return out


def component_class(table: str, spec: Any) -> Any:
    try:
        return registries()[table].get(spec.type)
    except Exception:  # noqa: BLE001 - an unknown or unimportable class: treat as using everything
        return None


def has_entities(vsc: Any) -> bool:
    """Whether a variant's scenario has anything a collision monitor can see: a backend whose class
    contributes entities to the world snapshot (unknown classes count as having some)."""
    if vsc is None:
        return True
    from corridor.engine import Backend

    for spec in vsc.backends.values():
        cls = component_class("backends", spec)
        if cls is None or getattr(cls, "snapshot_part", None) is not Backend.snapshot_part:
            return True
    return False


def collisions_apply(df: pd.DataFrame, scenario: Any) -> bool:
    """Show collision probabilities?  Not when the rows have no ``collisions`` column, nor when no
    variant that ran has entities (a macroscopic model); always when some run reported one."""
    import pandas as pd

    if "collisions" not in df:
        return False
    if (pd.to_numeric(df["collisions"], errors="coerce").fillna(0) > 0).any():
        return True
    scen = variant_scenarios(scenario)
    ran = [v for v in dict.fromkeys(df["variant"].astype(str)) if v in scen] if "variant" in df else []
    return not ran or any(has_entities(scen[v]) for v in ran)
