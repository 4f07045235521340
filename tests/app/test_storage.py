import io

import pytest

from workers.storage import BlobNotFound, DirectoryBlobStore, InvalidKey, check_key, new_key, open_store, safe_name


@pytest.fixture
def store(tmp_path):
    return DirectoryBlobStore(tmp_path / "blobs")


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


def test_generated_keys_and_safe_names():
    key = new_key("uploads")
    assert key.startswith("uploads/") and check_key(key) == key
    assert safe_name("../../etc/passwd") == "passwd"
    assert safe_name("C:\\Users\\me\\IMG 001.JPG") == "IMG_001.JPG"
    assert safe_name("...") == "file"


def test_publish_replaces_the_destination_whole(store):
    store.put("jobs/j/results/old.txt", b"attempt 1")
    store.put("jobs/j/tmp-2/new.txt", b"attempt 2")
    store.publish("jobs/j/tmp-2", "jobs/j/results")
    assert store.list("jobs/j/results") == ["jobs/j/results/new.txt"]
    assert store.list("jobs/j/tmp-2") == []


def test_a_failed_write_leaves_no_partial_blob(store):
    class Broken(io.RawIOBase):
        def __init__(self):
            self.calls = 0

        def read(self, n=-1):
            self.calls += 1
            if self.calls > 2:
                raise OSError("disk went away")
            return b"x" * 10

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
