"""SIGTERM to a running ``simtest eval --workers 2`` stops its worker processes too (a real run of the CLI, a
real estimator that sleeps in its images, the processes read from /proc)."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytestmark = pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc to find the workers")


def _children(pid: int) -> list[int]:
    out = []
    for p in Path("/proc").iterdir():
        if p.name.isdigit():
            try:
                stat = (p / "stat").read_text()
            except OSError:
                continue
            if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
                out.append(int(p.name))
    return out


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def test_sigterm_stops_the_run_and_its_workers(small_dataset, tmp_path):
    slow = tmp_path / "slow.py"
    slow.write_text("import time\n\n\nclass Slow:\n    def estimate(self, observation):\n"
                    "        time.sleep(120)\n        return []\n")
    proc = subprocess.Popen([sys.executable, "-m", "simtest", "eval", "--data", str(small_dataset), "--estimator",
                             f"{slow}:Slow", "--workers", "2", "--timeout", "0", "--no-vsd", "--quiet",
                             "--out", str(tmp_path / "run")], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    try:
        deadline, workers = time.time() + 120, []
        while time.time() < deadline and len(workers) < 2:  # the pool's workers (and its resource tracker)
            time.sleep(0.5)
            workers = _children(proc.pid)
        assert workers, "no worker process started"
        time.sleep(5)  # the workers are inside the estimator's sleep
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
        assert proc.returncode == 143 and "terminated" in err
        deadline = time.time() + 30
        while time.time() < deadline and any(_alive(w) for w in workers):
            time.sleep(0.5)
        assert not any(_alive(w) for w in workers), [w for w in workers if _alive(w)]
    finally:
        if proc.poll() is None:
            proc.kill()
