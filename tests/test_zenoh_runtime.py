"""The black box runs zenoh on one worker thread (common/config.py ONE_THREAD_RUNTIME): the
string is one zenoh accepts, it takes threads away, and a ZENOH_RUNTIME a person set wins."""
from __future__ import annotations

import os
import subprocess
import sys

from viena.common.config import ONE_THREAD_RUNTIME

THREADS = """
import os, sys, zenoh
from viena.common.config import load_zenoh_config, use_one_thread_runtime
if sys.argv[1] == "capped":
    use_one_thread_runtime()
session = zenoh.open(load_zenoh_config(mode="peer", listen=["tcp/127.0.0.1:0"]))
print(len(os.listdir("/proc/self/task")), os.environ.get("ZENOH_RUNTIME", ""))
session.close()
"""


def threads(how: str, **env: str) -> tuple[int, str]:
    environment = {k: v for k, v in os.environ.items() if k != "ZENOH_RUNTIME"} | env
    out = subprocess.run([sys.executable, "-c", THREADS, how], capture_output=True, text=True, timeout=60,
                         check=True, env=environment).stdout.split(maxsplit=1)
    return int(out[0]), out[1].strip() if len(out) > 1 else ""


def test_one_thread_runtime_is_taken_by_zenoh_and_runs_fewer_threads():
    default, _ = threads("default")
    capped, runtime = threads("capped")
    assert runtime == ONE_THREAD_RUNTIME and capped < default


def test_a_runtime_set_by_hand_wins():
    mine = "(app: (worker_threads: 2))"
    assert threads("capped", ZENOH_RUNTIME=mine)[1] == mine
