"""End-to-end tests against the real `adp learner`: Python actors train a run to its budget
with every episode's checksum verified, over plain gRPC and TLS; a killed actor, a learner
restart, a lost lease and refused data are handled."""

import datetime
import ipaddress
import json
import os
import signal
import struct
import subprocess
import time

import grpc
import numpy as np
import pytest

import adp_client
import adp_client.toy
from adp_client import ConfigError, Connection, MlpPolicy, Session, StepsRefused
from adp_client._proto import adp_pb2 as pb
from adp_client.actor import _Reconnect

from conftest import Learner, adp_bin, free_port, refused, spawn_actor, wait_exit, wait_for


def rank_steps(s, rank):
    """The steps of `rank` in status `s` (0 before the first status)."""
    return dict((r, n) for r, n in (s or {}).get("rank_steps", [])).get(rank, 0)


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """Three Python actors, one killed with SIGKILL mid-run; the run finishes."""
    d = tmp_path_factory.mktemp("trained")
    learner = Learner(d, steps=500)
    actors = [spawn_actor(learner.addr, learner.token, r, d / f"actor{r}.log") for r in range(3)]
    try:
        wait_for("steps from the Python actors",
                 lambda: (s := learner.status()) and s["steps_received"] >= 150 and s["episodes_verified"] >= 1)
        # Kill actor 2, at best mid-episode (while its step count moves). One that has done its
        # two episodes idles without a lease until the next cycle, and then none expires.
        last = [rank_steps(learner.status(), 2)]

        def streaming():
            now = rank_steps(learner.status(), 2)
            moved, last[0] = now > last[0], now
            return moved or learner.proc.poll() is not None

        wait_for("actor 2 streaming steps", streaming, poll=0.2)
        actors[2].send_signal(signal.SIGKILL)
        actors[2].wait()
        wait_for("the killed actor's lease to expire, or the run to end",
                 lambda: (s := learner.status()) and s["leases_expired"] >= 1 or learner.proc.poll() is not None)
        before = learner.status()["steps_received"]
        wait_for("training to go on", lambda: learner.status()["steps_received"] > before + 30
                 or learner.proc.poll() is not None)
        s = learner.wait_finished()
        codes = [wait_exit(a, f"actor {r} to exit") for r, a in enumerate(actors[:2])]
        return dict(dir=d, status=s, codes=codes, logs=[(d / f"actor{r}.log").read_text() for r in range(2)])
    finally:
        for a in actors:
            if a.poll() is None:
                a.kill()
                a.wait()
        learner.stop()


def test_python_actors_train_to_the_budget_with_verified_checksums(trained):
    s = trained["status"]
    assert trained["codes"] == [0, 0], trained["logs"]
    assert s["finished"] and s["inserts"] >= s["budget"] == 500, s
    assert s["episodes_verified"] > 0 and s["episodes_mismatched"] == 0, s
    # Every reported episode was verified; the killed actor's open episode is abandoned.
    assert s["episodes_verified"] == s["episodes"], s
    assert s["episodes_abandoned"] <= s["leases_expired"] <= 1, s
    assert s["policy_version"] >= 2, s
    # Only the killed actor's late records are refused: steps it sent before the kill that were
    # still queued behind the rate limiter when its lease expired.
    assert {k for k, v in s["refused"] if v} <= {"invalid_lease"}, s["refused"]
    expired = {e["lease"] for e in s["leases_expired_recent"]}
    assert all(r["lease"] in expired for r in s["refused_leases"]), s
    # The two surviving actors registered with this learner (and exited 0 when the run was
    # over, above).
    assert {0, 1} <= {r["rank"] for r in s["ranks"] if r["registrations"] >= 1}, s["ranks"]
    export = trained["dir"] / "run" / "export"
    for f in ("policy.onnx", "policy.safetensors", "policy.json"):
        assert (export / f).is_file(), f


def read_safetensors(path):
    raw = path.read_bytes()
    (n,) = struct.unpack("<Q", raw[:8])
    header = json.loads(raw[8:8 + n])
    data = raw[8 + n:]
    out = {}
    for name, t in header.items():
        if name == "__metadata__":
            continue
        assert t["dtype"] == "F32", t
        a, b = t["data_offsets"]
        out[name] = np.frombuffer(data[a:b], dtype="<f4").reshape(t["shape"])
    return out


