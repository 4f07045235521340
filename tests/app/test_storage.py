import io
import time

import numpy as np
import pytest

from workers.storage import BlobNotFound, DirectoryBlobStore, InvalidKey, check_key, open_store, safe_name


@pytest.fixture(params=["directory", "s3"])
def store(request, tmp_path):
    if request.param == "directory":
        return DirectoryBlobStore(tmp_path / "blobs")
    return open_store(request.getfixturevalue("s3_url"))


def test_put_read_list_delete(store):
    assert store.put("jobs/a/inputs/x", b"hello") == 5
    store.put("jobs/a/inputs/y", io.BytesIO(b"world" * 1000))
    assert store.read("jobs/a/inputs/x") == b"hello"
    assert store.size("jobs/a/inputs/y") == 5000
    assert store.list("jobs/a") == ["jobs/a/inputs/x", "jobs/a/inputs/y"]
    store.delete("jobs/a/inputs/x")
    assert not store.exists("jobs/a/inputs/x")
    with pytest.raises(BlobNotFound):
        store.read("jobs/a/inputs/x")
    assert store.delete_prefix("jobs/a") == 1
    assert store.list("jobs") == []


@pytest.mark.parametrize("key", ["../etc/passwd", "a/../../b", "/abs", "a//b", ".hidden", "a/b/", "", "a\\b", "a/.."])
def test_keys_that_could_escape_are_refused(store, key):
    with pytest.raises(InvalidKey):
        check_key(key)
    with pytest.raises(InvalidKey):
        store.put(key, b"x")


def test_safe_names():
    assert safe_name("../../etc/passwd") == "passwd"
    assert safe_name("C:\\Users\\me\\IMG 001.JPG") == "IMG_001.JPG"
    assert safe_name("...") == "file"
    long = safe_name("temple_ring_" + "x" * 150 + "_par.txt")  # the format is told by the end of the name
    assert len(long) == 100 and long.startswith("temple_ring_") and long.endswith("x_par.txt") and "~" in long


def test_publish_replaces_the_destination_whole(store):
    store.put("jobs/j/results/old.txt", b"attempt 1")
    store.put("jobs/j/tmp-2/new.txt", b"attempt 2")
    store.publish("jobs/j/tmp-2", "jobs/j/results")
    assert store.list("jobs/j/results") == ["jobs/j/results/new.txt"]
    assert store.list("jobs/j/tmp-2") == []


def test_a_copy_is_a_blob_of_its_own(store):
    store.put("jobs/j/work/files/a.jpg", b"made by a task")
    store.copy("jobs/j/work/files/a.jpg", "jobs/j/tmp-1/a.jpg")
    store.put("jobs/j/work/files/a.jpg", b"replaced later")  # the copy keeps what it was given
    store.delete_prefix("jobs/j/work")
    assert store.read("jobs/j/tmp-1/a.jpg") == b"made by a task"
    with pytest.raises(BlobNotFound):
        store.copy("jobs/j/work/files/a.jpg", "jobs/j/tmp-1/b.jpg")


def test_large_upload_goes_in_parts_and_comes_back_whole(store):
    rng = np.random.default_rng(0)
    data = rng.integers(0, 256, 20 * 2**20 + 12345, dtype=np.uint8).tobytes()  # over the 8 MiB part size
    assert store.put("jobs/v/inputs/video", io.BytesIO(data)) == len(data)
    assert store.size("jobs/v/inputs/video") == len(data)
    local = store.local_path("jobs/v/inputs/video")
    assert local.read_bytes() == data
    with store.open("jobs/v/inputs/video") as f:
        assert f.read(10) == data[:10]


def test_missing_keys_raise_blob_not_found(store):
    for call in (store.read, store.size, store.local_path, store.open):
        with pytest.raises(BlobNotFound):
            call("jobs/none/here")
    assert not store.exists("jobs/none/here")
    store.delete("jobs/none/here")  # deleting what is not there is fine


def test_a_failed_write_leaves_no_partial_blob(store):
    class Broken(io.RawIOBase):
        """A stream that fails after 12 MiB, like an upload cut off half way."""

        def __init__(self):
            self.sent = 0

        def readable(self):
            return True

        def read(self, n=-1):
            if n is None or n < 0 or self.sent >= 12 << 20:
                raise OSError("the client went away")
            size = min(n, 5 << 20)
            self.sent += size
            return b"x" * size

    with pytest.raises(OSError):
        store.put("jobs/k/big", Broken())
    assert not store.exists("jobs/k/big")
    assert store.list("jobs/k") == []


def test_open_store_from_url(tmp_path):
    s = open_store((tmp_path / "b").as_uri())
    s.put("a", b"1")
    assert open_store(str(tmp_path / "b")).read("a") == b"1"
    with pytest.raises(ValueError, match="unsupported storage URL"):
        open_store("ftp://example/x")
    with pytest.raises(ValueError, match="no bucket"):
        open_store("s3:///prefix")
    with pytest.raises(ValueError, match="unknown storage URL option"):
        open_store("s3://bucket/p?colour=blue")


def test_a_job_whose_results_do_not_fit_fails_saying_so_and_publishes_nothing(tmp_path, monkeypatch):
    import errno

    from pydantic import BaseModel

    from workers import runtime
    from workers.registry import JobKind
    from workers.storage import DirectoryBlobStore

    store = DirectoryBlobStore(tmp_path / "blobs")
    real_put = store.put

    def full(key, data):
        if "/tmp-" in key and store.list("jobs/j1"):  # the first result file fits, the second does not
            raise OSError(errno.ENOSPC, "No space left on device")
        return real_put(key, data)

    def entry(ctx):
        ctx.write_result("a.bin", b"a" * 10)
        ctx.write_result("b.bin", b"b" * 10)
        return {}

    monkeypatch.setattr(store, "put", full)
    monkeypatch.setattr(runtime, "open_store", lambda url: store)
    class NoParams(BaseModel):
        pass

    monkeypatch.setattr(runtime, "get_kind", lambda name: JobKind("test.write", entry, NoParams))
    events = list(runtime.execute_job(runtime.JobSpec("j1", "test.write", {}, {}, store_url=store.url)))
    assert events[-1]["type"] == "failed" and "storage is full" in events[-1]["error"], events[-1]
    assert store.list("jobs") == []  # nothing half-published: the staged copy is gone too


def test_an_unreachable_store_is_left_alone_for_its_retry_after_then_tried_again():
    from workers.storage import StoreUnavailable, storage_unavailable

    store = open_store("s3://bucket/p?endpoint_url=http://127.0.0.1:9&region=us-east-1&max_attempts=1&retry_after=0.5")
    assert store.retry_after_s == 0.5 and "retry_after=0.5" in store.url  # kept for the workers' copy of the URL
    with pytest.raises(Exception) as first:
        store.read("k")  # nothing listens on port 9: the connection is refused
    assert storage_unavailable(first.value) and not isinstance(first.value, StoreUnavailable)
    with pytest.raises(StoreUnavailable, match="not tried again"):
        store.read("k")  # at once, without trying
    time.sleep(0.6)
    with pytest.raises(Exception) as again:
        store.read("k")  # tried again after retry_after
    assert storage_unavailable(again.value) and not isinstance(again.value, StoreUnavailable)
    with pytest.raises(ValueError, match="retry_after must be positive"):
        open_store("s3://bucket/p?retry_after=0")
