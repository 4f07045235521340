"""One base of user-facing engine errors: each carries its code and HTTP status, survives pickling (Ray ships it),
and the service answers it with one handler."""
import pickle

import pytest

from workers.camera import CameraError
from workers.common.errors import InputError
from workers.common.images import EmptyImage, NotAnImage, TooManyPixels
from workers.common.jobctx import JobInputError
from workers.common.safezip import ZipInputError
from workers.depth.errors import DepthInputError, NotAVideo
from workers.faces.errors import DatasetError, FaceInputError
from workers.orientation import errors as orientation
from workers.orientation.exiftool import ExifToolError, ExifToolUnavailable
from workers.streaming.recording import RecordingError
from workers.streaming.session import ViewError
from workers.sweep.rig import RigError


@pytest.mark.parametrize("error, code, status", [
    (InputError("x"), "bad_input", 422),
    (InputError("x", "mine", 409), "mine", 409),
    (NotAnImage("x"), "not_an_image", 415),
    (TooManyPixels("x"), "too_many_pixels", 413),
    (EmptyImage("x"), "empty_file", 400),
    (orientation.TruncatedImage("x"), "truncated_image", 422),
    (orientation.UnwritableExif("x"), "unwritable_exif", 422),
    (ExifToolError("x"), "unwritable_metadata", 422),
    (ExifToolUnavailable("x"), "metadata_tool_unavailable", 503),
    (DepthInputError("x"), "bad_depth_input", 400),
    (NotAVideo("x"), "not_a_video", 415),
    (FaceInputError("x"), "bad_face_input", 422),
    (DatasetError("x"), "invalid_dataset", 422),
    (ZipInputError("x"), "invalid_archive", 422),
    (RecordingError("x"), "invalid_recording", 422),
])
def test_each_error_carries_its_code_and_status_and_survives_pickling(error, code, status):
    assert isinstance(error, (InputError, ValueError, JobInputError))
    back = pickle.loads(pickle.dumps(error))
    assert (type(back), str(back), back.code, back.status) == (type(error), "x", code, status)


@pytest.mark.parametrize("error, code", [
    (RigError("cam0", "K", "is not a matrix"), "invalid_rig"),
    (CameraError("cam0", "R", "is not orthonormal"), "invalid_camera"),
    (ViewError("too_large", "output 9x9 is over the limit"), "too_large"),
])
def test_calibration_and_view_errors_are_input_errors_that_keep_their_fields(error, code):
    back = pickle.loads(pickle.dumps(error))
    assert isinstance(back, InputError) and (back.code, back.status, str(back)) == (code, 422, str(error))
    assert vars(back) == vars(error)


def test_an_error_said_about_a_file_keeps_its_class_code_and_status():
    error = TooManyPixels("the image is 9x9 = 81 pixels; the limit is 10 pixels")
    named = error.about("photo.jpg")
    assert type(named) is TooManyPixels and (named.code, named.status) == ("too_many_pixels", 413)
    assert str(named) == "photo.jpg: the image is 9x9 = 81 pixels; the limit is 10 pixels"
    assert error.about(None) is error and str(error).startswith("the image")
    rig = RigError(None, "cameras", "every camera stands at the same place").about("rig.json")
    assert rig.problem == "every camera stands at the same place" and str(rig).startswith("rig.json: rig: ")


def test_the_service_answers_an_engine_error_with_its_status_and_code():
    from fastapi import FastAPI
    from fastapi.testclient import TestClient

    from app.errors import install_error_handlers

    app = FastAPI()
    install_error_handlers(app)

    @app.get("/boom")
    def boom() -> None:
        raise NotAnImage("not a readable image").about("depth.png")

    r = TestClient(app).get("/boom")
    assert r.status_code == 415 and r.json() == {"error": "not_an_image", "detail": "depth.png: not a readable image"}
