"""The SUMO backend skips comparing the id lists on a quiet step (no departure, arrival, teleport or
off-lane vehicle): on every such step of a real run the ids must be those of the previous step."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from corridor.batch import expand
from corridor.run import build
from corridor.scenario import apply_overrides, load, validate
from corridor.traffic.sumo.backend import SumoBackend
from tests.conftest import SCENARIOS

SCENARIO = SCENARIOS / "merging.yaml"


def test_a_quiet_step_has_the_previous_steps_ids(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    seen = {"quiet": 0, "other": 0}
    same_rows = SumoBackend._same_rows

    def checked(self: SumoBackend, ids: list[str], quiet: bool = False):  # noqa: ANN202
        prev = self._rows.id_list
        if quiet and len(ids) == len(prev):
            assert ids == prev  # what the skipped comparison would have found
            seen["quiet"] += 1
        else:
            seen["other"] += 1
        return same_rows(self, ids, quiet)

    monkeypatch.setattr(SumoBackend, "_same_rows", checked)
    sc, _ = load(str(SCENARIO), ["duration=120", "warmup=0"])  # departures from the start, arrivals from ~80 s
    metrics = build(sc, 1, tmp_path).run()
    assert metrics["vehicles_arrived"] > 0 and seen["quiet"] > 100 and seen["other"] > 100


def test_the_cached_roles_are_those_of_the_controlled_ids(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The role array with the controlled rows is kept while the rows and the controlled ids stay the
    same: on every step of a real V2X run it must be what marking them afresh gives (the former code)."""
    from corridor.snapshot import Role

    seen = {"kept": 0, "made": 0}
    role_of = SumoBackend._role

    def checked(self: SumoBackend, same):  # noqa: ANN001, ANN202
        before = self._roles[2]
        role = role_of(self, same)
        seen["kept" if role is before else "made"] += 1
        uid_of = self.tables.uid_of
        by_uid = np.zeros(len(self.tables.vehicle_ids), dtype=bool)
        by_uid[[uid_of[v] for v in self.controlled if v in uid_of]] = True
        fresh = same.role.copy()
        fresh[by_uid[same.uid]] = Role.CONTROLLED
        assert role.dtype == fresh.dtype and np.array_equal(role, fresh) and not role.flags.writeable
        return role

    monkeypatch.setattr(SumoBackend, "_role", checked)
    sc, raw = load(str(SCENARIO), ["duration=120", "warmup=0"])
    s = expand(sc, raw, str(SCENARIO), 1, variants=["v2x_cps"])[0]
    build(validate(apply_overrides(s.base, s.overrides), s.run_id), 1, tmp_path).run()
    assert seen["kept"] > 100 and seen["made"] > 100


def test_the_kept_set_of_live_ids_is_that_of_the_steps_ids(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """``apply`` keeps the set of the step's ids while the rows stay the same: it must be ``set(ids)``."""
    seen = {"kept": 0, "made": 0}
    apply = SumoBackend.apply

    def checked(self: SumoBackend, commands, ctx):  # noqa: ANN001, ANN202
        before = self._live[1]
        apply(self, commands, ctx)
        if self._ids_rows is not None:
            assert self._live[0] is self._ids_rows and self._live[1] == set(self._ids)
            seen["kept" if self._live[1] is before else "made"] += 1

    monkeypatch.setattr(SumoBackend, "apply", checked)
    sc, raw = load(str(SCENARIO), ["duration=120", "warmup=0"])
    s = expand(sc, raw, str(SCENARIO), 1, variants=["v2x_cps"])[0]
    build(validate(apply_overrides(s.base, s.overrides), s.run_id), 1, tmp_path).run()
    assert seen["kept"] > 100 and seen["made"] > 50
