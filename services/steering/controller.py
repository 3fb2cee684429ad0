"""The steering controller: the threaded runner around the pure core (`core.SteeringCore`).

No zenoh here: the service hands it payloads and publishes what it returns. The decisions
are the core's; this module owns what the core must not: the clock, the drive's I/O and
the threads.

- The control thread, every SYNC period: `control_step` reads the drive, gives the core a
  tick, sends the frames it returns (host heartbeat + setpoint RPDO + SYNC, stops) and
  publishes the state at its own rate.
- The worker thread does what blocks on the drive (opening the link, SDO configuration,
  writing the calibrated limits) and tells the core how it went.
- Requests are decided at once in the caller's thread (a zenoh callback): parsing and
  judging take microseconds and send at most a frame or two, so nothing queues behind
  anything. An arm is answered later, from the control thread, once the drive's DS402
  steps are done; an estop, like everything, acts at once.
- EMCY and boot-up messages (canopen's receive thread) go to the core at once.

One lock keeps the core and the frames in order: a setpoint sent meanwhile is never
overtaken by an older target. Replies go out after the lock is released.
"""
from __future__ import annotations

import logging
import queue
import threading
from collections.abc import Callable
from typing import Any

from viena.common import clock as clocks
from viena.services.steering.driver.emcy import Emcy, emcy_name
from viena.services.steering.driver.epos import DriveError, EposDrive
from viena.services.steering.model.actions import (
    JOBS,
    Command,
    Configure,
    Connect,
    Cycle,
    DriveReading,
    Reply,
    SendTarget,
    WriteLimits,
)
from viena.services.steering.model.calibration import Calibration, CalibrationSettings
from viena.services.steering.model.core import ControllerSettings, Phase, SteeringCore
from viena.services.steering.model.requests import Request, parse_request
from viena.services.steering.model.safety import REJECTED, Envelope
from viena.services.steering.model.state import sample

__all__ = ["ControllerSettings", "Phase", "SteeringController"]

log = logging.getLogger("viena.steering")

ReplyFn = Callable[[dict], None]
_QUIT = object()


