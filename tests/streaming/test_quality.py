"""The viewer's quality levels (workers.streaming.quality): what each sets, what a client's own option does to it, and
the "auto" choice by the measured render time, alone and in a session."""
import pytest
from pydantic import ValidationError

from workers.streaming.params import BatchRenderParams, Viewpoint
from workers.streaming.quality import LEVELS, QualityChooser, level_options
from workers.streaming.session import RecordingSession, SessionLimits

from .test_session import archive, at_camera  # noqa: F401 - the session tests' recording fixture


class Clock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def test_levels_set_the_depth_options_and_a_clients_own_value_makes_the_level_custom():
    assert level_options("best", {}) == ({"aggregation": "sgm", "occlusions": "fill"}, "best")
    assert level_options("fast", {"aggregation": None}) == ({"aggregation": "sgm", "occlusions": "keep"}, "fast")
    assert level_options("best", {"occlusions": "fill"}) == (LEVELS["best"], "best")  # the level's own value
    options, runs = level_options("best", {"aggregation": "window"})
    assert options == {"aggregation": "window", "occlusions": "fill"} and runs == "custom"


def test_viewpoints_default_to_auto_and_batch_renders_to_best():
    vp = Viewpoint()
    assert vp.render_quality == "auto" and vp.aggregation is None and vp.occlusions is None
    fields, runs = vp.render_fields("fast")
    assert (fields["aggregation"], fields["occlusions"], fields["coarse_to_fine"], runs) == ("sgm", "keep", True, "fast")
    batch = BatchRenderParams(recording_id="r", orbit={})
    fields, runs = batch.render_fields(batch.render_quality)
    assert (fields["aggregation"], fields["occlusions"], runs) == ("sgm", "fill", "best")
    with pytest.raises(ValidationError):
        Viewpoint(render_quality="ultra")
    with pytest.raises(ValidationError):  # a batch render waits for nobody: no rate to hold
        BatchRenderParams(recording_id="r", orbit={}, render_quality="auto")


def test_auto_starts_fast_tries_best_where_fast_leaves_room_and_keeps_it_while_it_holds_the_rate():
    clock = Clock()
    chooser = QualityChooser(target_fps=20.0, retry_s=30.0, clock=clock)  # a 50 ms budget
    shape = (320, 240, 48)
    assert chooser.choose(shape) == "fast"  # nothing measured: the cheaper level, the first frame soonest
    chooser.record(shape, "fast", 30.0)  # over half the budget: best (two to four times fast) could not hold
    assert chooser.choose(shape) == "fast"
    chooser.record(shape, "fast", 20.0)
    chooser.record(shape, "fast", 18.0)  # median 20 ms: room for best
    assert chooser.choose(shape) == "best" and chooser.choose((640, 480, 64)) == "fast"  # per view shape
    chooser.record(shape, "best", 120.0)  # one time over budget, not far over: not yet decided
    assert chooser.choose(shape) == "best"
    chooser.record(shape, "best", 90.0)
    assert chooser.choose(shape) == "fast"
    clock.now = 29.0
    assert chooser.choose(shape) == "fast"
    clock.now = 30.0
    assert chooser.choose(shape) == "best"  # tried again
    chooser.record(shape, "best", 40.0)
    chooser.record(shape, "best", 45.0)
    assert chooser.choose(shape) == "best"  # the load has gone
    chooser.record((16, 16, 8), "fast", 1.0)
    chooser.record((16, 16, 8), "best", 500.0)  # one render far over budget decides at once
    assert chooser.choose((16, 16, 8)) == "fast"
    with pytest.raises(ValueError):
        QualityChooser(target_fps=0.0)


def test_a_session_draws_the_level_asked_for_and_says_which(take, archive):  # noqa: F811
    session = RecordingSession(take.rig, archive, SessionLimits(max_pixels=200 * 200, max_planes=64))
    header, _ = session.view("a", at_camera(take, 1, render_quality="fast"))
    assert (header["quality"], header["quality_asked"]) == ("fast", "fast")
    header, _ = session.view("a", at_camera(take, 1, render_quality="best"))
    assert header["quality"] == "best" and "occlusions_ms" in header["timings"]  # the fill ran
    header, _ = session.view("a", at_camera(take, 1, render_quality="best", occlusions="keep"))
    assert header["quality"] == "custom" and "occlusions_ms" not in header["timings"]


def test_auto_in_a_session_draws_best_only_where_it_holds_the_target_rate(take, archive):  # noqa: F811
    """A target no render can hold (2,000 fps): the session stays at "fast"; with a target every render holds, its
    first frame is "fast" and the next ones "best"."""
    slow = RecordingSession(take.rig, archive, SessionLimits(max_pixels=200 * 200, max_planes=64, target_fps=2000.0))
    auto = {"render_quality": "auto"}
    assert {slow.view("a", at_camera(take, 1, frame=k % 2, **auto))[0]["quality"] for k in range(4)} == {"fast"}
    assert slow.view("a", at_camera(take, 1, **auto))[0]["quality_asked"] == "auto"
    easy = RecordingSession(take.rig, archive, SessionLimits(max_pixels=200 * 200, max_planes=64, target_fps=0.01))
    levels = [easy.view("a", at_camera(take, 1, frame=k % 2, **auto))[0]["quality"] for k in range(4)]
    assert levels == ["fast", "best", "best", "best"]


def test_playing_a_recording_keeps_the_depth_where_the_scene_stood_still(take, archive):  # noqa: F811
    """The same view of the next frame: most pixels keep the previous frame's depth (the ball moved elsewhere), and
    the header says how many; another view, or a viewer's first, keeps none."""
    session = RecordingSession(take.rig, archive, SessionLimits(max_pixels=200 * 200, max_planes=64))
    first, _ = session.view("a", at_camera(take, 1, frame=0, render_quality="fast"))
    assert first["held"] == 0.0
    nxt, _ = session.view("a", at_camera(take, 1, frame=1, render_quality="fast"))
    assert 0.2 < nxt["held"] <= nxt["coverage"]
    other, _ = session.view("a", at_camera(take, 2, frame=0, render_quality="fast"))
    assert other["held"] == 0.0
