"""The guarded zip reader (workers/common/safezip.py) and the engines that read zips through it."""
from __future__ import annotations

import io
import stat
import zipfile

import numpy as np
import pytest

from tests.common.hostile import zip_understating, zip_with
from workers.common.jobctx import JobInputError
from workers.common.safezip import SafeZip, ZipInputError, ZipLimits

MiB = 1 << 20


def test_a_plain_archive_reads_back():
    data = zip_with(("a/1.txt", b"hello"), ("b.txt", b"x" * 10))
    with SafeZip(data, label="x.zip") as zf:
        assert zf.names() == ["a/1.txt", "b.txt"]
        assert zf.read("a/1.txt") == b"hello"


@pytest.mark.parametrize("name, problem", [
    ("../evil.txt", "'..'"), ("a/../../evil.txt", "'..'"), ("..\\evil.txt", "'..'"),
    ("/etc/passwd", "absolute"), ("C:/windows/x", "absolute"), ("\\\\server\\x", "absolute"),
])
def test_unsafe_member_names_are_refused(name, problem):
    with pytest.raises(ZipInputError, match=f"x.zip member .*{problem}"):
        SafeZip(zip_with((name, b"1")), label="x.zip")


def test_symlinks_and_encrypted_members_are_refused():
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        link = zipfile.ZipInfo("link")
        link.create_system = 3
        link.external_attr = (stat.S_IFLNK | 0o777) << 16
        zf.writestr(link, "/etc/passwd")
    with pytest.raises(ZipInputError, match="symbolic link"):
        SafeZip(buf.getvalue())
    data = bytearray(zip_with(("secret", b"1")))
    data[6] |= 1  # general purpose flag bit 0: encrypted, in the local and the central header
    data[data.index(b"PK\x01\x02") + 8] |= 1
    with pytest.raises(ZipInputError, match="encrypted"):
        SafeZip(bytes(data))


def test_declared_sizes_count_and_ratio_are_checked_on_opening():
    limits = ZipLimits(max_zip_members=3, max_zip_member_bytes=2 * MiB, max_zip_total_bytes=3 * MiB, max_zip_ratio=50)
    with pytest.raises(ZipInputError, match="holds 4 members"):
        SafeZip(zip_with(*[(f"{i}", b"") for i in range(4)]), limits)
    noise = np.random.default_rng(0).integers(0, 255, 3 * MiB // 2, np.uint8).tobytes()  # does not compress
    with pytest.raises(ZipInputError, match="member 'big' is 3,145,728 bytes"):
        SafeZip(zip_with(("big", noise + noise)), limits)
    with pytest.raises(ZipInputError, match="expands to 4,718,592 bytes"):
        SafeZip(zip_with(("a", noise), ("b", noise), ("c", noise)), limits)
    with pytest.raises(ZipInputError, match="expands 1,0[0-9][0-9] times"):
        SafeZip(zip_with(("zeros", b"\0" * (2 * MiB))), limits)
    SafeZip(zip_with(("small-zeros", b"\0" * 100_000)), limits)  # small members may compress well


def test_a_member_larger_than_its_header_says_is_caught_while_reading():
    lying = zip_understating("frame.png", size=8 * MiB, declared=1000)
    with SafeZip(lying, label="x.zip") as zf:
        with pytest.raises(ZipInputError, match="x.zip member 'frame.png'"):
            zf.read("frame.png")


def test_a_huge_central_directory_is_refused_before_zipfile_parses_it(monkeypatch):
    data = zip_with(*[(f"f{i:05d}", b"") for i in range(2000)])
    parsed = []
    monkeypatch.setattr(zipfile, "ZipFile", lambda *a, **k: parsed.append(a))
    with pytest.raises(ZipInputError, match="2,000 members"):
        SafeZip(data, ZipLimits(max_zip_members=100))
    assert parsed == []


def test_limits_come_from_the_environment(monkeypatch):
    monkeypatch.setenv("SWEEPCAST_MAX_ZIP_MEMBERS", "7")
    monkeypatch.setenv("SWEEPCAST_MAX_ZIP_RATIO", "2.5")
    assert ZipLimits.from_env() == ZipLimits(max_zip_members=7, max_zip_ratio=2.5)


def test_errors_take_the_callers_type_and_are_job_input_errors():
    class EngineError(ValueError):
        pass

    with pytest.raises(EngineError, match="the dataset is not a readable zip"):
        SafeZip(b"not a zip", label="the dataset", error=EngineError)
    assert issubclass(ZipInputError, JobInputError)


def test_drone_job_refuses_a_zip_bomb_of_stills(tmp_path, monkeypatch):
    from workers.drone.frames import open_media

    monkeypatch.setenv("SWEEPCAST_MAX_ZIP_MEMBER_BYTES", str(16 * MiB))
    path = tmp_path / "media"
    path.write_bytes(zip_with(("0001.png", b"\0" * (32 * MiB))))  # 32 MiB in about 32 kB
    with pytest.raises(JobInputError, match="0001.png"):
        open_media(path)
    path.write_bytes(zip_understating("0001.png", size=32 * MiB, declared=1000))
    with pytest.raises(JobInputError, match="0001.png"):
        list(open_media(path))


def test_face_dataset_refuses_unsafe_archives():
    from workers.faces.dataset import load_dataset_zip
    from workers.faces.errors import FaceInputError

    with pytest.raises(FaceInputError, match="the dataset zip member '../manifest.csv'"):
        load_dataset_zip(zip_with(("../manifest.csv", b"person,expression,file\n")))
    with pytest.raises(FaceInputError, match="expands"):
        load_dataset_zip(zip_with(("manifest.csv", b"person,expression,file\n"), ("a.obj", b" " * (8 * MiB))))


def test_drone_job_names_the_clients_file_not_its_storage_key(tmp_path):
    from tests.fakectx import FakeContext
    from workers.drone.job import run_reconstruction

    params = {"fx": 100.0, "fy": 100.0, "cx": 16.0, "cy": 12.0}
    ctx = FakeContext(tmp_path, params, {"media": zip_with(("../0001.png", b"1"))},
                      input_meta={"media": {"filename": "flight.zip"}})
    with pytest.raises(JobInputError, match="the zip archive flight.zip member '../0001.png'"):
        run_reconstruction(ctx)
    ctx = FakeContext(tmp_path / "b", params, {"media": b"not a video"}, input_meta={"media": {"filename": "v.mp4"}})
    with pytest.raises(JobInputError, match="^v.mp4 is not a video"):
        run_reconstruction(ctx)
