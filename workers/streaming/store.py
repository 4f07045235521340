"""Rigs, recordings and live frames in the blob store (keys generated here, never from user text).

    rigs/<rig>/rig.json                     the calibration (our rig JSON)
    rigs/<rig>/meta.json                    {"id", "name", "created_at", "cameras", "format", "demo"}
    rigs/<rig>/recordings/<recording>.json  {"id", "rig_id", "name", "job_id", "kind", "created_at"}
    rigs/<rig>/live/frames/<cam>.jpg        the latest live frame set, as received
    rigs/<rig>/live/backgrounds/<cam>.png   the live background model
    rigs/<rig>/live/state.json              {"seq", "stale", "saved_at"}: which live set the frames are (stale: cameras left out)
    jobs/<job>/results/frames.zip           a recording's archive: the result of its import job

A recording's id is the id of the job that imports it (or builds the demo).
"""
from __future__ import annotations

import datetime as dt
import json
import re
import uuid
from typing import Any, Sequence

import numpy as np

from workers.common.images import encode_png
from workers.runtime import results_prefix
from workers.storage import BlobNotFound, BlobStore
from workers.sweep.rig import Rig
from workers.sweep.rig_io import rig_from_dict, rig_to_dict


RIGS = "rigs"
ARCHIVE_NAME = "frames.zip"
_ID = re.compile(r"^[A-Za-z0-9][A-Za-z0-9-]{0,63}$")


def valid_id(text: str) -> bool:
    """Whether ``text`` can be a rig or recording id (anything else cannot name a stored one)."""
    return bool(_ID.match(text))


def new_rig_id() -> str:
    return uuid.uuid4().hex


def now_iso() -> str:
    return dt.datetime.now(dt.timezone.utc).isoformat()


def rig_prefix(rig_id: str) -> str:
    return f"{RIGS}/{rig_id}"


def archive_key(recording_id: str) -> str:
    """Blob key of a recording's archive (its import job's result)."""
    return f"{results_prefix(recording_id)}/{ARCHIVE_NAME}"


def _json(store: BlobStore, key: str) -> dict[str, Any] | None:
    try:
        return json.loads(store.read(key))
    except BlobNotFound:
        return None


def _put_json(store: BlobStore, key: str, value: dict[str, Any]) -> None:
    store.put(key, json.dumps(value, indent=1).encode())


# --- rigs -----------------------------------------------------------------------------------------
def save_rig(store: BlobStore, rig_id: str, rig: Rig, meta: dict[str, Any]) -> dict[str, Any]:
    """Store the calibration, then the metadata (its presence marks a complete rig); return the meta."""
    meta = {"id": rig_id, "created_at": now_iso(), "cameras": len(rig), **meta}
    _put_json(store, f"{rig_prefix(rig_id)}/rig.json", rig_to_dict(rig))
    _put_json(store, f"{rig_prefix(rig_id)}/meta.json", meta)
    return meta


def rig_key(rig_id: str) -> str:
    return f"{rig_prefix(rig_id)}/rig.json"


def load_rig(store: BlobStore, rig_id: str) -> Rig:
    """The stored rig; BlobNotFound when there is none."""
    d = _json(store, rig_key(rig_id))
    if d is None:
        raise BlobNotFound(rig_key(rig_id))
    return rig_from_dict(d)


def load_rig_meta(store: BlobStore, rig_id: str) -> dict[str, Any] | None:
    if not valid_id(rig_id):
        return None
    return _json(store, f"{rig_prefix(rig_id)}/meta.json")


def list_rig_metas(store: BlobStore) -> list[dict[str, Any]]:
    """Every complete rig's metadata, newest first."""
    metas = []
    for key in store.list(RIGS):
        parts = key.split("/")
        if len(parts) == 3 and parts[2] == "meta.json":
            meta = _json(store, key)
            if meta is not None:
                metas.append(meta)
    return sorted(metas, key=lambda m: m.get("created_at", ""), reverse=True)


def delete_rig(store: BlobStore, rig_id: str) -> None:
    """Delete the metadata first (the rig disappears at once), then the rest."""
    store.delete(f"{rig_prefix(rig_id)}/meta.json")
    store.delete_prefix(rig_prefix(rig_id))


# --- recordings -----------------------------------------------------------------------------------
def recording_meta_key(rig_id: str, recording_id: str) -> str:
    return f"{rig_prefix(rig_id)}/recordings/{recording_id}.json"


def save_recording_meta(store: BlobStore, rig_id: str, recording_id: str, meta: dict[str, Any]) -> dict[str, Any]:
    meta = {"id": recording_id, "rig_id": rig_id, "job_id": recording_id, "created_at": now_iso(), **meta}
    _put_json(store, recording_meta_key(rig_id, recording_id), meta)
    return meta


def load_recording_meta(store: BlobStore, rig_id: str, recording_id: str) -> dict[str, Any] | None:
    if not (valid_id(rig_id) and valid_id(recording_id)):
        return None
    return _json(store, recording_meta_key(rig_id, recording_id))


def list_recording_metas(store: BlobStore, rig_id: str) -> list[dict[str, Any]]:
    """The rig's recordings' metadata, oldest first."""
    metas = [m for k in store.list(f"{rig_prefix(rig_id)}/recordings") if (m := _json(store, k)) is not None]
    return sorted(metas, key=lambda m: m.get("created_at", ""))


def delete_recording_meta(store: BlobStore, rig_id: str, recording_id: str) -> None:
    store.delete(recording_meta_key(rig_id, recording_id))


# --- live frames ----------------------------------------------------------------------------------
def save_live(store: BlobStore, rig_id: str, seq: int, jpegs: Sequence[bytes],
              backgrounds: Sequence[np.ndarray] | None, stale: Sequence[bool] = ()) -> None:
    """Persist the latest live frame set (number ``seq``, JPEGs as received, which cameras were stale) and, when
    given, the background model (PNG)."""
    base = f"{rig_prefix(rig_id)}/live"
    for c, data in enumerate(jpegs):
        store.put(f"{base}/frames/{c:03d}.jpg", data)
    for c, image in enumerate(backgrounds or ()):
        store.put(f"{base}/backgrounds/{c:03d}.png", encode_png(image))
    _put_json(store, f"{base}/state.json", {"seq": seq, "stale": [bool(x) for x in stale], "saved_at": now_iso()})


def load_live(store: BlobStore, rig_id: str, cameras: int) -> tuple[int, list[bytes], list[bytes], list[bool]]:
    """(number of the stored set, JPEG bytes of that set, PNG bytes of the background model, which cameras of the
    set were stale): the lists hold ``cameras`` items, or none when not (completely) stored; the number is 0 then."""
    base = f"{rig_prefix(rig_id)}/live"

    def every(folder: str, ext: str) -> list[bytes]:
        try:
            return [store.read(f"{base}/{folder}/{c:03d}.{ext}") for c in range(cameras)]
        except BlobNotFound:
            return []

    state = _json(store, f"{base}/state.json") or {}
    jpegs = every("frames", "jpg")
    stale = [bool(x) for x in state.get("stale", [])]
    return ((int(state.get("seq", 0)) if jpegs else 0), jpegs, every("backgrounds", "png"),
            stale if len(stale) == cameras and jpegs else [])
