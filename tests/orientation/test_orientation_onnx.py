"""The face detector on onnxruntime: a model's declared input size freed without changing the model, and YuNet's
faces as OpenCV's own YuNet finds them (when the model is there)."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import onnxruntime
import pytest

from workers.common.datasets import data_root, dataset
from workers.orientation.detect import DetectorConfig, get_detector
from workers.orientation.faces import YuNetFaceFinder
from workers.orientation.onnxshape import free_input_size, grey_input
from workers.orientation.textlines import model_path

YUNET = data_root().parent / "models" / "yunet" / "face_detection_yunet_2023mar.onnx"
FACES = dataset("faces", "dev")


def _session(model: bytes) -> onnxruntime.InferenceSession:
    return onnxruntime.InferenceSession(model, providers=["CPUExecutionProvider"])


def test_freeing_the_input_size_keeps_what_the_model_computes():
    original = model_path().read_bytes()  # the gate's text detector, shipped with rapidocr
    freed = free_input_size(original, {2: "rows", 3: "columns"})
    x = np.random.default_rng(1).uniform(-1, 1, (1, 3, 96, 160)).astype(np.float32)
    before, after = _session(original), _session(freed)
    want = before.run(None, {before.get_inputs()[0].name: x})[0]
    got = after.run(None, {after.get_inputs()[0].name: x})[0]
    np.testing.assert_array_equal(got, want)
    assert after.get_inputs()[0].shape[2:] == ["rows", "columns"]


def test_a_grey_input_computes_what_the_colour_model_computes_on_a_grey_image():
    original = model_path().read_bytes()  # a colour model: three channels into an ungrouped first convolution
    grey = grey_input(original)
    page = np.random.default_rng(2).uniform(-1, 1, (1, 1, 96, 160)).astype(np.float32)
    colour, one = _session(original), _session(grey)
    want = colour.run(None, {colour.get_inputs()[0].name: np.repeat(page, 3, axis=1)})[0]
    got = one.run(None, {one.get_inputs()[0].name: page})[0]
    np.testing.assert_allclose(got, want, atol=1e-5)
    assert one.get_inputs()[0].shape[1] == 1


def test_the_text_gate_reads_one_grey_channel_and_finds_what_the_colour_model_finds():
    from workers.orientation.textlines import LineDetector, network_input

    page = np.full((240, 320), 235, np.uint8)
    for row in range(40, 200, 30):
        cv2.putText(page, "orientation of a page", (16, row), cv2.FONT_HERSHEY_SIMPLEX, 0.7, 20, 2)
    gate = LineDetector(precision="float")
    assert gate._session.get_inputs()[0].shape[1] == 1
    colour = _session(model_path().read_bytes())
    x, (nh, nw) = network_input(page, 320)
    want = colour.run(None, {colour.get_inputs()[0].name: x})[0][0, 0, :nh, :nw]
    got, _ = gate.probability(page, 320)
    np.testing.assert_allclose(got, want, atol=1e-4)
    assert float(want.max()) > 0.9  # the page's lines are there to find


@pytest.mark.parametrize("reader, group", [("Relu", None), ("Conv", 3)])
def test_a_model_whose_input_is_not_read_by_a_plain_convolution_is_not_made_grey(reader: str, group: int | None):
    from workers.orientation.onnxshape import _model_class

    model = _model_class()()
    image = model.graph.input.add()
    image.name = "image"
    for length in (1, 3, 8, 8):
        image.type.tensor_type.shape.dim.add().dim_value = length
    node = model.graph.node.add(op_type=reader, input=["image", "w"], output=["out"])
    if group is not None:
        node.attribute.add(name="group", i=group)
    model.graph.initializer.add(name="w", dims=[3, 1, 3, 3], data_type=1, raw_data=bytes(4 * 27))
    with pytest.raises(ValueError, match="not read by ungrouped float convolutions"):
        grey_input(model.SerializeToString())


@pytest.mark.parametrize("junk", [b"", b"not a model at all", b"\x08\x07\x12\x04junk"])
def test_a_file_that_is_not_an_onnx_model_is_refused(junk: bytes):
    with pytest.raises(ValueError):
        free_input_size(junk, {2: "rows", 3: "columns"})


def test_a_damaged_yunet_model_is_refused_when_the_detector_is_built(tmp_path: Path):
    damaged = tmp_path / "face_detection_yunet_2023mar.onnx"
    damaged.write_bytes(model_path().read_bytes()[:5000])
    with pytest.raises(FileNotFoundError, match="cannot load the YuNet model"):
        YuNetFaceFinder(damaged)
    from workers.orientation.onnxshape import _model_class

    empty = _model_class()()  # an ONNX model with a 4-axis input and no graph to run
    axes = empty.graph.input.add().type.tensor_type.shape.dim
    for _ in range(4):
        axes.add().dim_value = 1
    hollow = tmp_path / "hollow.onnx"
    hollow.write_bytes(empty.SerializeToString())
    with pytest.raises(FileNotFoundError, match="cannot load the YuNet model"):
        YuNetFaceFinder(hollow)
    not_yunet = tmp_path / "other.onnx"
    not_yunet.write_bytes(model_path().read_bytes())  # a valid ONNX model, but not a face detector
    with pytest.raises(FileNotFoundError, match="not YuNet's"):
        get_detector(DetectorConfig(method="yunet", yunet_model=not_yunet, text=False))


@pytest.mark.data
@pytest.mark.skipif(FACES is None or not YUNET.is_file(), reason="needs $SWEEPCAST_DATA/faces/dev and the YuNet model")
def test_yunet_on_onnxruntime_finds_the_faces_opencv_finds_at_any_size():
    finder = YuNetFaceFinder(YUNET)
    photos = sorted(p for p in FACES.rglob("*") if p.suffix.lower() in (".jpg", ".jpeg"))[:8]
    compared = 0
    for path in photos:
        gray = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        for long_side in (320, 500):  # neither is the 640 x 640 the model declares
            s = long_side / max(gray.shape)
            small = cv2.resize(gray, None, fx=s, fy=s, interpolation=cv2.INTER_AREA)
            opencv = cv2.FaceDetectorYN.create(str(YUNET), "", (small.shape[1], small.shape[0]), 0.5, 0.3, 5000)
            _, rows = opencv.detect(cv2.cvtColor(small, cv2.COLOR_GRAY2BGR))
            want = np.empty((0, 5)) if rows is None else rows[:, [0, 1, 2, 3, 14]]
            boxes, scores = finder.detect(small)
            got = np.c_[boxes, scores]
            assert len(got) == len(want), path.name
            np.testing.assert_allclose(got[np.lexsort(got.T)], want[np.lexsort(want.T)], atol=1e-3)
            compared += len(got)
    assert compared > 0
