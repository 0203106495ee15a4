"""A real two-node Ray cluster on this machine: a head and a second raylet, each with its own temp dir, on free
loopback ports, token authentication off (``RAY_AUTH_MODE=disabled`` for every process) except where it is
tested. ``simtest generate`` and ``simtest corrupt`` joining it write the local back end's bytes; a raylet
killed mid-unit costs a retry (one line through the progress bar's writer, not Ray's log dump) and no bytes; a
port that is not a head, and a head that wants a token, fail in one line with rc 2 before anything is written.
Every cluster is stopped by killing the processes it started (found by its temp dir), never ``ray stop``
(which would stop other Ray instances on the machine)."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

pytest.importorskip("ray")
pytestmark = pytest.mark.slow

RAY = str(Path(sys.executable).with_name("ray"))
TINY = ["--objects", "builtin-small", "--width", "128", "--height", "96", "--seed", "7"]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _env(**extra: str) -> dict[str, str]:
    """This process's environment without Ray's address and auth settings (a local ray.init earlier in the
    session sets RAY_AUTH_MODE=token here), auth disabled, plus ``extra``."""
    env = {k: v for k, v in os.environ.items() if not k.startswith(("RAY_AUTH", "RAY_ADDRESS"))}
    env["RAY_AUTH_MODE"] = "disabled"
    env.update(extra)
    return {k: v for k, v in env.items() if v != ""}


def _children(pids: set[int]) -> set[int]:
    """``pids`` and all their descendants (Ray's workers rename themselves, so they are found by parent)."""
    parent: dict[int, int] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            parent[int(stat.parent.name)] = int(stat.read_text().rsplit(")", 1)[1].split()[1])
        except (OSError, ValueError, IndexError):
            continue
    found, grew = set(pids), True
    while grew:
        more = {p for p, pp in parent.items() if pp in found} - found
        found |= more
        grew = bool(more)
    return found


def _processes_with(text: str) -> set[int]:
    found = set()
    for cmdline in Path("/proc").glob("[0-9]*/cmdline"):
        try:
            if text.encode() in cmdline.read_bytes():
                found.add(int(cmdline.parent.name))
        except OSError:
            continue
    return found


class Cluster:
    """Ray nodes started with ``ray start`` on 127.0.0.1, each under its own temp dir in ``root``."""

    def __init__(self, root: Path, env: dict[str, str]) -> None:
        self.root, self.env = root, env
        self.port = _free_port()
        self.address = f"127.0.0.1:{self.port}"
        self.dirs: list[Path] = []
        self.node_manager_ports: list[int] = []

    def start_node(self, head: bool) -> Path:
        temp = self.root / f"n{len(self.dirs)}"
        self.dirs.append(temp)
        cmd = [RAY, "start", "--num-cpus", "1", "--temp-dir", str(temp), "--disable-usage-stats"]
        if head:
            cmd += ["--head", "--port", str(self.port), "--include-dashboard=false"]
        else:
            nm = _free_port()
            self.node_manager_ports.append(nm)
            cmd += ["--address", self.address, "--node-manager-port", str(nm)]
        done = subprocess.run(cmd, env=self.env, capture_output=True, text=True, timeout=120)
        assert done.returncode == 0, done.stdout + done.stderr
        return temp

    def raylet(self, temp: Path) -> int:
        pids = [p for p in _processes_with(f"{temp}/session_") if b"raylet/raylet" in
                Path(f"/proc/{p}/cmdline").read_bytes()]
        assert len(pids) == 1, pids
        return pids[0]

    def stop(self) -> None:
        deadline = time.time() + 20
        while time.time() < deadline:
            pids = set()
            for temp in self.dirs:
                pids |= _processes_with(str(temp))
            pids = _children(pids) - {os.getpid()}
            if not pids:
                break
            for pid in pids:
                try:
                    os.kill(pid, signal.SIGKILL)
                except OSError:
                    pass
            time.sleep(0.3)
        shutil.rmtree(self.root, ignore_errors=True)


@pytest.fixture(scope="module")
def cluster(request):
    root = Path(tempfile.mkdtemp(prefix="sxray", dir="/tmp"))  # short: Ray's socket paths live under it
    c = Cluster(root, _env())
    request.addfinalizer(c.stop)
    c.start_node(head=True)
    c.start_node(head=False)
    return c


def _simtest(args: list[str], env: dict[str, str], timeout: float = 240) -> tuple[subprocess.CompletedProcess, float]:
    t0 = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "simtest", *args], env=env, capture_output=True, text=True,
                          timeout=timeout, stdin=subprocess.DEVNULL)
    return done, time.perf_counter() - t0


