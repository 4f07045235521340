"""A JobContext over a temporary folder, for running job functions in tests."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from workers.fanout import FanOut, InProcess
from workers.settings import WorkerSettings, worker_settings
from workers.workarea import InputRef, WorkArea


@dataclass
class FakeContext:
    root: Path
    params: dict[str, Any]
    files: dict[str, bytes]
    job_id: str = "test"
    kind: str = "test"
    input_meta: dict[str, dict[str, Any]] = field(default_factory=dict)
    progress_calls: list[tuple[float, str]] = field(default_factory=list)

    def __post_init__(self) -> None:
        (self.root / "in").mkdir(parents=True, exist_ok=True)
        (self.root / "out").mkdir(parents=True, exist_ok=True)
        for name, data in self.files.items():
            (self.root / "in" / name).write_bytes(data)

    @property
    def settings(self) -> WorkerSettings:
        """Read from the environment at each use, as a worker reads it once per attempt (tests set variables)."""
        return worker_settings()

    @property
    def inputs(self) -> dict[str, str]:
        return {name: f"blob/{name}" for name in self.files}

    def input_path(self, name: str) -> Path:
        if name not in self.files:
            raise KeyError(name)
        return self.root / "in" / name

    def read_input(self, name: str) -> bytes:
        return self.input_path(name).read_bytes()

    def result_path(self, name: str) -> Path:
        return self.root / "out" / name

    def write_result(self, name: str, data: bytes) -> None:
        self.result_path(name).write_bytes(data)

    def progress(self, fraction: float, stage: str, **counts: Any) -> None:
        self.progress_calls.append((fraction, stage))

    def fanout(self) -> FanOut:
        return InProcess()

    def work_area(self) -> WorkArea:
        """Kept in the test's folder across runs of the job (an attempt after a failure finds it)."""
        return WorkArea.in_folder(self.root / "store")

    def input_ref(self, name: str) -> InputRef:
        return InputRef(name, path=str(self.input_path(name)))