def test_numpy_policy_equals_the_exported_onnx_model(trained):
    import onnxruntime as ort

    export = trained["dir"] / "run" / "export"
    card = json.loads((export / "policy.json").read_text())
    dims = card["network"]["layer_sizes"]
    tensors = read_safetensors(export / "policy.safetensors")
    # The wire layout: per layer, W as [in][out] row-major, then the bias.
    flat = np.concatenate([np.concatenate([tensors[f"layers.{i}.weight"].T.ravel(), tensors[f"layers.{i}.bias"]])
                           for i in range(len(dims) - 1)]).astype("<f4")
    net = MlpPolicy(dims, flat.tobytes())
    rng = np.random.default_rng(17)
    obs = rng.uniform(-1, 1, (100, dims[0])).astype(np.float32)
    obs[:, 720:] = rng.normal(0, 1, (100, dims[0] - 720))
    sess = ort.InferenceSession(str(export / "policy.onnx"))
    want = sess.run([card["network"]["onnx_output"]], {card["network"]["onnx_input"]: obs})[0]
    got = net.act(obs)
    single = np.stack([net.act(o) for o in obs])
    err = float(np.max(np.abs(got - want)))
    print(f"numpy vs ONNX max abs error over 100 observations: {err:.3g}")
    assert err < 1e-5, err
    assert float(np.max(np.abs(single - want))) < 1e-5
    assert np.std(want) > 0, "a constant policy proves little"


def make_ca(d):
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import NameOID

    now = datetime.datetime.now(datetime.timezone.utc)

    def name(cn):
        return x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, cn)])

    ca_key = ec.generate_private_key(ec.SECP256R1())
    ca = (x509.CertificateBuilder().subject_name(name("adp test CA")).issuer_name(name("adp test CA"))
          .public_key(ca_key.public_key()).serial_number(x509.random_serial_number())
          .not_valid_before(now - datetime.timedelta(days=1)).not_valid_after(now + datetime.timedelta(days=2))
          .add_extension(x509.BasicConstraints(ca=True, path_length=None), critical=True)
          .add_extension(x509.KeyUsage(digital_signature=True, content_commitment=False, key_encipherment=False,
                                       data_encipherment=False, key_agreement=False, key_cert_sign=True,
                                       crl_sign=True, encipher_only=False, decipher_only=False), critical=True)
          .sign(ca_key, hashes.SHA256()))
    key = ec.generate_private_key(ec.SECP256R1())
    cert = (x509.CertificateBuilder().subject_name(name("localhost")).issuer_name(ca.subject)
            .public_key(key.public_key()).serial_number(x509.random_serial_number())
            .not_valid_before(now - datetime.timedelta(days=1)).not_valid_after(now + datetime.timedelta(days=2))
            .add_extension(x509.SubjectAlternativeName([x509.DNSName("localhost"),
                                                        x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]),
                           critical=False)
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(x509.ExtendedKeyUsage([x509.oid.ExtendedKeyUsageOID.SERVER_AUTH]), critical=False)
            .sign(ca_key, hashes.SHA256()))
    (d / "ca.pem").write_bytes(ca.public_bytes(serialization.Encoding.PEM))
    (d / "server.pem").write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    (d / "server.key").write_bytes(key.private_bytes(serialization.Encoding.PEM,
                                                     serialization.PrivateFormat.PKCS8,
                                                     serialization.NoEncryption()))
    os.chmod(d / "server.key", 0o600)


def test_two_python_actors_over_tls(tmp_path):
    make_ca(tmp_path)
    tls = f'\n[service.tls]\ncert = "{tmp_path / "server.pem"}"\nkey = "{tmp_path / "server.key"}"\n'
    learner = Learner(tmp_path, steps=300, tls=tls)
    try:
        # Without the CA the handshake fails: the client refuses the learner's certificate.
        plain = Connection(learner.addr, token_file=learner.token)
        with pytest.raises(grpc.RpcError):
            Session(plain, 0, print)
        plain.close()
        actors = [spawn_actor(learner.addr, learner.token, r, tmp_path / f"actor{r}.log",
                              ["--tls-ca", str(tmp_path / "ca.pem")]) for r in range(2)]
        s = learner.wait_finished()
        codes = [wait_exit(a, "actor exit") for a in actors]
        assert codes == [0, 0], [(tmp_path / f"actor{r}.log").read_text() for r in range(2)]
        assert s["inserts"] >= 300 and s["episodes_verified"] == s["episodes"] > 0, s
        assert s["episodes_mismatched"] == 0 and s["policy_version"] >= 2, s
        assert (learner.run / "export" / "policy.onnx").is_file()
    finally:
        learner.stop()