def _digest(root: Path, skip: tuple[str, ...] = ("manifest.json",)) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha1(p.read_bytes()).hexdigest() for p in sorted(root.rglob("*"))
            if p.is_file() and p.name not in skip}


def _refused(done: subprocess.CompletedProcess, seconds: float, out: Path, *needles: str) -> str:
    line = done.stderr.strip()
    assert done.returncode == 2, done.stderr
    assert len(line.splitlines()) == 1, line  # one line: no Ray C++ log lines, no traceback
    assert seconds < 12, f"{seconds:.1f} s: {line}"
    assert not out.exists(), "nothing may be written before the cluster is joined"
    for needle in needles:
        assert needle in line, line
    return line


def test_a_port_that_is_not_a_head_fails_in_one_line(cluster, tmp_path):
    """The second raylet's node-manager port accepts TCP and speaks gRPC, but is no GCS."""
    address = f"127.0.0.1:{cluster.node_manager_ports[0]}"
    out = tmp_path / "d"
    done, s = _simtest(["generate", *TINY, "--scenes", "1", "--frames-per-scene", "1", "--backend", "ray",
                        "--ray-address", address, "--out", str(out)], cluster.env)
    line = _refused(done, s, out, f"cannot join Ray at {address}", "not the head's GCS", "ray start --head --port")
    log = Path(line.rsplit("Ray's log: ", 1)[1].rstrip(")"))
    assert "gcs_client" in log.read_text()  # Ray's own lines are kept, in the file the line names


def test_corrupt_on_the_cluster_writes_the_local_bytes(cluster, tmp_path):
    data = tmp_path / "data"
    done, _ = _simtest(["generate", *TINY, "--scenes", "2", "--frames-per-scene", "2", "--out", str(data),
                        "--quiet"], cluster.env)
    assert done.returncode == 0, done.stderr
    args = ["corrupt", "--in", str(data), "--weather", "fog", "--severity", "3", "--seed", "1"]
    done, _ = _simtest([*args, "--out", str(tmp_path / "local"), "--quiet"], cluster.env)
    assert done.returncode == 0, done.stderr
    done, _ = _simtest([*args, "--out", str(tmp_path / "ray"), "--backend", "ray", "--ray-address",
                        cluster.address], cluster.env)
    assert done.returncode == 0, done.stderr
    assert "joined 127.0.0.1" in done.stderr and "2 nodes, 2 CPUs" in done.stderr, done.stderr
    skip = ("manifest.json", "corruption.json")  # they record the command line
    ref = _digest(tmp_path / "local", skip)
    assert len(ref) > 8 and _digest(tmp_path / "ray", skip) == ref


