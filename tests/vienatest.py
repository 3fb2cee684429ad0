"""What tests share besides fixtures: processes that are always cleaned up, the `viena`
command and the sim profile, collecting samples, and waits on readiness (a condition, a
port, a log line, a subscriber the router knows) instead of fixed sleeps. Imported as
`vienatest` (a unique name: every tests/ folder sees it)."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from contextlib import contextmanager
from pathlib import Path

from benchmarks.harness import free_port, wait_for_port  # noqa: F401  (tests import them from here)

PYTHON = sys.executable
VIENA = [PYTHON, "-m", "viena.cli"]


class Processes:
    """Starts subprocesses and guarantees they are gone at the end of the test."""

    def __init__(self):
        self.procs: list[subprocess.Popen] = []

    def start(self, *args: str, **kw) -> subprocess.Popen:
        kw.setdefault("stdout", subprocess.PIPE)
        kw.setdefault("stderr", subprocess.PIPE)
        kw.setdefault("text", True)
        proc = subprocess.Popen([str(a) for a in args], **kw)
        self.procs.append(proc)
        return proc

    def python(self, *args: str, **kw) -> subprocess.Popen:
        return self.start(PYTHON, *args, **kw)

    def stop_all(self) -> None:
        for proc in self.procs:
            if proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
        for proc in self.procs:
            try:
                proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


def start_router(procs: Processes) -> str:
    """A `viena router` on a free loopback port, started by `procs`; its endpoint once it
    listens."""
    port = free_port()
    procs.python("-m", "viena.router", "--listen", f"tcp/127.0.0.1:{port}", "--log-level", "WARNING")
    wait_for_port(port)
    return f"tcp/127.0.0.1:{port}"


def open_session(router: str):
    """A zenoh client session on the router at endpoint `router` (close it, or use `with`)."""
    import zenoh

    from viena.common.config import load_zenoh_config
    return zenoh.open(load_zenoh_config(mode="client", connect=[router]))


def viena(*args, timeout: float = 60, **kw) -> subprocess.CompletedProcess:
    """`viena ARGS...` run to its end, its output captured as text."""
    return subprocess.run([*VIENA, *map(str, args)], capture_output=True, text=True,
                          timeout=timeout, **kw)


@contextmanager
def sim_profile_up(run: Path, flags: tuple[str, ...] = (), **environment: str):
    """The `sim` profile under supervisord (`viena up -d --free-ports`, and `flags`), its run
    directory `run`, with `environment` added to its programs' (the profile's ${VAR}
    settings): yields (environment, router endpoint) once the router listens (supervisord
    calls a program RUNNING before that), and brings the profile down at the end."""
    env = dict(os.environ, VIENA_RUN=str(run), **environment)
    env.pop("VIENA_ROUTER_PORT", None)
    up = viena("up", "--profile", "sim", "-d", "--free-ports", *flags, env=env, timeout=120)
    try:
        assert up.returncode == 0, up.stderr
        port = int(json.loads((run / "env.json").read_text())["VIENA_ROUTER_PORT"])
        wait_for_port(port)
        yield env, f"tcp/127.0.0.1:{port}"
    finally:
        viena("down", "--profile", "sim", env=env)


def supervisor(run: Path):
    """supervisord's XML-RPC interface of the profile running in `run`."""
    import xmlrpc.client

    from supervisor.xmlrpc import SupervisorTransport

    transport = SupervisorTransport(None, None, f"unix://{run}/supervisor.sock")
    return xmlrpc.client.ServerProxy("http://127.0.0.1", transport=transport).supervisor


def collect(session, keyexpr: str, count: int, timeout: float = 10.0, decode=None) -> list:
    """The first `count` samples on keyexpr (decoded by `decode` if given)."""
    return collect_until(session, keyexpr, lambda out: len(out) >= count, timeout, decode)


def collect_until(session, keyexpr: str, done: Callable[[list], bool], timeout: float = 10.0,
                  decode=None) -> list:
    """Samples on keyexpr (decoded by `decode` if given, else (key, payload, encoding))
    until `done(samples)` says enough, or `timeout` s pass."""
    import queue

    q: queue.Queue = queue.Queue()
    sub = session.declare_subscriber(keyexpr, lambda s: q.put((str(s.key_expr), s.payload.to_bytes(), str(s.encoding))))
    out = []
    end = time.monotonic() + timeout
    try:
        while not done(out) and time.monotonic() < end:
            try:
                key, payload, enc = q.get(timeout=0.1)
            except queue.Empty:
                continue
            out.append(decode(payload) if decode else (key, payload, enc))
    finally:
        sub.undeclare()
    return out