def test_actor_reconnects_to_a_restarted_learner(tmp_path):
    listen = f"127.0.0.1:{free_port()}"
    every = "checkpoint_every_s = 2.0\n"
    learner = Learner(tmp_path, steps=500, listen=listen, service=every)
    actor = spawn_actor(learner.addr, learner.token, 0, tmp_path / "actor.log", ["--give-up-after", "300"])
    ckpts = learner.run / "checkpoints"
    try:
        wait_for("steps and a checkpoint with steps in it",
                 lambda: (s := learner.status()) and s["inserts"] >= 150 and ckpts.is_dir()
                 and any(not c.name.startswith("ckpt-000000000000-") and ".tmp" not in c.name
                         for c in ckpts.iterdir()))
        first = learner.status()
        # kill -9: no final checkpoint, no shutdown for the actor, which must keep trying.
        learner.proc.send_signal(signal.SIGKILL)
        learner.proc.wait()
        learner.log.close()
        # The actor keeps trying while no learner answers (it has --give-up-after 300).
        time.sleep(3)  # an observation window, not a limit
        assert actor.poll() is None, (tmp_path / "actor.log").read_text()
        learner = Learner(tmp_path, steps=500, listen=listen, resume=True, service=every)
        s = learner.wait_finished()
        assert wait_exit(actor, "actor exit") == 0, (tmp_path / "actor.log").read_text()
        # The same actor process registered with the resumed learner (counted per learner).
        assert any(r["rank"] == 0 and r["registrations"] >= 1 for r in s["ranks"]), s["ranks"]
        assert s["run_id"] == first["run_id"] and s["incarnation"] != first["incarnation"], (s, first)
        assert s["inserts"] >= 500 and s["episodes_mismatched"] == 0, s
        assert s["episodes_verified"] > 0, s
    finally:
        if actor.poll() is None:
            actor.kill()
            actor.wait()
        learner.stop()


def test_lease_loss_and_refused_data(tmp_path):
    learner = Learner(tmp_path, steps=100000)
    actors = [spawn_actor(learner.addr, learner.token, r, tmp_path / f"actor{r}.log") for r in range(2)]
    try:
        wait_for("steps", lambda: (s := learner.status()) and s["episodes_verified"] >= 2)
        # Freeze one actor (heartbeats included) past the lease TTL: the learner expires its
        # lease; when it wakes it drops the assignment (or registers again) and goes on.
        actors[1].send_signal(signal.SIGSTOP)
        # It may hold a lease (which expires) or be idle between cycles (the learner retires it).
        wait_for("the learner to give up on the frozen actor",
                 lambda: (s := learner.status())["leases_expired"] >= 1 or s["live_actors"] <= 1)
        time.sleep(0.5)  # let it stay frozen a little past expiry (not a limit)
        actors[1].send_signal(signal.SIGCONT)
        verified = learner.status()["episodes_verified"]
        steps1 = dict((r, n) for r, n in learner.status()["rank_steps"]).get(1, 0)
        wait_for("the thawed actor to deliver verified episodes again",
                 lambda: (s := learner.status())["episodes_verified"] > verified + 2
                 and dict((r, n) for r, n in s["rank_steps"]).get(1, 0) > steps1 + 40)
        assert actors[1].poll() is None, (tmp_path / "actor1.log").read_text()

        # Refused data: a record with a NaN observation and one of the wrong length.
        conn = Connection(learner.addr, token_file=learner.token)
        sess = Session(conn, 99, print)
        try:
            a = wait_for("an assignment", lambda: (x := sess.next_assignment()) and not isinstance(x, int) and x)
            dim = sess.info.obs_dim
            nan = np.full(dim, 0.5, np.float32)
            nan[3] = np.nan
            for obs in (nan, np.zeros(dim - 1, np.float32)):
                sess.send(a.lease_id, pb.StepRecord(episode_id=a.first_episode_id, obs=obs.tobytes(),
                                                    action=np.zeros(sess.info.act_dim, np.float32).tobytes()))
            with pytest.raises(StepsRefused) as e:
                sess.flush()
            assert (e.value.refused, e.value.sent) == (2, 2)
            assert "not finite" in e.value.reason, e.value.reason
            # Without its own actor secret a request naming this actor is refused
            # (UNAUTHENTICATED) and its lease is kept.
            assert len(sess.secret) == 16
            good, sess.secret = sess.secret, bytes(16)
            with pytest.raises(_Reconnect, match="UNAUTHENTICATED"):
                sess.next_assignment()
            sess.secret = good
            # A request for an older incarnation is refused: the client re-registers.
            sess.run.incarnation ^= 1
            with pytest.raises(_Reconnect, match="FAILED_PRECONDITION"):
                sess.next_assignment()
        finally:
            sess.close()
            conn.close()
        wait_for("refusals in status.json", lambda: (s := learner.status()) and refused(s, "not_finite") == 1
                 and refused(s, "bad_shape") == 1 and refused(s, "unauthenticated") >= 1)
        # A wrong token is a clear configuration error, not a retry loop.
        bad = tmp_path / "bad-token"
        bad.write_text("not-the-token\n")
        os.chmod(bad, 0o600)
        with pytest.raises(ConfigError, match="refused the token"):
            adp_client.Actor(learner.addr, adp_client.toy.PointWorld(), token_file=bad).run()
        loose = tmp_path / "loose-token"
        loose.write_text("x\n")
        os.chmod(loose, 0o644)
        with pytest.raises(ConfigError, match="chmod 600"):
            adp_client.Actor(learner.addr, adp_client.toy.PointWorld(), token_file=loose)
    finally:
        learner.stop()
        for a in actors:
            wait_exit(a, "actors to leave after the learner stops")
        s = learner.status()
        assert s["episodes_mismatched"] == 0, s
    codes = [a.returncode for a in actors]
    logs = [(tmp_path / f"actor{r}.log").read_text() for r in range(2)]
    assert codes == [0, 0], logs


