"""A prepared worker's rehearsal (workers/orientation/rehearsal.py): its page goes through every step of the text cue,
as a text photo would, so what that sets up is ready before the first photo."""
from __future__ import annotations

import pytest

from workers.orientation.detect import DetectorConfig, get_detector
from workers.orientation.rehearsal import rehearse


def test_the_rehearsal_page_is_read_by_the_text_cue_and_turned_back():
    engine = get_detector(DetectorConfig(text=True))
    if engine.text is None:
        pytest.skip(f"no text cue here: {engine.text_info}")
    report = rehearse(engine)
    assert (report.cue, report.decision, report.rotation_degrees) == ("text", "rotated", 270)