class SteeringController:
    """Runs a SteeringCore against an EposDrive, on the real clock by default."""

    def __init__(self, drive: EposDrive, envelope: Envelope,
                 calibration: CalibrationSettings = CalibrationSettings(),
                 settings: ControllerSettings = ControllerSettings(),
                 on_state: Callable[[dict], None] | None = None,
                 clock: Callable[[], float] = clocks.monotonic,
                 wall_ns: Callable[[], int] = clocks.time_ns):
        self.drive = drive
        self.core = SteeringCore(envelope, calibration, settings, drive.settings)
        self.settings = settings
        self.on_state = on_state
        self._clock, self._wall_ns = clock, wall_ns
        self._lock = threading.Lock()
        self._jobs = clocks.Queue()
        self._waiting: dict[object, ReplyFn] = {}          # arms answered later, by token
        self._answers: list[tuple[ReplyFn, dict]] = []     # sent once the lock is released
        self._next_state = float("-inf")
        self._seq = 0                                      # states made so far
        self._stop = clocks.Event()
        self._threads: list[Any] = []
        drive.add_emcy_listener(self._on_emcy)
        drive.add_bootup_listener(self._on_bootup)

    # -- what callers read -----------------------------------------------------------------
    @property
    def envelope(self) -> Envelope:
        return self.core.envelope

    @property
    def phase(self) -> Phase:
        return self.core.phase

    @property
    def calibration(self) -> Calibration | None:
        return self.core.calibration

    @property
    def link_ok(self) -> bool:
        return self.core.link_ok

    def state(self) -> dict:
        """The `viena.steering.state/1` sample, now."""
        now = self._clock()
        with self._lock:
            self._seq += 1
            return sample(self.core, now, self._wall_ns(), self._read(now), self._seq)

    # -- life ------------------------------------------------------------------------------
    def start(self, threads: bool = True) -> None:
        """Connect to the drive; `threads=False` leaves the stepping to the caller
        (`control_step`, `run_jobs`), as tests on a simulated clock do."""
        self._event(self.core.start)
        if not threads:
            return
        for name, target in (("steering-control", self._control_loop), ("steering-worker", self._work_loop)):
            t = clocks.Thread(target=target, name=name, daemon=True)
            t.start()
            self._threads.append(t)

    def stop(self) -> None:
        """Stop the wheel (if it was armed), then the threads, then the drive."""
        now = self._clock()
        with self._lock:
            actions, hold_s = self.core.shutdown(now)
            self._perform(actions, now)
        self._deliver()
        if hold_s and self._threads:
            clocks.sleep(hold_s)             # the control loop sends the power-off meanwhile
        self._stop.set()
        self._jobs.put(_QUIT)
        for t in self._threads:
            t.join(timeout=1.0)
        with self._lock:
            for frame in self.core.power_off():
                try:
                    self._send(frame)
                except Exception as exc:
                    log.debug("final disable: %s", exc)
        self.drive.close()

    # -- requests --------------------------------------------------------------------------
    def submit(self, kind: str, payload, reply: ReplyFn | None = None) -> None:
        """Decide an 'arm', 'setpoint', 'calibration' or 'estop' request now; `reply` gets
        the answer (an arm's once the drive is enabled)."""
        answer = self._decide(parse_request(kind, payload), reply)
        if answer is not None and reply is not None:
            _call(reply, answer)

    def request(self, kind: str, payload, timeout: float = 2.0) -> dict:
        """submit() and wait for the answer (for tests and the bench)."""
        box = clocks.Queue()
        self.submit(kind, payload, box.put)
        return box.get(timeout=timeout)

    def estop(self, payload=None) -> dict:
        """Quick stop now, whoever asks and whatever they send (a `by` in it is logged); disarms."""
        answer = self._decide(parse_request("estop", payload), None)
        if answer is None:                       # only an arm answers later
            raise RuntimeError("an estop gave no answer")
        return answer

    def _decide(self, request: Request, reply: ReplyFn | None) -> dict | None:
        token = object()
        now = self._clock()
        with self._lock:
            try:
                answer, actions = self.core.handle(request, now, self._wall_ns(), self._read(now), token)
            except Exception as exc:          # a bug must not take the service down; say so
                log.exception("%s failed", type(request).__name__)
                answer, actions = _rejected(f"internal error: {exc}"), []
            if answer is None and reply is not None:
                self._waiting[token] = reply
            lost = self._perform(actions, now)
        self._deliver()
        return _rejected(f"CAN link lost: {lost}") if lost and answer is not None else answer

    def speed(self, source: str, t_ns: int, speed_mps: float, sigma_mps: float, valid: bool) -> str:
        """A speed for the envelope from `source` ("estimator", or a GNSS unit's name); the
        cause it was refused for, or "" (model/speed.py)."""
        now, wall_ns = self._clock(), self._wall_ns()
        with self._lock:
            sources = self.core.envelope.speeds
            if source == "estimator":
                return sources.estimator(t_ns, speed_mps, sigma_mps, valid, now, wall_ns)
            return sources.gnss(source, t_ns, speed_mps, sigma_mps, valid, now, wall_ns)

    # -- the control thread ----------------------------------------------------------------
    def _control_loop(self) -> None:
        period = self.drive.settings.sync_period_s
        next_t = clocks.monotonic()
        while not self._stop.is_set():
            self.control_step()
            next_t += period
            delay = next_t - clocks.monotonic()
            if delay > 0.05:                     # a long period (a setting): stop() must not wait it out
                self._stop.wait(delay)
            elif delay > 0:
                clocks.sleep(delay)              # a plain sleep: stop() waits a period at most
            elif delay < -10 * period:           # fell far behind (suspended): resync
                next_t = clocks.monotonic()

    def control_step(self) -> None:
        """One SYNC period: the core's tick and its frames, and the state when it is due."""
        now = self._clock()
        with self._lock:
            try:
                actions = self.core.tick(now, self._read(now))
            except Exception as exc:             # a stop on the safe side: trip, reconnect
                log.exception("control step failed")
                actions = self.core.link_lost(now, str(exc))
            self._perform(actions, now)
            publish = self.on_state is not None and now >= self._next_state
            if publish:
                self._next_state = max(self._next_state + 1.0 / self.settings.state_rate_hz,
                                       now - self.drive.settings.sync_period_s)
        self._deliver()
        if publish and self.on_state is not None:
            try:
                self.on_state(self.state())
            except Exception:
                log.exception("state callback failed")

    # -- the worker ------------------------------------------------------------------------
    def _work_loop(self) -> None:
        while True:
            job = self._jobs.get()
            if job is _QUIT:
                return
            try:
                self.work(job)
            except Exception:                    # a bug must not kill the worker; say so
                log.exception("%s failed", type(job).__name__)

    def run_jobs(self) -> None:
        """Do the waiting blocking jobs now, in this thread (tests on a simulated clock)."""
        while True:
            try:
                job = self._jobs.get_nowait()
            except queue.Empty:
                return
            if job is not _QUIT:
                self.work(job)

    def work(self, job: Connect | Configure | WriteLimits) -> None:
        """Do one blocking job on the drive and tell the core how it went."""
        if isinstance(job, Connect):
            self._event(self.core.connected, self._open())
        elif isinstance(job, Configure):
            self._event(self.core.configured, *self._configure())
        else:
            self._event(self.core.limits_written, job.calibration, self._write_limits(job.calibration))

    def _open(self) -> str:
        self.drive.close()
        try:
            self.drive.open()
        except Exception as exc:
            log.warning("CAN interface %s %s: %s", self.drive.settings.interface,
                        self.drive.settings.channel, exc)
            return str(exc) or type(exc).__name__
        return ""

    def _configure(self) -> tuple[str, str, tuple[str, ...]]:
        """("", "", history) when configured; (why, "", ()) when the drive refused or did
        not answer; ("", why, ()) when the link itself went away. `history` names the
        drive's last errors (0x1003), newest first."""
        try:
            self.drive.configure(limits_qc=None)
        except DriveError as exc:
            return str(exc), "", ()
        except Exception as exc:
            return "", str(exc) or type(exc).__name__, ()
        try:
            history = tuple(emcy_name(code) for code in self.drive.error_history())
        except DriveError as exc:
            log.warning("could not read the drive's error history: %s", exc)
            history = ()
        return "", "", history

    def _write_limits(self, cal: Calibration) -> str:
        try:
            self.drive.set_position_limits(cal.limits_qc())
        except Exception as exc:
            return str(exc) or type(exc).__name__
        return ""

    # -- events from the drive (canopen's receive thread) ----------------------------------
    def _on_emcy(self, emcy: Emcy) -> None:
        self._event(self.core.on_emcy, emcy)

    def _on_bootup(self) -> None:
        self._event(self.core.on_bootup)

    # -- doing what the core says ----------------------------------------------------------
    def _event(self, decide: Callable[..., list], *args) -> None:
        """Give the core one event at the current time, and do what it returns."""
        now = self._clock()
        with self._lock:
            self._perform(decide(now, *args), now)
        self._deliver()

    def _read(self, now: float) -> DriveReading:
        return DriveReading(self.drive.feedback(), self.drive.heartbeat_age(now), self.drive.heartbeat_state)

    def _perform(self, actions: list, now: float) -> str:
        """Frames now, in order (only while the link is up); jobs to the worker; replies once
        the lock is released. Returns why the link failed if a frame could not go."""
        lost = ""
        for action in actions:
            if isinstance(action, Reply):
                reply = self._waiting.pop(action.token, None)
                if reply is not None:
                    self._answers.append((reply, action.answer))
            elif isinstance(action, JOBS):
                self._jobs.put(action)
            elif self.core.link_ok:
                try:
                    self._send(action)
                except Exception as exc:
                    lost = str(exc) or type(exc).__name__
                    self._perform(self.core.link_lost(now, lost), now)
        return lost

    def _send(self, frame: Command | SendTarget | Cycle) -> None:
        if isinstance(frame, Cycle):
            self.drive.cycle(frame.target_qc)
        elif isinstance(frame, SendTarget):
            self.drive.send_target(frame.target_qc, frame.controlword)
        else:
            self.drive.command(frame.controlword)

    def _deliver(self) -> None:
        with self._lock:
            answers, self._answers = self._answers, []
        # Each popped, so no reference stays here: a zenoh query is answered for good (its
        # final reply sent) only when the last reference to it goes.
        while answers:
            _call(*answers.pop(0))


def _call(reply: ReplyFn, answer: dict) -> None:
    try:
        reply(answer)
    except Exception:
        log.exception("reply failed")


def _rejected(reason: str) -> dict:
    return {"status": REJECTED, "reason": reason}