def test_mixed_fleet_counts_per_actor_kind(tmp_path):
    """A Rust actor (`adp actor`) and a Python actor in the same run: status.json counts
    registrations, live actors, episodes and steps per actor kind."""
    learner = Learner(tmp_path, steps=400)
    rust_log = open(tmp_path / "rust-actor.log", "w")
    rust = subprocess.Popen(
        [str(adp_bin()), "actor", "--learner", learner.addr, "--data-plane", "grpc", "--rank", "1",
         "--token-file", str(learner.token)],
        stdout=rust_log, stderr=subprocess.STDOUT,
    )
    python = spawn_actor(learner.addr, learner.token, 0, tmp_path / "python-actor.log")

    def kinds(s):
        return {k["kind"]: k for k in (s or {}).get("actor_kinds", [])}

    try:
        wait_for("both kinds registered and live",
                 lambda: (k := kinds(learner.status())) and all(
                     k.get(kind, {}).get("active") == 1 for kind in ("rust", "python")))
        wait_for("episodes from both kinds",
                 lambda: (k := kinds(learner.status())) and all(
                     k.get(kind, {}).get("episodes", 0) >= 1 for kind in ("rust", "python")))
        s = learner.wait_finished()
        assert wait_exit(python, "the Python actor to exit") == 0, (tmp_path / "python-actor.log").read_text()
        assert wait_exit(rust, "the Rust actor to exit") == 0, (tmp_path / "rust-actor.log").read_text()
    finally:
        for p in (rust, python):
            if p.poll() is None:
                p.kill()
                p.wait()
        rust_log.close()
        learner.stop()
    k = kinds(s)
    assert set(k) == {"rust", "python"}, s["actor_kinds"]
    for kind in ("rust", "python"):
        assert k[kind]["registered"] >= 1 and k[kind]["steps"] > 0 and k[kind]["episodes"] >= 1, k
    # Every stored step and every accepted episode is counted under exactly one kind.
    assert sum(x["steps"] for x in k.values()) == s["steps_received"], s
    assert sum(x["episodes"] for x in k.values()) == s["episodes"], s
    assert s["episodes_mismatched"] == 0, s


def test_grpcio_over_the_unix_socket_needs_no_default_authority(tmp_path):
    """grpc-core sends the socket's percent-encoded path as `:authority` on `unix:PATH`
    (`tmp%2F...%2Flearner.sock`), which the learner's HTTP/2 library refused (the call failed
    with INTERNAL "Stream removed") unless the client set `grpc.default_authority`. The learner
    rewrites it: a session registers, gets work and heartbeats; `status.json` counts the
    rewrite. A second session naming the first as its previous registration retires it."""
    learner = Learner(tmp_path, steps=100000)
    try:
        conn = Connection(f"unix:{learner.run / 'learner.sock'}", token_file=learner.token)
        try:
            first = Session(conn, 3, print)
            work = wait_for("an assignment", lambda: (x := first.next_assignment()) and not isinstance(x, int) and x)
            assert work.lease_id > 0
            second = Session(conn, 3, print, previous=(first.actor_id, first.secret))
            assert second.actor_id != first.actor_id
            with pytest.raises(_Reconnect, match="NOT_FOUND"):
                first.next_assignment()
            second.close()
            first.close()
        finally:
            conn.close()
        wait_for("the rewrites in status.json",
                 lambda: (s := learner.status()) and s["connections"]["authorities_rewritten"] >= 1)
    finally:
        learner.stop()
