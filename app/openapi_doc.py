"""The OpenAPI document as committed in ``openapi/openapi.json``."""
from __future__ import annotations

import json

from app.main import create_app
from app.settings import Settings


def render_openapi() -> str:
    """The app's schema, serialised stably (sorted keys, 2-space indent, trailing newline)."""
    app = create_app(Settings(api_keys=[]))
    return json.dumps(app.openapi(), indent=2, sort_keys=True) + "\n"
