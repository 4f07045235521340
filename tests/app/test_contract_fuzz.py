"""The OpenAPI contract is true: schemathesis fuzzes every operation of the live service against it.

The service runs as `sweepcast serve` on loopback (uvicorn, a local Ray, SQLite, a file blob store)
with two user keys: the fuzz runs with the first, so every `/v1` operation is also checked to refuse requests
without it, and whatever the first key can read, the second must get 404 for (the stateful phase's sequences
create, read and delete jobs; fuzz_cross_key.py holds that check). The
run's settings (seed, examples per operation, phases, checks and the few per-operation exceptions,
each with its reason) are in contract_fuzz.toml next to this file; a failure prints schemathesis's
report: each failing case with a curl command that reproduces it.
"""
from __future__ import annotations

import json
import os
import secrets
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from harness.servers import ServedApp, serve_app

CONFIG = Path(__file__).with_name("contract_fuzz.toml")
RUN_TIMEOUT_S = 240  # ~30 s here, ~1-2 min on 2 busy cores; far past that, something hangs


HOOKS = Path(__file__).with_name("fuzz_cross_key.py")
NO_LIMITS = ["--quota", "uploads_per_minute=1000000", "--quota", "active_jobs=1000000"]


def _user_key(data_dir: Path, name: str) -> str:
    """A managed user key made with the CLI (in the service's database, before it starts); its secret."""
    done = subprocess.run([sys.executable, "-m", "app", "keys", "create", "--name", name, *NO_LIMITS,
                           "--data-dir", str(data_dir)], capture_output=True, text=True, check=True,
                          env={**os.environ, "SWEEPCAST_DATABASE_URL": ""})
    return done.stdout.strip().splitlines()[-1]


@pytest.fixture(scope="module")
def fuzz_folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("contract-fuzz")


@pytest.fixture(scope="module")
def fuzz_keys(fuzz_folder: Path) -> tuple[str, str]:
    return _user_key(fuzz_folder / "data", "fuzz"), _user_key(fuzz_folder / "data", "other")


@pytest.fixture(scope="module")
def service(fuzz_folder: Path, fuzz_keys: tuple[str, str]) -> ServedApp:
    folder = fuzz_folder
    env = {
        "SWEEPCAST_DATA_DIR": str(folder / "data"),
        "SWEEPCAST_API_KEYS": secrets.token_urlsafe(16),  # an admin key nobody uses: the managed keys are users
        "SWEEPCAST_DEMO_RIG": "false",  # rendering its recording would take a core for a minute
        "SWEEPCAST_RAY_NUM_CPUS": "1",
        # Jobs are accepted (202, a row, stored inputs) but never run: no Ray node offers this resource,
        # so each fails after half a second. Their engines have their own tests; running the fuzzer's
        # random inputs would only take the cores the fuzz run needs.
        "SWEEPCAST_JOB_RESOURCES": '{"contract_fuzz_no_worker": 1}',
        "SWEEPCAST_JOB_UNSCHEDULABLE_SECONDS": "0.5",
        "SWEEPCAST_DATABASE_URL": None, "SWEEPCAST_STORAGE_URL": None, "SWEEPCAST_RAY_ADDRESS": None,
    }
    with serve_app(env, log=folder / "server.log") as app:
        yield app


def run_schemathesis(base: str, key: str, reports: Path,
                     other_key: str | None = None) -> tuple[subprocess.CompletedProcess[str], dict[str, Any]]:
    """One schemathesis run over the live document; its console output and its JSON report."""
    command = [sys.executable, "-m", "schemathesis.cli", "--config-file", str(CONFIG), "--no-color", "run",
               f"{base}/openapi.json", "--report", "json", "--report-dir", str(reports)]
    env = {**os.environ, "SWEEPCAST_FUZZ_KEY": key, "COLUMNS": "120", "SCHEMATHESIS_HOOKS": str(HOOKS),
           "SWEEPCAST_FUZZ_OTHER_KEY": other_key or ""}
    try:
        # cwd: Hypothesis keeps a cache folder in the working directory; not in the checkout.
        done = subprocess.run(command, env=env, cwd=reports.parent, capture_output=True, text=True,
                              timeout=RUN_TIMEOUT_S)
    except subprocess.TimeoutExpired as exc:
        pytest.fail(f"the fuzz run took over {RUN_TIMEOUT_S} s; its output so far:\n{_text(exc.stdout)[-6000:]}")
    found = sorted(reports.glob("*.json"))
    assert found, f"schemathesis wrote no report (exit {done.returncode}):\n{done.stdout[-6000:]}\n{done.stderr[-3000:]}"
    return done, json.loads(found[-1].read_text())


def _text(output: str | bytes | None) -> str:
    return output.decode(errors="replace") if isinstance(output, bytes) else output or ""


def summary(report: dict[str, Any]) -> str:
    cases = report["test_cases"]
    lines = [f"{cases['generated']} cases, {cases['with_failures']} with failures, "
             f"{cases['unique_failures']} unique failures, {cases['errored']} errored"]
    lines += [f"  {f['code']} {f['title']}: {f['count']} ({', '.join(f['operations'])})" for f in report["failures"]]
    lines += [f"  error: {e}" for e in report["errors"]]
    return "\n".join(lines)


