"""One orientation engine over a list of trials, in its own process: ``python benchmarks/_engine_worker.py TRIALS OUT``.

Run by :mod:`benchmarks._orientation_cost` with ``PYTHONPATH`` naming the checkout whose engine is measured (this
one, or a ``git worktree`` of an earlier release), so both engines meet the same photos in the same way. It uses only
what every release since issue 33 offers: ``get_detector(DetectorConfig(yunet_model=..., text=True))`` and
``analyze(data, engine)``. ``TRIALS`` is a JSON list of {"id", "path"} (JPEG files); ``OUT`` gets one JSON line per
trial: the rotation decided, the cue, the text cue's status and lines (where the engine reports them) and the CPU
seconds the process spent on it (OpenCV and onnxruntime set to one core; all threads counted), decode included.
"""
from __future__ import annotations

import json
import sys
import time
from pathlib import Path


def main(trials_path: str, out_path: str, yunet: str) -> int:
    import cv2

    from workers.orientation.detect import DetectorConfig, get_detector
    from workers.orientation.orient import analyze

    cv2.setNumThreads(1)
    engine = get_detector(DetectorConfig(yunet_model=Path(yunet) if yunet else None, text=True))
    trials = json.loads(Path(trials_path).read_text())
    warm = Path(trials[0]["path"]).read_bytes()
    analyze(warm, engine)  # models and caches loaded before the first measured photo
    with open(out_path, "w") as out:
        for trial in trials:
            data = Path(trial["path"]).read_bytes()
            start = time.process_time()
            report = analyze(data, engine)
            cpu = time.process_time() - start
            text = report.text
            out.write(json.dumps({"id": trial["id"], "rotation": report.rotation_degrees, "cue": report.cue,
                                  "text_status": text.status, "text_lines": getattr(text, "lines", None),
                                  "text_zoomed": getattr(text, "zoomed", None),
                                  "text_how": _how(text), "cpu_s": round(cpu, 5)}) + "\n")
            out.flush()
    return 0


def _how(text) -> str | None:
    readings = getattr(text, "readings", None)
    if not readings or text.rotation_degrees is None:
        return None
    return next((r.reader for r in readings if r.rotation_degrees == text.rotation_degrees and r.real_words), None)


if __name__ == "__main__":
    raise SystemExit(main(*sys.argv[1:4]))
