"""One base of user-facing engine errors: each carries its code and HTTP status, survives pickling (Ray ships it),
and the service answers it with one handler."""
import pickle

import pytest

from workers.common.errors import InputError
from workers.common.images import NotAnImage, TooManyPixels
from workers.common.jobctx import JobInputError
from workers.depth.errors import DepthInputError
from workers.faces.errors import FaceInputError
from workers.orientation import errors as orientation
from workers.streaming.recording import RecordingError


@pytest.mark.parametrize("error, code, status", [
    (InputError("x"), "bad_input", 422),
    (InputError("x", "mine", 409), "mine", 409),
    (NotAnImage("x"), "not_an_image", 415),
    (TooManyPixels("x"), "too_many_pixels", 413),
    (orientation.EmptyFile("x"), "empty_file", 400),
    (orientation.TruncatedImage("x"), "truncated_image", 422),
    (orientation.UnwritableExif("x"), "unwritable_exif", 422),
    (DepthInputError("x"), "bad_depth_input", 400),
    (DepthInputError("x", "not_a_video"), "not_a_video", 415),
    (FaceInputError("x"), "bad_face_input", 422),
    (RecordingError("x"), "invalid_recording", 422),
])
def test_each_error_carries_its_code_and_status_and_survives_pickling(error, code, status):
    assert isinstance(error, (InputError, ValueError, JobInputError))
    back = pickle.loads(pickle.dumps(error))
    assert (type(back), str(back), back.code, back.status) == (type(error), "x", code, status)


def test_the_service_answers_an_engine_error_with_its_status_and_code():
    from fastapi import FastAPI
    from fastapi.testclient import TestClient

    from app.errors import install_error_handlers

    app = FastAPI()
    install_error_handlers(app)

    @app.get("/boom")
    def boom() -> None:
        raise DepthInputError("depth.png is not an image", "not_an_image")

    r = TestClient(app).get("/boom")
    assert r.status_code == 415 and r.json() == {"error": "not_an_image", "detail": "depth.png is not an image"}
