"""Helpers that run the real `adp learner` (target/release/adp, or $ADP_BIN) and Python actor
processes for the tests."""

import json
import os
import pathlib
import signal
import socket
import subprocess
import sys
import time

import pytest

REPO = pathlib.Path(__file__).resolve().parents[3]
# A watchdog, not a time limit: a wait that takes this long means the test hung.
WATCHDOG_S = float(os.environ.get("ADP_TEST_WATCHDOG_S", "600"))

CONFIG = """[env]
laser_clip_m = 2.5

[td3]
warmup_steps = 128
rate_tolerance = 64.0
# The short test runs train the actor from the first updates (no critic-only warm-up), so
# the exported policy is not the DDP-initialized constant.
actor_warmup_updates = 0

[service]
shared_memory = false
heartbeat_ms = 200
lease_ttl_ms = 2000
status_every_s = 0.2
{service}{tls}"""


def adp_bin() -> pathlib.Path:
    p = pathlib.Path(os.environ.get("ADP_BIN", REPO / "target" / "release" / "adp"))
    if not p.is_file():
        pytest.fail(f"the adp binary {p} is missing: build it with `cargo build --release` (or set ADP_BIN)")
    return p


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_for(what, pred, poll=0.1):
    """Polls `pred` until true; fails the test when the watchdog expires (a hang)."""
    end = time.monotonic() + WATCHDOG_S
    while time.monotonic() < end:
        v = pred()
        if v:
            return v
        time.sleep(poll)
    pytest.fail(f"watchdog: waited {WATCHDOG_S} s for {what}")


def status(run: pathlib.Path):
    try:
        return json.loads((run / "status.json").read_text())
    except (OSError, ValueError):
        return None


def refused(s, kind):
    return dict((k, v) for k, v in s["refused"]).get(kind, 0)


class Learner:
    """An `adp learner` process with its run directory."""

    def __init__(self, dir: pathlib.Path, steps: int, listen="127.0.0.1:0", tls="", resume=False, service=""):
        self.dir, self.run = dir, dir / "run"
        cfg = dir / "test.toml"
        cfg.write_text(CONFIG.format(tls=tls, service=service))
        args = [str(adp_bin()), "learner", "--config", str(cfg), "--steps", str(steps), "--listen", listen,
                "--out", str(self.run)]
        if resume:
            args.append("--resume")
        else:
            (self.run / "learner.addr").unlink(missing_ok=True)
        self.log_path = dir / ("learner-resumed.log" if resume else "learner.log")
        self.log = open(self.log_path, "w")
        self.proc = subprocess.Popen(args, stdout=self.log, stderr=subprocess.STDOUT)
        wait_for("learner.addr", lambda: (self.run / "learner.addr").is_file() or self.proc.poll() is not None)
        if self.proc.poll() is not None:
            pytest.fail(f"adp learner exited with {self.proc.returncode}: {self.log_path.read_text()}")
        self.addr = (self.run / "learner.addr").read_text().strip()
        self.token = self.run / "token"

    def status(self):
        return status(self.run)

    def wait_finished(self):
        wait_for("the learner to finish", lambda: self.proc.poll() is not None)
        assert self.proc.returncode == 0, self.log_path.read_text()
        return self.status()

    def stop(self):
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout=120)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self.log.close()


def spawn_actor(learner_addr, token, rank, log_path, extra=()):
    """A Python actor process (`python -m adp_client`) with the toy environment."""
    log = open(log_path, "w")
    return subprocess.Popen(
        [sys.executable, "-m", "adp_client", "--learner", learner_addr, "--token-file", str(token),
         "--rank", str(rank), *extra],
        stdout=log, stderr=subprocess.STDOUT,
    )


def wait_exit(proc, what):
    wait_for(what, lambda: proc.poll() is not None)
    return proc.returncode


@pytest.fixture
def workdir(tmp_path):
    return tmp_path