def wait_until(predicate: Callable[[], bool], timeout: float, period: float = 0.01) -> bool:
    """Poll `predicate` until true or `timeout` s pass; for tests and start-up waits."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if predicate():
            return True
        time.sleep(period)
    return bool(predicate())


def wait_for_line(stream, text: str, timeout: float = 20.0) -> str:
    """Read lines of a subprocess pipe until one contains `text` (a process saying it is
    ready, or what it is doing); that line."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        line = stream.readline()
        if text in line:
            return line
        if not line:                # the pipe is closed: nothing more will come
            break
    raise TimeoutError(f"no line with {text!r}")


def wait_for_subscriber(session, keyexpr: str, timeout: float = 10.0) -> bool:
    """Until the router has told `session` of a subscriber on keyexpr in another session
    or process: from then on a put on keyexpr, from any client of that router, reaches
    it. (A subscriber in `session` itself matches at once: pass another session.)"""
    publisher = session.declare_publisher(keyexpr)
    try:
        return wait_until(lambda: publisher.matching_status.matching, timeout)
    finally:
        publisher.undeclare()


def wait_for_queryable(session, keyexpr: str, timeout: float = 10.0) -> bool:
    """Until the router has told `session` of a queryable on keyexpr elsewhere, so that a
    query from `session` reaches it."""
    querier = session.declare_querier(keyexpr)
    try:
        return wait_until(lambda: querier.matching_status.matching, timeout)
    finally:
        querier.undeclare()



#: EPOS twin settings (TwinSettings) whose person sweeps the wheel lock to lock in under a
#: second after power-up, so that a steering service on it calibrates quickly
FAST_SWEEP = {"sweep_speed_qc_s": 400_000.0, "sweep_delay_s": 0.1, "sweep_hold_s": 0.05}


def fast_sweeping_twin():
    """An EPOS twin behind an slcan hub (`start_twin_on_hub`) with FAST_SWEEP; stop it at
    the end."""
    from viena.services.steering.simulator import TwinSettings, start_twin_on_hub

    return start_twin_on_hub(TwinSettings(**FAST_SWEEP))


def steering_on(procs: Processes, router: str, twin, config: Path):
    """`viena-steering` (started by `procs`) on `twin`, its settings written to `config`:
    (process, ready), where `ready(state)` says whether a steering state is past its
    calibration, and lets the person at the wheel read it (they sweep again if the service
    threw a sweep away, as a stalled host makes it do)."""
    # a drive on a bench: no estimator, no speed assumed (the speed envelope has its own tests)
    config.write_text("[steering]\nsweep_settle_s = 0.2\nspeed_conservative_mps = 0.0\n")
    proc = procs.python("-m", "viena.services.steering.service", "--connect", router, "--config", config,
                        "--interface", "slcan", "--channel", twin.url, "--log-level", "WARNING")
    return proc, calibrated_with_a_person_at(twin.twin)


def calibrated_with_a_person_at(wheel) -> Callable[[dict], bool]:
    """`ready(state)`: whether a steering state is past its calibration. It lets a person
    at the wheel (an EposTwin) read the state too, who sweeps again if the steering threw a
    sweep away, as a stalled host makes it do."""
    from viena.services.steering.simulator import PersonAtTheWheel

    person = PersonAtTheWheel([wheel])

    def ready(state: dict) -> bool:
        person.read(state)
        return state["phase"] == "ready"
    return ready


