"""Orientation writers: ours against Exiv2 and ExifTool (section orientation_writers).

Every real file of ``$SWEEPCAST_DATA/exif`` and ``orientation/formats`` in a format we write (JPEG, TIFF, PNG), plus
generated TIFFs without the tag, is given a new Orientation by each writer: ours (byte-level IFD0 edit for JPEG/TIFF;
ExifTool for PNG, the product's choice), Exiv2 through pyexiv2 (in memory, ``ImageData``; the bench extra) and
ExifTool (``-stay_open``, and one process per file). Per writer and format: files whose new tag reads back, bytes
changed (differing bytes when the length is kept, else the changed span before plus after) and median milliseconds
per file. A writer of ours is kept only where it wins on bytes or time.

Run: ``python -m benchmarks.orientation_writers [--quick]`` from the repository root.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks._report import md_table, prog, publish
from workers.common.datasets import dataset

def changed_bytes(before: bytes, after: bytes) -> int:
    """Bytes a write changed: differing bytes when the length is kept, else the changed span of both versions
    (everything between the common prefix and the common suffix, before plus after)."""
    if len(before) == len(after):
        return int(np.count_nonzero(np.frombuffer(before, np.uint8) != np.frombuffer(after, np.uint8)))
    n = min(len(before), len(after))
    a, b = np.frombuffer(before[:n], np.uint8), np.frombuffer(after[:n], np.uint8)
    diff = np.nonzero(a != b)[0]
    prefix = int(diff[0]) if diff.size else n
    ra, rb = np.frombuffer(before[::-1][:n], np.uint8), np.frombuffer(after[::-1][:n], np.uint8)
    rdiff = np.nonzero(ra != rb)[0]
    suffix = min(int(rdiff[0]) if rdiff.size else n, n - prefix)
    span = (len(before) - prefix - suffix) + (len(after) - prefix - suffix)
    if len(after) > len(before):  # data appended at the end (a new IFD0): what changed in place, plus it
        kept = np.frombuffer(after[:len(before)], np.uint8) != np.frombuffer(before, np.uint8)
        span = min(span, int(np.count_nonzero(kept)) + len(after) - len(before))
    return span

def writer_inputs(quick: bool = False) -> dict[str, list[tuple[str, bytes]]]:
    """Real files per format we write (jpeg, tiff, png), plus generated TIFFs without an Orientation tag."""
    from harness.photos import gray_pages, tiff

    out: dict[str, list[tuple[str, bytes]]] = {"jpeg": [], "tiff": [], "png": []}
    for folder in (dataset("exif"), dataset("orientation", "formats")):
        if folder is None:
            continue
        for path in sorted(folder.rglob("*")):
            ext = path.suffix.lower()
            fmt = {".jpg": "jpeg", ".jpeg": "jpeg", ".tif": "tiff", ".tiff": "tiff", ".png": "png"}.get(ext)
            if fmt is not None and "bad_exif" not in path.name:
                out[fmt].append((path.name, path.read_bytes()))
    for endian in "<>":
        for pages in (1, 3):
            out["tiff"].append((f"generated_{'LE' if endian == '<' else 'BE'}_{pages}p_untagged.tif",
                                tiff(gray_pages(pages, 300, 400), endian)))
    if quick:
        out = {k: v[::3] for k, v in out.items()}
    return out

def run_writers(quick: bool = False) -> dict:
    """Each writer on each input (see the module docstring); returns per (format, writer) tallies."""
    import shutil
    import subprocess

    from workers.orientation import exiftool
    from workers.orientation.exif import write_orientation
    from workers.orientation.headers import parse_header
    from workers.orientation.metadata import inspect, write_png_orientation, write_tiff_orientation

    def via_exiftool_files(data: bytes, value: int, suffix: str, one_shot: bool) -> bytes:
        with tempfile.TemporaryDirectory() as tmp:
            src, dst = Path(tmp) / f"in{suffix}", Path(tmp) / f"out{suffix}"
            src.write_bytes(data)
            args = ["-q", "-m", "-n", f"-IFD0:Orientation={value}", "-o", str(dst), str(src)]
            if one_shot:
                subprocess.run(["exiftool", *args], check=True, capture_output=True)
            else:
                exiftool.run(args)
            return dst.read_bytes()

    def via_pyexiv2(data: bytes, value: int, suffix: str) -> bytes:
        import pyexiv2

        with pyexiv2.ImageData(data) as img:
            img.modify_exif({"Exif.Image.Orientation": value})
            return img.get_bytes()

    ours = {"jpeg": lambda d, v, s: write_orientation(d, v), "tiff": lambda d, v, s: write_tiff_orientation(d, v),
            "png": lambda d, v, s: write_png_orientation(d, v)}
    writers: dict[str, object] = {"sweepcast": None}
    import importlib.util

    if importlib.util.find_spec("pyexiv2") is not None:
        writers["exiv2 (pyexiv2)"] = via_pyexiv2
    else:
        print("note: pyexiv2 not installed (pip install '.[bench]'): Exiv2 not measured")
    has_exiftool = shutil.which("exiftool") is not None
    if has_exiftool:
        writers["exiftool -stay_open"] = lambda d, v, s: via_exiftool_files(d, v, s, False)
        writers["exiftool per file"] = lambda d, v, s: via_exiftool_files(d, v, s, True)
    inputs = writer_inputs(quick)
    rows = []
    for fmt, files in inputs.items():
        suffix = {"jpeg": ".jpg", "tiff": ".tif", "png": ".png"}[fmt]
        for name, fn in writers.items():
            fn = ours[fmt] if fn is None else fn
            if name == "sweepcast" and fmt == "png" and not has_exiftool:
                continue
            ok, changed, times, failures = 0, [], [], []
            for fname, data in files:
                value = 8 if inspect(data, parse_header(data)).shown() != 8 else 3
                try:
                    fn(data, value, suffix)  # warm-up (exiftool's first call starts Perl)
                    start = time.perf_counter()
                    out = fn(data, value, suffix)
                    times.append((time.perf_counter() - start) * 1000)
                except Exception as exc:  # noqa: BLE001 - a library refusing a file is a result
                    failures.append(f"{fname}: {type(exc).__name__}")
                    continue
                if inspect(out, parse_header(out)).shown() == value:
                    ok += 1
                changed.append(changed_bytes(data, out))
            label = "sweepcast (exiftool)" if name == "sweepcast" and fmt == "png" else name
            rows.append({"format": fmt, "writer": label, "files": len(files), "per_file_bytes_changed": changed, "tag_reads_back": ok,
                         "failed": failures, "bytes_changed_median": float(np.median(changed)) if changed else None,
                         "bytes_changed_max": int(max(changed)) if changed else None,
                         "ms_per_file_median": float(np.median(times)) if times else None})
            print(rows[-1], flush=True)
    return {"rows": rows, "files": {k: [n for n, _ in v] for k, v in inputs.items()}}

def writers_markdown(result: dict) -> str:
    rows = [[r["format"], r["writer"], f"{r['tag_reads_back']}/{r['files']}", len(r["failed"]),
             r["bytes_changed_median"], r["bytes_changed_max"], r["ms_per_file_median"]] for r in result["rows"]]
    return "\n".join([
        "Orientation writers on the real JPEG/TIFF/PNG files of `exif/` and `orientation/formats/` plus generated "
        "untagged TIFFs (LE/BE, 1 and 3 pages, 400x300). Bytes changed: differing bytes when the length is kept, "
        "else the changed span before plus after, or for data appended at the end the bytes changed in place plus "
        "the appended ones (a tag patched in place changes 1-2 bytes). Our PNG writer is ExifTool (with an eXIf "
        "chunk added when a PNG keeps its EXIF only in ImageMagick's text chunk); an eXIf chunk found after IDAT "
        "is moved before it, which the span counts as a change of everything between.", "",
        md_table(["format", "writer", "tag reads back", "failed", "bytes changed (median)", "bytes changed (max)",
                  "ms per file (median)"], rows)])


def main() -> int:
    parser = argparse.ArgumentParser(prog=prog(), description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="a third of the files")
    args = parser.parse_args()
    result = run_writers(args.quick)
    publish("orientation_writers", result, writers_markdown(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
