"""The face-model routes over HTTP: the default model, training jobs, transforms and bad input."""
from __future__ import annotations

import base64
import io
import json
import zipfile

import numpy as np
import pytest

from tests.app.test_jobs_e2e import wait_final
from workers.faces.mesh import read_mesh, write_mesh
from workers.faces.synthetic import generate_dataset


@pytest.fixture(scope="module")
def faces():
    """A few synthetic people: their meshes as OBJ/PLY bytes."""
    return generate_dataset(people=3, seed=11)


def mesh_bytes(dataset, row: int, fmt: str = "obj") -> bytes:
    mesh = dataset.topology
    return write_mesh(type(mesh)(dataset.vertices[row], mesh.face_sizes, mesh.face_indices), fmt)


def row_of(dataset, expression: str, person_index: int = 0) -> int:
    person = sorted(set(dataset.persons.tolist()))[person_index]
    return next(i for i, (p, e) in enumerate(zip(dataset.persons, dataset.expressions))
                if p == person and e == expression)


@pytest.fixture
def client(client_factory):
    return client_factory()


def test_default_model_transforms_an_obj_and_keeps_its_format(client, faces):
    row = row_of(faces, "smile_open")
    data = mesh_bytes(faces, row, "obj")
    r = client.post("/v1/face-models/default/transform", files={"mesh": ("face.obj", data, "text/plain")},
                    data={"params": json.dumps({"impression": "smile_open", "method": "svm", "q": 1.5})})
    assert r.status_code == 200, r.text
    body = r.json()
    assert body["format"] == "obj"
    out = read_mesh(base64.b64decode(body["mesh_base64"]), "out.obj")
    assert out.n_vertices == faces.vertices.shape[1]
    assert np.array_equal(out.face_indices, faces.topology.face_indices)
    assert not np.allclose(out.vertices, faces.vertices[row])
    assert base64.b64decode(body["preview_png_base64"])[:4] == b"\x89PNG"
    assert body["info"]["decision_after"] > body["info"]["decision_before"]
    models = client.get("/v1/face-models").json()["models"]
    assert models[0]["id"] == "default" and models[0]["summary"]["trained"] is True


def test_q_zero_returns_the_input_unchanged(client, faces):
    data = mesh_bytes(faces, row_of(faces, "utter_a"), "ply")
    r = client.post("/v1/face-models/default/transform", files={"mesh": ("face.ply", data, "application/octet-stream")},
                    data={"params": json.dumps({"impression": "utter_a", "q": 0})})
    assert r.status_code == 200, r.text
    out = read_mesh(base64.b64decode(r.json()["mesh_base64"]), "out.ply")
    assert np.allclose(out.vertices, read_mesh(data, "face.ply").vertices)


@pytest.mark.parametrize("files,params,status,fragment", [
    ({"mesh": ("x.obj", b"this is not a mesh at all", "text/plain")}, {"impression": "smile_open"}, 422, "mesh"),
    (None, {"impression": "frown"}, 422, "frown"),
    (None, {"impression": "smile_open", "q": 9}, 422, "q"),
    (None, {"impression": "smile_open", "method": "pca"}, 422, "method"),
])
def test_bad_transform_requests_say_what_was_wrong(client, faces, files, params, status, fragment):
    files = files or {"mesh": ("face.obj", mesh_bytes(faces, 0), "text/plain")}
    r = client.post("/v1/face-models/default/transform", files=files, data={"params": json.dumps(params)})
    assert r.status_code == status, r.text
    assert fragment in r.json()["detail"]


