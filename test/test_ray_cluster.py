"""A real two-node Ray cluster on this machine — a head node, and a second node in a network namespace of its own
where CAP_NET_ADMIN allows it (else on another loopback address) — that the asynchronous runner and the grid
command use as users' clusters are used: training with actors on both nodes (asserted from the nodes' ids), the
second node killed mid-run (the run goes on, the death counted, nothing lost beyond the rollouts in flight), a grid
of runs as Ray tasks, and the one-line refusals: an address nobody answers at, more workers than the cluster has.

Everything the cluster needs is in its environment: an auth token of its own (Ray's processes listen on every
interface), failure detection in about a second (the head's health-check settings), no usage statistics. The
pytest process itself never imports Ray: the trainer and the grid run as the users' commands, in subprocesses."""
from __future__ import annotations

import csv
import json
import os
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
RAY = str(Path(sys.executable).parent / "ray")
FAST_FAILURE_DETECTION = {"RAY_health_check_period_ms": "500", "RAY_health_check_timeout_ms": "500",
                          "RAY_health_check_failure_threshold": "3", "RAY_health_check_initial_delay_ms": "0"}
TINY = ["variant=baseline", "players_per_team=1", "num_envs=2", "perception=none", "rollout_length=4",
        "ltp_horizon=2", "feature_size=16", "ppo_minibatches=1", "log_every_updates=1",
        "checkpoint_every_minutes=10"]
NAMESPACE = f"dynenv-ray-{os.getpid()}"


def _free_port(host: str) -> int:
    with socket.socket() as s:
        s.bind((host, 0))
        return s.getsockname()[1]


def _netns_available() -> bool:
    """A namespace with a veth pair can be made here (root with CAP_NET_ADMIN and iproute2)."""
    if shutil.which("ip") is None:
        return False
    probe = subprocess.run(["ip", "netns", "add", NAMESPACE + "-probe"], capture_output=True)
    if probe.returncode != 0:
        return False
    subprocess.run(["ip", "netns", "del", NAMESPACE + "-probe"], capture_output=True)
    return True


def _sh(*command: str) -> None:
    subprocess.run(command, check=True, capture_output=True)