def test_generate_on_the_cluster_survives_a_killed_raylet(cluster, tmp_path):
    """Run last on the cluster: it kills the second node."""
    args = ["generate", *TINY, "--scenes", "4", "--frames-per-scene", "3", "--quiet"]
    done, _ = _simtest([*args, "--out", str(tmp_path / "local")], cluster.env)
    assert done.returncode == 0, done.stderr
    out = tmp_path / "ray"
    cmd = [sys.executable, "-m", "simtest", *args[:-1], "--out", str(out), "--backend", "ray", "--ray-address",
           cluster.address, "--workers", "5"]
    proc = subprocess.Popen(cmd, env=cluster.env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            stdin=subprocess.DEVNULL)
    try:
        second = cluster.raylet(cluster.dirs[1])
        deadline, killed = time.time() + 120, False
        while time.time() < deadline and proc.poll() is None and not killed:
            for pid in _children({second}) - {second}:
                try:
                    busy = Path(f"/proc/{pid}/cmdline").read_bytes().startswith(b"ray::_ray_unit")
                except OSError:
                    continue
                if busy:  # the node dies while one of its workers makes a scene
                    for victim in (second, pid):
                        os.kill(victim, signal.SIGKILL)
                    killed = True
                    break
            time.sleep(0.05)
        stdout, stderr = proc.communicate(timeout=180)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert killed, "no unit ran on the second node"
    assert proc.returncode == 0, stderr
    assert "retry 1/3" in stderr and ("(NodeDiedError)" in stderr or "(WorkerCrashedError)" in stderr), stderr
    said = [line for line in stderr.replace("\r", "\n").splitlines() if line.strip() and
            not line.startswith("generate:")]  # the progress bar aside: the retry, Ray's one line, the summary
    assert "[state-dump]" not in stderr and len(said) <= 4, said  # not the dead raylet's log
    assert "1 retried, 0 failed (joined 127.0.0.1" in stderr, stderr
    assert _digest(out) == _digest(tmp_path / "local")
    run = json.loads((out / "manifest.json").read_text())["runs"][0]
    assert run["cluster"] == "joined" and run["nodes"] == 2 and run["cluster_cpus"] == 2 and run["retried"] == 1
    assert "workers" not in run  # --workers does not apply to a joined cluster
    assert run["startup_s"] > 0


def test_token_authentication(tmp_path):
    """A head with token auth: a driver without the token is refused in one line saying how to get it; with
    the token in RAY_AUTH_TOKEN (the way Ray reads it) the run goes."""
    token = hashlib.sha256(str(time.time_ns()).encode()).hexdigest()
    root = Path(tempfile.mkdtemp(prefix="sxauth", dir="/tmp"))
    head = Cluster(root, _env(RAY_AUTH_MODE="token", RAY_AUTH_TOKEN=token))
    try:
        head.start_node(head=True)
        gen = ["generate", *TINY, "--scenes", "1", "--frames-per-scene", "1", "--backend", "ray", "--ray-address",
               head.address, "--quiet"]
        out = tmp_path / "refused"
        done, s = _simtest([*gen, "--out", str(out)], _env())
        _refused(done, s, out, f"cannot join Ray at {head.address}", "refused this driver", "ray get-auth-token",
                 "RAY_AUTH_MODE=token RAY_AUTH_TOKEN=")
        done, _ = _simtest([*gen, "--out", str(tmp_path / "ok")], _env(RAY_AUTH_MODE="", RAY_AUTH_TOKEN=token))
        assert done.returncode == 0, done.stderr
        assert (tmp_path / "ok" / "train_pbr" / "000000").is_dir()
    finally:
        head.stop()


def test_a_local_instance_writes_no_token_file(tmp_path):
    """Ray's local ray.init() would write ~/.ray/auth_token, after which every `ray start --head` on the machine
    wants the token; simtest's own local instance gets a token in its environment instead."""
    from simtest.objects.model import cache_dir

    home = tmp_path / "home"
    home.mkdir()
    env = _env(HOME=str(home), RAY_AUTH_MODE="", SIMTEST_CACHE=str(cache_dir()))
    done, _ = _simtest(["generate", *TINY, "--scenes", "1", "--frames-per-scene", "1", "--backend", "ray",
                        "--workers", "1", "--out", str(tmp_path / "d"), "--quiet"], env)
    assert done.returncode == 0 and not done.stderr, done.stderr  # nor Ray's warning about the token
    assert not (home / ".ray" / "auth_token").exists()
    run = json.loads((tmp_path / "d" / "manifest.json").read_text())["runs"][0]
    assert run["cluster"] == "started" and run["workers"] == 1 and run["nodes"] == 1