@pytest.mark.slow
@pytest.mark.timeout(RUN_TIMEOUT_S + 240)
def test_every_operation_keeps_the_documented_contract(service: ServedApp, fuzz_keys: tuple[str, str],
                                                       tmp_path: Path) -> None:
    done, report = run_schemathesis(service.base, fuzz_keys[0], tmp_path / "reports", other_key=fuzz_keys[1])
    print(summary(report))  # shown with -rP, and in the failure message below
    operations = report["operations"]
    problems = report["failures"] or report["errors"] or done.returncode != 0
    assert not problems, (
        f"{summary(report)}\n\n--- schemathesis ---\n{done.stdout[-20000:]}\n{done.stderr[-3000:]}"
        f"\n--- server log ---\n{service.log_tail(6000)}")
    assert report["stop_reason"] == "completed" and report["complete"], report["stop_reason"]
    # every operation but DELETE /v1/keys/me (it would revoke the run's own key; contract_fuzz.toml)
    assert operations["tested"] == operations["selected"] == operations["total"] - 1 >= 26, operations
    assert report["test_cases"]["generated"] > 1000, report["test_cases"]  # the run really fuzzed


# --- the document and the fixes the fuzz run found, checked directly (fast, no server) ---------------
def _doc() -> dict[str, Any]:
    from app.main import render_openapi

    return json.loads(render_openapi())


def test_errors_are_documented_with_the_body_the_service_sends() -> None:
    doc = _doc()
    schemas = doc["components"]["schemas"]
    assert "HTTPValidationError" not in schemas and "ValidationError" not in schemas
    assert schemas["ValidationErrorResponse"]["properties"]["detail"] == {
        "type": "string", "description": "what was wrong, for a person"}
    for path, item in doc["paths"].items():
        for method, op in item.items():
            for status, response in op["responses"].items():
                if status.startswith("4"):
                    ref = response["content"]["application/json"]["schema"]["$ref"]
                    expected = "ValidationErrorResponse" if status == "422" else "Error"
                    assert ref == f"#/components/schemas/{expected}", (method, path, status)
            if path.startswith("/v1/"):
                assert "401" in op["responses"] and op["security"] == [{"bearerAuth": []}], (method, path)
    results = doc["paths"]["/v1/jobs/{job_id}/results/{name}"]["get"]["responses"]
    assert {"401", "404", "409", "410", "422"} <= set(results)
    assert {"400", "413", "415", "422"} <= set(doc["paths"]["/v1/photos/orientation"]["post"]["responses"])


def test_params_form_fields_are_documented_as_json_objects() -> None:
    doc = _doc()
    media = doc["paths"]["/v1/depth/filter"]["post"]["requestBody"]["content"]["multipart/form-data"]
    assert media["encoding"]["params"] == {"contentType": "application/json"}
    body = doc["components"]["schemas"][media["schema"]["$ref"].rsplit("/", 1)[-1]]
    assert body["properties"]["params"]["$ref"] == "#/components/schemas/DepthFilterParams"
    assert body["properties"]["texture"] == {  # optional file: left out, never null
        "contentMediaType": "application/octet-stream", "type": "string", "title": "Texture",
        "description": "texture at the output size (guided methods: wmf)"}
    assert doc["components"]["schemas"]["DepthFilterParams"]["additionalProperties"] is False


def test_a_params_field_without_a_documented_model_fails_rendering() -> None:
    from fastapi import FastAPI

    from app.main import create_app
    from app.openapi_doc import ContractError, document_contract
    from app.settings import Settings

    doc = FastAPI.openapi(create_app(Settings(api_keys=[])))  # FastAPI's own document, before corrections
    doc["components"]["schemas"]["B"] = {"type": "object", "properties": {"params": {"type": "string"}}}
    doc["paths"]["/v1/new"] = {"post": {
        "requestBody": {"content": {"multipart/form-data": {"schema": {"$ref": "#/components/schemas/B"}}}},
        "responses": {"200": {"description": "ok"}}}}
    with pytest.raises(ContractError, match="POST /v1/new has a 'params' form field without its model"):
        document_contract(doc)


def test_405_allows_every_method_of_the_path() -> None:
    from fastapi.testclient import TestClient

    from app.main import create_app
    from app.settings import Settings

    client = TestClient(create_app(Settings(api_keys=[], demo_rig=False, fetch_models=False)))  # no lifespan
    r = client.request("OPTIONS", "/v1/jobs/abc")
    # GET and DELETE are two routes; Starlette's own 405 named only the first one.
    assert r.status_code == 405 and r.headers["allow"] == "GET, DELETE"
    assert r.json() == {"error": "method_not_allowed", "detail": "Method Not Allowed"}
    assert client.put("/v1/rigs").headers["allow"] == "GET, POST"


def test_params_json_is_read_strictly() -> None:
    from app.errors import ApiError
    from app.params_form import parse_params
    from workers.faces.job import FaceTrainParams

    assert parse_params(FaceTrainParams, '{"variance": 1, "source": "synthetic"}').variance == 1.0
    for text in ('{"n": true}', '{"people": "40"}', '{"balanced": 0}'):
        with pytest.raises(ApiError) as refused:  # lax pydantic took these (true as 1, "40" as 40)
            parse_params(FaceTrainParams, text)
        assert refused.value.status_code == 422