class Cluster:
    """Head on ``head_ip``; the second node on ``node_ip`` (in ``namespace`` when there is one)."""

    def __init__(self) -> None:
        self.base = Path(tempfile.mkdtemp(prefix="rc", dir="/tmp"))      # short: Unix socket paths are limited
        self.namespace, self.head, self.node = None, None, None
        try:
            self._start_cluster()
        except BaseException:
            self.stop()
            raise

    def _start_cluster(self) -> None:
        self.env = {**os.environ, "RAY_AUTH_MODE": "token", "RAY_AUTH_TOKEN": secrets.token_hex(32),
                    "RAY_USAGE_STATS_ENABLED": "0", **FAST_FAILURE_DETECTION}
        self.namespace = NAMESPACE if _netns_available() else None
        if self.namespace:
            suffix = str(os.getpid() % 200 + 20)
            self.head_ip, self.node_ip = f"10.231.{suffix}.1", f"10.231.{suffix}.2"
            host_if, ns_if = f"rh{os.getpid() % 100000}", f"rn{os.getpid() % 100000}"
            _sh("ip", "netns", "add", self.namespace)
            _sh("ip", "link", "add", host_if, "type", "veth", "peer", "name", ns_if)
            _sh("ip", "link", "set", ns_if, "netns", self.namespace)
            _sh("ip", "addr", "add", f"{self.head_ip}/24", "dev", host_if)
            _sh("ip", "link", "set", host_if, "up")
            _sh("ip", "netns", "exec", self.namespace, "ip", "addr", "add", f"{self.node_ip}/24", "dev", ns_if)
            _sh("ip", "netns", "exec", self.namespace, "ip", "link", "set", ns_if, "up")
            _sh("ip", "netns", "exec", self.namespace, "ip", "link", "set", "lo", "up")
        else:
            self.head_ip, self.node_ip = "127.0.0.2", "127.0.0.3"
        self.port = _free_port(self.head_ip)
        self.address = f"{self.head_ip}:{self.port}"
        self.head = self._start("head", ["--head", "--port", str(self.port), "--node-ip-address", self.head_ip])
        self._wait_started("head", self.head)
        self._start_second_node()

    def _start_second_node(self) -> None:
        prefix = ["ip", "netns", "exec", self.namespace] if self.namespace else []
        self.node = self._start("node", ["--address", self.address, "--node-ip-address", self.node_ip], prefix)
        self._wait_started("node", self.node)
        self.node_ids = self._node_ids(expect=2)

    def ensure_two_nodes(self) -> None:
        """A new second node where a test killed it: once the head has counted the old one dead (so that the ids
        read next are the new node's), a node started as the first one was."""
        if self.node is None or self.node.poll() is None:
            return
        if len(self._node_ids(expect=1)) != 1:
            raise RuntimeError("the head still counts the killed node alive after 60 s")
        self._start_second_node()

    def _start(self, name: str, args: list[str], prefix: list[str] = ()) -> subprocess.Popen:
        log = open(self.base / f"{name}.log", "w")
        head_only = ["--include-dashboard=false", "--temp-dir", str(self.base / name)] if name == "head" else []
        command = [*prefix, RAY, "start", "--block", *args, "--num-cpus", "1", "--object-store-memory",
                   str(100 << 20), "--disable-usage-stats", "--include-log-monitor=false", *head_only]
        return subprocess.Popen(command, env=self.env, stdout=log, stderr=subprocess.STDOUT,
                                start_new_session=True)

    def _wait_started(self, name: str, process: subprocess.Popen, timeout: float = 90.0) -> None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if "Ray runtime started" in (self.base / f"{name}.log").read_text():
                return
            if process.poll() is not None:
                raise RuntimeError(f"ray {name} exited: {(self.base / f'{name}.log').read_text()[-2000:]}")
            time.sleep(0.2)
        raise RuntimeError(f"ray {name} did not start within {timeout} s")

    def _node_ids(self, expect: int, timeout: float = 60.0) -> dict[str, str]:
        """Node IP → node id of the alive nodes, read by a driver of its own."""
        # os._exit once printed: Ray's own shutdown at exit is not needed here, and on a busy machine it outlasted
        # the 60 s timeout after the answer was out
        script = ("import json, os, ray; ray.init(address=%r, _node_ip_address=%r, log_to_driver=False, "
                  "logging_level='ERROR'); print(json.dumps({n['NodeManagerAddress']: n['NodeID'] "
                  "for n in ray.nodes() if n['Alive']}), flush=True); os._exit(0)") % (self.address, self.head_ip)
        deadline = time.monotonic() + timeout
        while True:
            out = subprocess.run([sys.executable, "-c", script], env=self.env, capture_output=True, text=True,
                                 timeout=60)
            nodes = json.loads(out.stdout.strip().splitlines()[-1]) if out.returncode == 0 else {}
            if len(nodes) == expect or time.monotonic() > deadline:
                return nodes
            time.sleep(0.5)

    def kill_node(self) -> None:
        os.killpg(self.node.pid, signal.SIGKILL)

    def stop(self) -> None:
        for process in (self.node, self.head):
            if process is None:
                continue
            if process.poll() is None:
                process.send_signal(signal.SIGTERM)
                try:
                    process.wait(15)
                except subprocess.TimeoutExpired:
                    pass
            try:
                os.killpg(process.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        if self.namespace:
            subprocess.run(["ip", "netns", "del", self.namespace], capture_output=True)
        shutil.rmtree(self.base, ignore_errors=True)


@pytest.fixture(scope="module")
def shared_cluster():
    """One cluster for the module's tests (starting one is two Ray processes and a driver: tens of seconds)."""
    made = Cluster()
    try:
        yield made
    finally:
        made.stop()


@pytest.fixture
def cluster(shared_cluster):
    """The shared cluster with both its nodes, whatever the test before did to the second one."""
    shared_cluster.ensure_two_nodes()
    return shared_cluster


def _train(cluster: Cluster, run_dir: Path, *extra: str) -> subprocess.Popen:
    command = [sys.executable, "-m", "dynenv_ros.learning.train_cli", "--config", "async", "--run-dir",
               str(run_dir), "--no-progress", "--set", "backend=ray", "--set", f"ray_address={cluster.address}",
               *[f"--set={item}" for item in TINY], *extra]
    return subprocess.Popen(command, cwd=ROOT, env=cluster.env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)


def _scalar(run_dir: Path, name: str) -> list[float]:
    path = run_dir / "metrics.csv"
    if not path.is_file():
        return []
    with open(path, newline="") as handle:
        return [float(row["value"]) for row in csv.DictReader(handle) if row.get("name") == name]


def test_training_uses_both_nodes_and_goes_on_when_the_second_dies(cluster, tmp_path):
    assert set(cluster.node_ids) == {cluster.head_ip, cluster.node_ip}
    run_dir = tmp_path / "run"
    process = _train(cluster, run_dir, "--set=workers=2", "--set=worker_restarts=1",
                     "--set=total_env_steps=1600", "--set=max_minutes=4")
    try:
        deadline = time.monotonic() + 180
        while time.monotonic() < deadline and max(_scalar(run_dir, "async/nodes_seen_max") or [0]) < 2:
            assert process.poll() is None, process.communicate()[1][-3000:]
            time.sleep(0.2)
        assert max(_scalar(run_dir, "async/nodes_seen_max") or [0]) == 2, "no rollouts from both nodes"
        learnt_before = max(_scalar(run_dir, "async/workers_alive") and [1] or [0])
        cluster.kill_node()
        out, err = process.communicate(timeout=300)
    finally:
        if process.poll() is None:
            process.kill()
    assert process.returncode == 0, err[-3000:]
    summary = json.loads((run_dir / "summary.json").read_text())
    by_node = summary["rollouts_by_node"]
    assert set(by_node) == set(cluster.node_ids.values())             # actors on both nodes, by their node ids
    assert summary["worker_deaths"] == 1 and summary["env_steps"] >= 1600 and learnt_before
    assert by_node[cluster.node_ids[cluster.head_ip]] > by_node[cluster.node_ids[cluster.node_ip]]
    died = [line for line in err.splitlines() if "died" in line]
    assert len(died) == 1 and "going on with 1 of 2" in died[0], err[-3000:]
    assert min(_scalar(run_dir, "async/workers_alive")) == 1
    assert (run_dir / "policy.safetensors").is_file()


def test_a_grid_of_runs_runs_as_tasks_on_the_cluster(cluster, tmp_path):
    out = tmp_path / "sweep"
    command = [sys.executable, "-m", "dynenv_ros.experiments.sweep", "--config", "quick", "--variants", "baseline",
               "--seeds", "0", "1", "--ray-address", cluster.address, "--out", str(out), "--eval-episodes", "1",
               "--set", "total_env_steps=48", "--set", "num_envs=2", "--set", "players_per_team=1",
               "--set", "perception=none", "--set", "episode_seconds=10"]
    done = subprocess.run(command, cwd=ROOT, env=cluster.env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    nodes = {json.loads((out / f"baseline_s{s}" / "sweep.json").read_text())["node"] for s in (0, 1)}
    assert nodes <= set(cluster.node_ids.values())
    assert len(nodes) == 2                      # one CPU per node: the two runs ran side by side, one on each
    merged = json.loads((out / "baseline.json").read_text())
    assert [row["unit"] for row in merged["per_seed"]] == ["baseline_s0", "baseline_s1"]
    assert "paper_metric" in (out / "table.md").read_text()
    for seed in (0, 1):
        assert (out / f"baseline_s{seed}" / "policy.safetensors").is_file()


def test_more_workers_than_the_cluster_has_are_refused_in_one_line(cluster, tmp_path):
    process = _train(cluster, tmp_path / "run", "--set=workers=3", "--set=num_envs=4", "--set=total_env_steps=8")
    out, err = process.communicate(timeout=120)
    assert process.returncode == 2
    assert err.strip() == f"dynenv-train: workers 3 need 3 CPUs, the Ray cluster at {cluster.address} has 2", err


def test_an_address_nobody_answers_at_is_refused_within_its_timeout(tmp_path):
    port = _free_port("127.0.0.2")                  # nothing listens there
    started = time.monotonic()
    done = subprocess.run([sys.executable, "-m", "dynenv_ros.learning.train_cli", "--config", "async", "--run-dir",
                           str(tmp_path / "run"), "--set", "backend=ray", "--set", f"ray_address=127.0.0.2:{port}",
                           "--set", "ray_connect_timeout_s=3"], cwd=ROOT, capture_output=True, text=True, timeout=120)
    elapsed = time.monotonic() - started
    assert done.returncode == 2
    assert f"127.0.0.2:{port}" in done.stderr and done.stderr.strip().count("\n") == 0, done.stderr
    assert elapsed < 60                               # python and torch start-up included; Ray's own wait is minutes


def test_an_embedded_local_ray_trains_with_its_actors(tmp_path):
    env = {k: v for k, v in os.environ.items() if not k.startswith("RAY_")}
    token_file = Path.home() / ".ray" / "auth_token"
    token_before = token_file.exists()
    run_dir = tmp_path / "run"
    done = subprocess.run([sys.executable, "-m", "dynenv_ros.learning.train_cli", "--config", "async", "--run-dir",
                           str(run_dir), "--no-progress", "--set", "backend=ray", "--set", "workers=1",
                           *[f"--set={item}" for item in TINY], "--set", "total_env_steps=32"],
                          cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["env_steps"] >= 32 and len(summary["rollouts_by_node"]) == 1 and summary["worker_deaths"] == 0
    assert token_file.exists() == token_before      # its token lives in its environment, not in ~/.ray
