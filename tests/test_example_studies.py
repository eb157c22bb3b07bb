"""The study files in examples/studies/ load, and every run they plan is a valid config (a policy file a wipe
refuses, or a field out of range, fails here rather than hours into a study)."""

from __future__ import annotations

from pathlib import Path

import pytest

from tactex.experiments.study_spec import load_spec_file, spec_from_dict
from tactex.tasks.clean import CleanConfig
from tactex.tasks.wipe import WipeConfig

ROOT = Path(__file__).resolve().parents[1]
SPECS = sorted((ROOT / "examples" / "studies").glob("*.toml"))


@pytest.mark.parametrize("path", SPECS, ids=lambda p: p.name)
def test_every_planned_run_of_an_example_study_is_a_valid_config(path: Path, monkeypatch) -> None:
    monkeypatch.chdir(ROOT)  # the policy files are named relative to the repository's root
    spec = spec_from_dict(load_spec_file(path))
    runs = spec.runs()
    assert runs
    cls = {"clean": CleanConfig, "wipe": WipeConfig}[spec.task]
    for run in runs:
        cls(**run.config)


def test_the_cup_policies_are_sized_for_its_wall(monkeypatch) -> None:
    """The bowl's policies rise past the cup's rim and are refused there; the cup's own fit it."""
    monkeypatch.chdir(ROOT)
    from tactex.errors import PolicyFileError

    with pytest.raises(PolicyFileError, match="leaves the cup's wall"):
        WipeConfig(object_name="cup", policy="examples/policies/sinusoid.toml", start_y_m=0.0)
    WipeConfig(object_name="cup", policy="examples/policies/cup/sinusoid.toml", start_y_m=0.0)
