"""``sweepcast face train|transform|synth`` through an argparse parser built like the real one."""
from __future__ import annotations

import argparse
import json

import numpy as np
import pytest

from workers.faces.cli import register
from tests.faces.meshes import demo_mesh, load_mesh
from workers.faces.mesh import write_mesh
from workers.faces.model import load_face_model


def run(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="sweepcast")
    register(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    return args.func(args)


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    root = tmp_path_factory.mktemp("facecli")
    assert run(["face", "synth", "--people", "3", "--format", "ply", "--out", str(root / "set.zip")]) == 0
    assert run(["face", "train", "--dataset", str(root / "set.zip"), "--out", str(root / "m.npz")]) == 0
    return root


def test_train_from_a_zip_writes_a_model(trained, capsys):
    model = load_face_model(trained / "m.npz")
    assert model.meta["n_faces_trained"] == 21
    assert run(["face", "train", "--people", "4", "--out", str(trained / "s.npz")]) == 0
    assert "smile_open" in capsys.readouterr().out


def test_transform_writes_mesh_preview_and_reports(trained, capsys):
    src = trained / "face.obj"
    src.write_bytes(write_mesh(demo_mesh("smile_open", 0.4), "obj"))
    code = run(["face", "transform", str(src), "--impression", "smile_open", "--method", "svm", "--q", "1.5",
                "--model", str(trained / "m.npz"), "--preview", str(trained / "p.png")])
    assert code == 0
    report = json.loads(capsys.readouterr().out)
    out = trained / "face_smile_open_svm.obj"
    assert report["output"] == str(out) and report["decision_after"] > report["decision_before"]
    assert load_mesh(out).same_topology(load_mesh(src))
    assert not np.allclose(load_mesh(out).vertices, load_mesh(src).vertices)
    assert (trained / "p.png").read_bytes()[:4] == b"\x89PNG"


def test_transform_uses_the_cached_default_model(trained, monkeypatch, capsys):
    monkeypatch.setenv("SWEEPCAST_FACE_MODEL", str(trained / "default.npz"))
    src = trained / "face.ply"
    src.write_bytes(write_mesh(demo_mesh("utter_a", 0.5), "ply"))
    out = trained / "out.ply"
    assert run(["face", "transform", str(src), "--impression", "utter_a", "--out", str(out)]) == 0
    assert (trained / "default.npz").exists() and out.read_bytes()[:3] == b"ply"


@pytest.mark.parametrize("argv,message", [
    (["--impression", "smile_open", "--q", "9"], "q: Input should be less than or equal to 3"),
    (["--impression", "grin"], "unknown impression 'grin'"),
    (["--impression", "smile_open", "--m", "0"], "m: Input should be greater than or equal to 1"),
])
def test_transform_user_errors_exit_2_with_one_line(trained, capsys, argv, message):
    src = trained / "face.obj"
    src.write_bytes(write_mesh(demo_mesh(), "obj"))
    assert run(["face", "transform", str(src), "--model", str(trained / "m.npz"), *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and "\n" not in err and "Traceback" not in err


def test_missing_files_and_bad_meshes_exit_2(trained, capsys):
    assert run(["face", "transform", str(trained / "none.obj"), "--impression", "smile_open"]) == 2
    bad = trained / "bad.obj"
    bad.write_text("not a mesh at all\n")
    assert run(["face", "transform", str(bad), "--impression", "smile_open",
                "--model", str(trained / "m.npz")]) == 2
    assert run(["face", "train", "--dataset", str(trained / "none.zip")]) == 2
    assert run(["face", "train", "--dataset", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "no such mesh file" in err and "no vertices" in err and "not a zip" in err
