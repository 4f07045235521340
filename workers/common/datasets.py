"""Where the real benchmark data lives: ``$SWEEPCAST_DATA`` (default ``../shared/data``)."""
from __future__ import annotations

import os
from pathlib import Path


def data_root() -> Path:
    """The benchmark data folder. It may not exist: callers skip with a message then."""
    env = os.environ.get("SWEEPCAST_DATA")
    if env:
        return Path(env)
    return Path(__file__).resolve().parents[2].parent / "shared" / "data"


def dataset(*parts: str) -> Path | None:
    """``data_root()/parts...`` when it exists, else None."""
    path = data_root().joinpath(*parts)
    return path if path.exists() else None
