"""Cross-key probes, shared by the isolation tests (tests/app/test_tenants.py) and the benchmark
(python -m benchmarks.robustness --only tenants): every operation of the service's own OpenAPI document that names a resource,
called with another key's resource ids, in a shape the operation accepts (so that its answer is about the owner,
never about the body)."""
from __future__ import annotations

import re
from typing import Any, Iterator

import httpx

PATH_PARAMS_NEEDED = ("job_id", "model_id", "rig_id", "recording_id", "index", "name", "frame", "key_id")
OWN_NOT_FOUND = ("result_not_found", "frame_not_found", "photo_not_found", "no_background")
"""404s the owner may get for its own resource (a name, frame or photo the resource lacks, no live model yet)."""
SOCKETS = ("/v1/jobs/{job_id}/events", "/v1/rigs/{rig_id}/view", "/v1/rigs/{rig_id}/view?render=browser",
           "/v1/rigs/{rig_id}/live")


def bearer(secret: str) -> dict[str, str]:
    return {"Authorization": f"Bearer {secret}"}


def operations(doc: dict[str, Any]) -> list[tuple[str, str]]:
    """(method, path) of every ``/v1`` operation in the document."""
    return [(m, p) for p, item in doc["paths"].items() for m in item if p.startswith("/v1/")]


def resource_operations(doc: dict[str, Any]) -> Iterator[tuple[str, str]]:
    """The operations that name a resource in their path (keys' routes are admin-only: checked apart)."""
    for method, path in operations(doc):
        if re.search(r"{\w+}", path) and not path.startswith("/v1/keys"):
            yield method, path


def request_for(method: str, path: str, ids: dict[str, str]) -> dict[str, Any]:
    """Keyword arguments of an httpx request that ``method path`` accepts in shape."""
    if method == "post" and path.endswith("/transform"):
        return {"files": {"mesh": ("f.obj", b"v 0 0 0\n", "text/plain")},
                "data": {"params": '{"impression": "smile_open"}'}}
    if method == "post" and path.endswith("/recordings"):
        return {"files": {"archive": ("take.zip", b"PK\x05\x06" + bytes(18), "application/zip")}}
    if method == "post" and path.endswith("/renders"):
        return {"json": {"recording_id": ids["recording_id"], "orbit": {}, "frames": 2, "width": 64, "height": 48,
                         "planes": 8}}
    if method == "post" and path.endswith("/review/{index}"):
        return {"json": {"rotation_degrees": None, "reviewer": "another key"}}
    return {}


def probe(client: httpx.Client, doc: dict[str, Any], ids: dict[str, str], other: str,
          owner: str | None = None) -> list[dict[str, Any]]:
    """Every resource operation with ``ids`` (the owner's) and the ``other`` key's secret: one row each with its
    status and error code (and, with ``owner``'s secret, the owner's own status, except for deletions, which
    would remove what the next operations need)."""
    rows = []
    for method, path in resource_operations(doc):
        missing = [p for p in re.findall(r"{(\w+)}", path) if p not in ids]
        if missing:
            raise KeyError(f"{method.upper()} {path}: give its parameters {missing} a value")
        url = path.format(**ids)
        kwargs = request_for(method, path, ids)
        r = client.request(method.upper(), url, headers=bearer(other), **kwargs)
        row = {"operation": f"{method.upper()} {path}", "status": r.status_code,
               "error": r.json().get("error") if r.headers.get("content-type", "").startswith("application/json")
               else None}
        if owner is not None and method != "delete":
            own = client.request(method.upper(), url, headers=bearer(owner), **kwargs)
            row["owner_status"] = own.status_code
            row["owner_error"] = own.json().get("error") if own.status_code >= 400 else None
        rows.append(row)
    return rows


def refused_as_missing(row: dict[str, Any]) -> bool:
    """The other key got the 404 of a resource that does not exist, and the owner did not."""
    owner_ok = "owner_status" not in row or row["owner_status"] != 404 or row["owner_error"] in OWN_NOT_FOUND
    return row["status"] == 404 and (row["error"] or "").endswith("not_found") and owner_ok
