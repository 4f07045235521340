"""A schemathesis check for the contract fuzz (tests/app/test_contract_fuzz.py), loaded with
``SCHEMATHESIS_HOOKS=tests/app/fuzz_cross_key.py``: the fuzz runs with one user key, and whatever that key could
read (a resource's own GET answered 2xx, or the Location of what it just created), a second user key
(``SWEEPCAST_FUZZ_OTHER_KEY``) must get 404 for, as for something that does not exist."""
from __future__ import annotations

import os
from urllib.parse import urljoin

import requests
import schemathesis


@schemathesis.check
def no_cross_key_access(ctx, response, case) -> bool | None:
    other = os.environ.get("SWEEPCAST_FUZZ_OTHER_KEY")
    if not other or not 200 <= response.status_code < 300:
        return None
    urls = []
    if case.method.upper() == "GET" and "{" in case.operation.path:
        urls.append(response.request.url)
    for location in response.headers.get("location", []):
        urls.append(urljoin(response.request.url, location))
    for url in urls:
        seen = requests.get(url, headers={"Authorization": f"Bearer {other}"}, timeout=30)
        if seen.status_code != 404:
            raise AssertionError(f"another user key got {seen.status_code} (not 404) for GET {url}, which only "
                                 f"the key that made it may read")
    return None