def signed(payload, lease: str | None = None):
    """A setpoint as its owner sends it: `{"angle_deg": x, "lease": L}` (the form tests read
    best) becomes the signed setpoint (model/signing.py) with a fresh seq, keeping its other
    fields (`t`, unknown ones) so the envelope still sees what the test meant. `lease` signs
    a payload without one. Anything that is not such a map comes back as it is."""
    from viena.services.steering.client import next_seq
    from viena.services.steering.model.signing import setpoint_mac

    if not isinstance(payload, dict):
        return payload
    lease = payload.get("lease", lease)
    if not isinstance(lease, str):
        return payload
    out = {k: v for k, v in payload.items() if k != "lease"}
    out.setdefault("seq", next_seq())
    unit = "rad" if "angle_rad" in out and "angle_deg" not in out else "deg"
    t = out.get("t") if isinstance(out.get("t"), int) else None
    try:
        out["mac"] = setpoint_mac(lease, unit, float(out.get(f"angle_{unit}")), out["seq"], t)
    except Exception:                             # noqa: BLE001  (struct.error among others)
        out["mac"] = "0" * 32                   # an angle no client could sign: refused before the code
    return out


class Hijacker:
    """A second pilot who reads every sample of the car (what `viena/<car>/**` gives any
    pilot or observer, and what `viena record` stores) and steers with whatever it saw:
    each setpoint sent again as it was, with the hijacker's angle, with a later seq or a
    fresh stamp, and every piece of text seen used as a lease, in the clear and as a key to
    sign with; by put and by query. `accepted` holds the queries answered accepted or
    clamped; what the puts did shows in the steering's state."""

    def __init__(self, session, car: str = "elettra", angle_deg: float = -25.0):
        self.session, self.prefix, self.angle_deg = session, f"viena/{car}", angle_deg
        self.setpoints: list[dict] = []
        self.texts: set[str] = set()
        self.raw: list[bytes] = []               # every sample's bytes, as a recording holds them
        self.goals: list[float | None] = []      # the steering's goal in every state seen meanwhile
        self.accepted: list[dict] = []
        self.sent = 0
        self.sub = session.declare_subscriber(f"{self.prefix}/**", self._on_sample)

    def _on_sample(self, sample) -> None:
        from viena.common.errors import PayloadError
        from viena.common.payload import parse_payload

        self.raw.append(sample.payload.to_bytes())
        try:
            value = parse_payload(self.raw[-1], max_bytes=1 << 20, max_depth=64)
        except PayloadError:
            return
        key = str(sample.key_expr)
        if key.endswith("/steering/setpoint"):
            self.setpoints.append(value)
        elif key.endswith("/steering/state"):
            self.goals.append(value.get("goal_deg"))
        self._collect_texts(value)

    def _collect_texts(self, value) -> None:
        if isinstance(value, dict):
            for item in (*value.keys(), *value.values()):
                self._collect_texts(item)
        elif isinstance(value, list):
            for item in value:
                self._collect_texts(item)
        elif isinstance(value, str) and 8 <= len(value) <= 64:
            self.texts.add(value)

    def forgeries(self) -> list[dict]:
        """Everything the hijacker can make of what it saw so far."""
        from viena.services.steering.client import next_seq
        from viena.services.steering.model.signing import signed_setpoint

        made: list[dict] = []
        for seen in self.setpoints[-10:]:
            made += [seen, {**seen, "angle_deg": self.angle_deg}, {**seen, "seq": next_seq()},
                     {**seen, "t": time.time_ns(), "seq": next_seq(), "angle_deg": self.angle_deg}]
        for text in sorted(self.texts)[:100]:
            made += [{"angle_deg": self.angle_deg, "lease": text},
                     signed_setpoint(text, self.angle_deg, seq=next_seq())]
        return made

    def attack(self) -> int:
        """One round: every forgery by put and by query; how many were sent."""
        forgeries = self.forgeries()
        key = f"{self.prefix}/steering/setpoint"
        for payload in forgeries:
            data = json.dumps(payload).encode()
            self.session.put(key, data)
            for reply in self.session.get(key, payload=data, timeout=2.0):
                if reply.ok is not None:
                    answer = json.loads(reply.ok.payload.to_bytes())
                    if answer.get("status") in ("accepted", "clamped"):
                        self.accepted.append({"sent": payload, "answer": answer})
        self.sent += 2 * len(forgeries)
        return len(forgeries)

    def hijack(self, rounds: int) -> None:
        """Once the owner's setpoints are seen, `rounds` rounds of attack."""
        assert wait_until(lambda: len(self.setpoints) >= 5, 10.0), "the owner's setpoint puts were not seen"
        for _ in range(rounds):
            assert self.attack() > 0

    def close(self) -> None:
        self.sub.undeclare()
