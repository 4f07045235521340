"""The job kinds: each engine declares its kinds (entry, parameter model) in workers/<engine>/job.py."""
import importlib

import pytest
from pydantic import ValidationError

from workers.registry import ENGINES, JobKind, get_kind


def all_kinds() -> list[JobKind]:
    """Every job kind of every engine (imports them all)."""
    return [kind for engine in ENGINES for kind in importlib.import_module(f"workers.{engine}.job").JOBS]


def test_every_kind_lives_in_its_engines_job_module():
    kinds = all_kinds()
    assert {k.name for k in kinds} >= {"orientation.batch", "depth.video", "streaming.recording", "streaming.render",
                                       "streaming.demo", "faces.train", "drone.reconstruct"}
    for kind in kinds:
        engine = kind.name.split(".")[0]
        assert engine in ENGINES
        module = importlib.import_module(f"workers.{engine}.job")
        assert kind in module.JOBS and kind.entry.__module__ == module.__name__
        assert get_kind(kind.name) is kind


def test_unknown_kinds_are_refused_by_name():
    for name in ("nope.x", "depth.nope", "os.system"):
        with pytest.raises(KeyError, match="unknown job kind"):
            get_kind(name)


def test_validate_fills_defaults_once_and_keeps_a_model_as_it_is():
    kind = get_kind("depth.video")
    params = kind.validate({"width": 16, "height": 12})
    assert isinstance(params, kind.params) and params.width == 16
    assert kind.validate(params) is params  # what the route parsed is what the job gets
    with pytest.raises(ValidationError):
        kind.validate({"width": 16, "height": 12, "scale": 0})
