"""The session actor's readers-writer lock: views drawn together, frame changes alone."""
import threading
import time

from workers.streaming.actor import FrameLock


def test_readers_share_the_lock_and_a_writer_waits_for_them():
    lock = FrameLock()
    inside, most = [0], [0]
    guard = threading.Lock()
    both_in = threading.Barrier(2, timeout=5)

    def reader():
        lock.acquire_read()
        with guard:
            inside[0] += 1
            most[0] = max(most[0], inside[0])
        both_in.wait()  # fails (BrokenBarrierError) unless the two readers hold the lock together
        with guard:
            inside[0] -= 1
        lock.release_read()

    threads = [threading.Thread(target=reader) for _ in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert most[0] == 2 and lock.readers == 0


def test_a_writer_runs_alone_and_goes_before_new_readers():
    lock = FrameLock()
    order = []
    lock.acquire_read()  # a view being drawn
    writer = threading.Thread(target=lambda: (lock.acquire_write(), order.append("write"), lock.release_write()))
    writer.start()
    time.sleep(0.1)
    assert order == []  # the frame change waits for the view
    reader = threading.Thread(target=lambda: (lock.acquire_read(), order.append("read"), lock.release_read()))
    reader.start()
    time.sleep(0.1)
    assert order == []  # a new view waits behind the waiting frame change
    lock.release_read()
    writer.join(5)
    reader.join(5)
    assert order == ["write", "read"]


def test_downgrade_lets_readers_in_but_no_writer_in_between():
    lock = FrameLock()
    events = []
    lock.acquire_write()
    writer = threading.Thread(target=lambda: (lock.acquire_write(), events.append("other write"), lock.release_write()))
    writer.start()
    time.sleep(0.1)
    lock.downgrade()  # the prepared view is drawn on the frames it was prepared on
    assert lock.holds_current() and lock.readers == 1
    time.sleep(0.1)
    assert events == []  # the waiting writer still waits
    lock.release_current()
    writer.join(5)
    assert events == ["other write"] and not lock.holds_current()
