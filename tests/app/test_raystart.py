"""A node's ray start that stalls reaching its head's GCS is started again; signals reach it; its code is ours."""
import os
import signal
import subprocess
import sys
import textwrap
import time

from app.raystart import start_node

STALL = "[2026-11-29 11:34:57,417 W 1 1] rpc_client.h:153: Failed to connect to GCS at address ray-head:6379 within 5 seconds."


def _stand_in(tmp_path, script: str):
    """A stand-in ``ray`` (a shell script) that appends its pid to ``calls`` and then does ``script``."""
    calls = tmp_path / "calls"
    ray = tmp_path / "ray"
    ray.write_text(f"#!/bin/sh\necho $$ >> {calls}\nn=$(wc -l < {calls})\n" + textwrap.dedent(script))
    ray.chmod(0o755)
    return ray, calls


def test_a_start_that_stalls_reaching_the_gcs_is_stopped_and_run_again(tmp_path, capfd):
    ray, calls = _stand_in(tmp_path, f"""\
        if [ "$n" -eq 1 ]; then echo "{STALL}"; sleep 60 & wait; fi
        echo "Ray runtime started."
        """)
    assert start_node([str(ray), "start"], try_s=0.5) == 0
    first, second = (int(p) for p in calls.read_text().split())
    assert first != second
    time.sleep(0.2)
    assert not os.path.exists(f"/proc/{first}") or open(f"/proc/{first}/stat").read().split()[2] == "Z"
    out = capfd.readouterr().out
    assert out.count("Failed to connect to GCS") == 1 and "Ray runtime started" in out  # its output is passed on


def test_a_slow_start_is_waited_for_and_a_failing_one_is_not_run_again(tmp_path):
    slow, slow_calls = _stand_in(tmp_path, f"""\
        echo "{STALL}"; sleep 1; echo "Ray runtime started."; exit 0
        """)
    assert start_node([str(slow), "start"], try_s=5) == 0
    assert len(slow_calls.read_text().split()) == 1
    (tmp_path / "failing").mkdir()
    failing, failing_calls = _stand_in(tmp_path / "failing", "exit 7\n")
    assert start_node([str(failing), "start"], try_s=0.2) == 7  # an error without the stall: said, not retried
    assert len(failing_calls.read_text().split()) == 1


def test_every_try_stalling_gives_up_with_an_error(tmp_path):
    ray, calls = _stand_in(tmp_path, f"""\
        echo "{STALL}"; sleep 60 & wait
        """)
    assert start_node([str(ray), "start"], try_s=0.3, tries=2) == 1
    assert len(calls.read_text().split()) == 2


def test_sigterm_reaches_a_blocking_node_and_its_exit_code_is_returned(tmp_path):
    ray, calls = _stand_in(tmp_path, """\
        trap 'echo stopped > "$(dirname "$0")/stopped"; exit 0' TERM
        echo "Ray runtime started."
        while true; do sleep 0.1; done
        """)
    runner = subprocess.Popen([sys.executable, "-c", f"import sys; from app.raystart import start_node; "
                               f"sys.exit(start_node([{str(ray)!r}, 'start', '--block']))"],
                              stdout=subprocess.PIPE, text=True)
    assert runner.stdout.readline().strip() == "Ray runtime started."
    runner.send_signal(signal.SIGTERM)
    assert runner.wait(10) == 0
    assert (tmp_path / "stopped").read_text().strip() == "stopped"