def test_mesh_of_another_topology_and_nan_vertices_are_refused(client, faces):
    tri = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"
    r = client.post("/v1/face-models/default/transform", files={"mesh": ("tri.obj", tri, "text/plain")},
                    data={"params": json.dumps({"impression": "smile_open"})})
    assert r.status_code == 422 and "vert" in r.json()["detail"]
    mesh = faces.topology
    vertices = faces.vertices[0].copy()
    vertices[5, 1] = np.nan
    nan_obj = write_mesh(type(mesh)(vertices, mesh.face_sizes, mesh.face_indices), "obj")
    r = client.post("/v1/face-models/default/transform", files={"mesh": ("nan.obj", nan_obj, "text/plain")},
                    data={"params": json.dumps({"impression": "smile_open"})})
    assert r.status_code == 422
    assert "NaN" in r.json()["detail"] or "finite" in r.json()["detail"], r.json()


def test_training_from_a_dataset_zip_gives_a_usable_model(client):
    from workers.faces.dataset import write_dataset_zip

    dataset = generate_dataset(people=8, seed=3)
    r = client.post("/v1/face-models", files={"dataset": ("faces.zip", write_dataset_zip(dataset, "ply"), "application/zip")})
    assert r.status_code == 202, r.text
    job = wait_final(client, r.json()["id"], timeout=180)
    assert job["state"] == "succeeded", job
    ids = [m["id"] for m in client.get("/v1/face-models").json()["models"]]
    assert job["id"] in ids
    data = mesh_bytes(dataset, row_of(dataset, "smile_closed"), "obj")
    r = client.post(f"/v1/face-models/{job['id']}/transform", files={"mesh": ("f.obj", data, "text/plain")},
                    data={"params": json.dumps({"impression": "smile_closed", "method": "fisher", "q": 1})})
    assert r.status_code == 200, r.text


def test_a_bad_dataset_fails_the_job_with_the_reason(client):
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as z:
        z.writestr("readme.txt", "no manifest here")
    r = client.post("/v1/face-models", files={"dataset": ("bad.zip", buf.getvalue(), "application/zip")})
    job = wait_final(client, r.json()["id"])
    assert job["state"] == "failed" and "manifest" in job["error"]
    r = client.post(f"/v1/face-models/{job['id']}/transform", files={"mesh": ("f.obj", b"v 0 0 0", "text/plain")},
                    data={"params": json.dumps({"impression": "smile_open"})})
    assert r.status_code == 409 and r.json()["error"] == "model_not_ready"
    assert client.post("/v1/face-models/nope/transform", files={"mesh": ("f.obj", b"v 0 0 0", "text/plain")},
                       data={"params": json.dumps({"impression": "smile_open"})}).status_code == 404


@pytest.mark.parametrize("data", [b"null", b"PK\x03\x04 not really a zip", b""])
def test_a_dataset_that_is_no_zip_is_refused_before_a_job_is_made(client, data):
    before = client.get("/v1/jobs", params={"kind": "faces.train"}).json()["jobs"]
    r = client.post("/v1/face-models", files={"dataset": ("faces.zip", data, "application/zip")})
    assert r.status_code == 422 and r.json()["error"] == "invalid_dataset", r.text
    assert "faces.zip" in r.json()["detail"]
    assert client.get("/v1/jobs", params={"kind": "faces.train"}).json()["jobs"] == before


def test_transforms_wait_for_room_in_the_budget_of_synchronous_work(client_factory, faces):
    from workers.common.work import WorkEstimate

    client = client_factory(sync_memory_budget_mb=1.0, sync_wait_seconds=0.2)
    request = {"files": {"mesh": ("face.obj", mesh_bytes(faces, row_of(faces, "smile_open")), "text/plain")},
               "data": {"params": json.dumps({"impression": "smile_open", "q": 1.0})}}
    held = client.app.state.services.sync_work.admit(WorkEstimate(3.0, 2**20))  # another request: the whole budget
    client.portal.call(held.__aenter__)
    try:
        r = client.post("/v1/face-models/default/transform", **request)
        assert r.status_code == 503 and r.json()["error"] == "busy" and int(r.headers["Retry-After"]) >= 1
    finally:
        client.portal.call(held.__aexit__, None, None, None)
    assert client.post("/v1/face-models/default/transform", **request).status_code == 200
