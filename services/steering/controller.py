"""The steering controller: one owner of the drive, the envelope and the calibration.

No zenoh here: the service hands it parsed payloads and publishes what it returns, so the
whole policy runs in tests against the twin on a python-can virtual bus.

Threads:
- the control loop, every SYNC period: host heartbeat + setpoint RPDO + SYNC, watchdog and
  ramp (`Envelope.tick`), drive supervision (heartbeat, faults, feedback age), the
  calibration sweep, the state callback at its own rate;
- the worker, for everything that waits on the drive (SDO configuration, the DS402 steps of
  an arm) and for setpoints, so replies keep their order;
- `estop()` runs in the caller's thread at once: it only sends one frame and never waits.

Every stop (estop, watchdog, drive fault, disarm, service stop) is the same: quick stop now,
so the drive halts and holds the wheel, then power off after `quickstop_hold_s`.
"""
from __future__ import annotations

import logging
import queue
import threading
import time
from dataclasses import dataclass
from typing import Callable

from viena.services.steering.calibration import (Calibration, CalibrationRefused,
                                                 CalibrationSettings, SweepRecorder)
from viena.services.steering.driver import ds402
from viena.services.steering.driver.emcy import Emcy
from viena.services.steering.driver.epos import NMT_OPERATIONAL, POSITION_MODE, DriveError, EposDrive
from viena.services.steering.safety import ACCEPTED, REJECTED, Envelope

log = logging.getLogger("viena.steering")

CONNECTING, CALIBRATING, CHECKING, READY, ARMED = "connecting", "calibrating", "checking", "ready", "armed"
ARM_FIELDS = frozenset({"arm", "lease"})
MAX_WAITING = 256          # queued requests beyond this are refused at once (a flood)


@dataclass(frozen=True)
class ControllerSettings:
    quickstop_hold_s: float = 0.1      # quick stop, hold this long, then power off
    feedback_timeout_s: float = 0.2    # no TPDO for this long while armed: trip
    state_period_s: float = 0.02       # the state callback's period (50 Hz)
    arm_step_timeout_s: float = 0.3    # each DS402 step of an arm
    silent_drive_s: float = 1.0        # no heartbeat this long: configure (and calibrate) again
    reconnect_min_s: float = 0.5
    reconnect_max_s: float = 5.0


Reply = Callable[[dict], None]


class SteeringController:
    """Owns the drive; judges requests with the envelope; stops the wheel on every fault."""

    def __init__(self, drive: EposDrive, envelope: Envelope,
                 calibration: CalibrationSettings = CalibrationSettings(),
                 settings: ControllerSettings = ControllerSettings(),
                 on_state: Callable[[dict], None] | None = None,
                 clock: Callable[[], float] = time.monotonic):
        self.drive = drive
        self.envelope = envelope
        self.settings = settings
        self.cal_settings = calibration
        self.on_state = on_state
        self._clock = clock
        self._lock = threading.RLock()
        self._jobs: queue.Queue = queue.Queue()
        self._stop = threading.Event()
        self.phase = CONNECTING
        self.calibration: Calibration | None = None
        self.recorder = SweepRecorder(calibration)
        self.link_ok = False
        self.drive_alive = False
        self.emcy = ""                  # the last EMCY, as text
        self.fault = ""                 # the drive's current fault, as text ("" when none)
        self._epoch = 0                 # bumped by every stop: an arm in flight is void
        self._disable_at: float | None = None
        self._not_operational_since: float | None = None
        self._configured_at = float("-inf")
        self._seen_feedback = 0
        self._seq = 0
        self._backoff = settings.reconnect_min_s
        self._threads: list[threading.Thread] = []
        drive.add_emcy_listener(self._on_emcy)
        drive.add_bootup_listener(self._on_bootup)

    # -- life ------------------------------------------------------------------------------
    def start(self) -> None:
        self._internal("connect")
        for name, target in (("steering-control", self._control_loop), ("steering-worker", self._worker)):
            t = threading.Thread(target=target, name=name, daemon=True)
            t.start()
            self._threads.append(t)

    def stop(self) -> None:
        """Stop the wheel (if it was armed), then the threads, then the drive."""
        with self._lock:
            was_armed = self.envelope.armed
            self._stop_drive("service stopping")
        if was_armed and self.link_ok:
            time.sleep(self.settings.quickstop_hold_s)
        self._stop.set()
        self._internal("quit")
        for t in self._threads:
            t.join(timeout=1.0)
        if self.link_ok:
            try:
                self.drive.command(ds402.CW_DISABLE_VOLTAGE)
            except Exception as exc:
                log.debug("final disable: %s", exc)
        self.drive.close()

    # -- requests --------------------------------------------------------------------------
    def submit(self, kind: str, payload, reply: Reply | None = None) -> None:
        """Queue an 'arm', 'setpoint' or 'calibration' request; `reply` gets the answer.
        A flood beyond the queue's size is refused at once rather than answered late."""
        if self._jobs.qsize() >= MAX_WAITING:
            log.warning("%s refused: %d requests already waiting", kind, self._jobs.qsize())
            if reply is not None:
                reply(_rejected("busy: too many requests waiting"))
            return
        self._jobs.put((kind, payload, reply))

    def request(self, kind: str, payload, timeout: float = 2.0) -> dict:
        """submit() and wait for the answer (for tests and the bench)."""
        box: queue.Queue = queue.Queue()
        self.submit(kind, payload, box.put)
        return box.get(timeout=timeout)

    def _internal(self, kind: str, payload=None) -> None:
        """Our own jobs are never refused (and never block: callers may hold the lock)."""
        self._jobs.put((kind, payload, None))

    def estop(self, payload=None) -> dict:
        """Quick stop now, whoever asks and whatever they send; disarms."""
        with self._lock:
            was_armed = self.envelope.armed
            self._stop_drive("estop")
        log.warning("estop (%s)", "was armed" if was_armed else "was not armed")
        return {"status": ACCEPTED, "reason": "quick stop, then power off", "was_armed": was_armed}

    # -- the worker ------------------------------------------------------------------------
    def _worker(self) -> None:
        retry_at = None
        while not self._stop.is_set():
            timeout = None if retry_at is None else max(0.0, retry_at - time.monotonic())
            try:
                kind, payload, reply = self._jobs.get(timeout=timeout)
            except queue.Empty:
                kind, payload, reply = "connect", None, None
            if kind == "quit":
                return
            if kind == "connect":
                retry_at = None if self._connect() else time.monotonic() + self._next_backoff()
                continue
            if kind == "configure":
                retry_at = None if self._configure() else time.monotonic() + self._next_backoff()
                continue
            handler = {"arm": self._arm, "setpoint": self._setpoint,
                       "calibration": self._calibration_request,
                       "limits": self._write_limits}.get(kind)
            try:
                answer = handler(payload) if handler else {"status": REJECTED, "reason": f"unknown request {kind}"}
            except Exception as exc:          # a bug must not kill the worker; say so
                log.exception("%s failed", kind)
                answer = {"status": REJECTED, "reason": f"internal error: {exc}"}
            if reply is not None:
                try:
                    reply(answer)
                except Exception:
                    log.exception("reply failed")
            # Drop our references now: a zenoh query is answered for good (its final reply
            # sent) only when the last reference to it goes.
            kind = payload = reply = None

    def _next_backoff(self) -> float:
        delay, self._backoff = self._backoff, min(self._backoff * 2, self.settings.reconnect_max_s)
        return delay

    def _connect(self) -> bool:
        with self._lock:
            self.link_ok = False
            self.phase = CONNECTING
        self.drive.close()
        try:
            self.drive.open()
        except Exception as exc:
            log.warning("CAN interface %s %s: %s", self.drive.settings.interface,
                        self.drive.settings.channel, exc)
            return False
        with self._lock:
            self.link_ok = True
        return self._configure()

    def _configure(self) -> bool:
        with self._lock:
            self.phase = CONNECTING
            self.calibration = None
            self.envelope.clear_range()
        try:
            self.drive.configure(limits_qc=None)
        except DriveError as exc:
            log.warning("drive configuration failed: %s", exc)
            return False
        except Exception as exc:               # the link itself went away
            log.warning("drive configuration failed: %s", exc)
            with self._lock:
                self.link_ok = False
            self._internal("connect")
            return True
        with self._lock:
            self._backoff = self.settings.reconnect_min_s
            self._configured_at = self._clock()
            self.recorder.reset()
            self.phase = CALIBRATING
        log.info("calibration: power stage off; turn the wheel to both locks and back to the centre")
        return True

    def _write_limits(self, cal: Calibration) -> dict:
        try:
            self.drive.set_position_limits(cal.limits_qc())
        except Exception as exc:
            log.error("could not write the software position limits: %s; sweep again", exc)
            with self._lock:
                self.recorder.reset()
                self.recorder.problem = f"drive refused the limits: {exc}"
            return {"status": REJECTED, "reason": str(exc)}
        with self._lock:
            self.calibration = cal
            self.envelope.set_range(*cal.range_deg)
            self.phase = READY
        lo, hi = cal.range_deg
        log.info("calibrated: min %d max %d zeroRef %d (span %d qc), range %.1f..%.1f deg",
                 cal.min_qc, cal.max_qc, cal.zero_qc, cal.span_qc, lo, hi)
        return {"status": ACCEPTED}

    # -- arm / disarm ----------------------------------------------------------------------
    def _arm(self, payload) -> dict:
        if not isinstance(payload, dict):
            return _rejected("expected a map like {\"arm\": true}")
        unknown = sorted(str(k) for k in payload if k not in ARM_FIELDS)
        if unknown:
            return _rejected(f"unknown field '{unknown[0]}' (known: arm, lease)")
        arm, lease = payload.get("arm"), payload.get("lease")
        if not isinstance(arm, bool):
            return _rejected("arm must be true or false")
        if lease is not None and not isinstance(lease, str):
            return _rejected("lease must be text")
        if not arm:
            return self._disarm(lease)
        with self._lock:
            if self.phase not in (READY, ARMED):
                return _rejected(f"not ready: {self.phase}")
            if not self.drive_alive:
                return _rejected("the drive is not answering (no heartbeat)")
            fb = self.drive.feedback()
            if not self._fresh(fb):
                return _rejected("no feedback from the drive")
            angle = self.calibration.angle_deg(fb.position_qc)
            refusal = self.envelope.arm_refusal(angle, lease)
            if refusal:
                return _rejected(refusal)
            if self.envelope.armed:               # the owner arming again: a renewal
                self.envelope.arm(angle, lease)
                return self._arm_reply(lease, fb)
            if fb.op_mode != POSITION_MODE:
                return _rejected(f"drive is in operation mode {fb.op_mode}, not Position Mode")
            epoch = self._epoch
        reason = self._enable_drive()
        with self._lock:
            fb = self.drive.feedback()
            if not reason and self._epoch != epoch:
                reason = f"stopped while arming ({self.envelope.tripped or 'estop'})"
            if not reason and fb.state != ds402.OPERATION_ENABLED:
                reason = f"drive left operation enabled ({fb.state})"
            if reason:
                self.drive.command(ds402.CW_DISABLE_VOLTAGE)
                return _rejected(reason)
            try:
                lease = self.envelope.arm(self.calibration.angle_deg(self.drive.target_qc))
            except PermissionError as exc:
                self.drive.command(ds402.CW_DISABLE_VOLTAGE)
                return _rejected(str(exc))
            self.phase = ARMED
            self.fault = ""
            return self._arm_reply(lease, fb)

    def _enable_drive(self) -> str:
        """Fault reset (the explicit re-arm is the only place it happens), then hold the
        measured position and enable. '' on success, else why not."""
        d, step = self.drive, self.settings.arm_step_timeout_s
        with self._lock:
            self._disable_at = None           # a power-off pending from the last stop is ours now
        state = d.feedback().state
        if ds402.is_fault(d.feedback().statusword):
            log.info("arm: fault reset (%s)", self.fault or "fault without EMCY")
            if not d.fault_reset(step):
                return f"drive fault persists after reset: {self.fault or d.feedback().state}"
        elif state not in (ds402.SWITCH_ON_DISABLED, ds402.READY):      # e.g. still quick-stopped
            d.command(ds402.CW_DISABLE_VOLTAGE)
            if not d.wait_feedback(lambda fb: fb.state == ds402.SWITCH_ON_DISABLED, step):
                return f"drive did not power off first ({d.feedback().state})"
        hold = d.feedback().position_qc
        d.send_target(hold, ds402.CW_SHUTDOWN)
        if not d.wait_feedback(lambda fb: fb.state == ds402.READY, step):
            return f"drive did not become ready ({d.feedback().state})"
        hold = d.feedback().position_qc
        d.send_target(hold, ds402.CW_ENABLE_OPERATION)
        if not d.wait_feedback(lambda fb: fb.state == ds402.OPERATION_ENABLED, step):
            return f"drive did not enable ({d.feedback().state})"
        return ""

    def _arm_reply(self, lease: str, fb) -> dict:
        lo, hi = self.envelope.allowed_deg
        return {"status": ACCEPTED, "reason": "", "lease": lease, "owner": self.envelope.owner,
                "angle_deg": self.calibration.measured_deg(fb.position_qc),
                "target_deg": self.envelope.target_deg, "range_deg": [lo, hi],
                "watchdog_s": self.envelope.settings.watchdog_s}

    def _disarm(self, lease) -> dict:
        with self._lock:
            if not self.envelope.armed:
                return {"status": ACCEPTED, "reason": "was not armed"}
            if not self.envelope.disarm(lease):
                return _rejected("only the owner can disarm (anyone can estop)")
            self._stop_drive("")
            self.phase = READY
        return {"status": ACCEPTED, "reason": "disarmed: quick stop, then power off"}

    # -- setpoints -------------------------------------------------------------------------
    def _setpoint(self, payload) -> dict:
        with self._lock:
            fb = self.drive.feedback()
            cal = self.calibration
            measured = cal.angle_deg(fb.position_qc) if cal is not None and self._fresh(fb) else None
            was_armed = self.envelope.armed
            d = self.envelope.setpoint(payload, measured)
            if was_armed and not self.envelope.armed:          # it came after the deadline
                self._stop_drive(self.envelope.tripped, already_tripped=True)
            if d.target_deg is not None:
                self.drive.send_target(round(cal.qc_of(d.target_deg)))
        reply = {"status": d.status, "reason": d.reason, "target_deg": d.target_deg,
                 "angle_deg": None if measured is None else cal.measured_deg(fb.position_qc),
                 "limits": list(d.limits)}
        if d.goal_deg is not None and d.goal_deg != d.target_deg:
            reply["goal_deg"] = d.goal_deg
        return reply

    # -- calibration requests --------------------------------------------------------------
    def _calibration_request(self, payload) -> dict:
        payload = payload or {}
        if not isinstance(payload, dict) or not set(payload) <= {"restart", "finish"}:
            return _rejected("expected {} (status), {\"restart\": true} or {\"finish\": true}")
        with self._lock:
            if payload.get("restart") is True:
                if self.envelope.armed:
                    return _rejected("disarm first")
                if self.phase == CONNECTING:
                    return _rejected("the drive is not configured yet")
                self.recorder.reset()
                self.calibration = None
                self.envelope.clear_range()
                self.phase = CALIBRATING
                self.drive.command(ds402.CW_DISABLE_VOLTAGE)
                log.info("calibration restarted: turn the wheel to both locks and back to the centre")
            elif payload.get("finish") is True:
                if self.phase != CALIBRATING:
                    return _rejected(f"no sweep in progress ({self.phase})")
                try:
                    cal = self.recorder.result()
                except CalibrationRefused as exc:
                    log.warning("calibration refused: %s", exc)
                    self.recorder.problem = str(exc)
                    return {"status": REJECTED, "reason": f"calibration refused: {exc}",
                            "calibration": self._calibration_state()}
                self._internal("limits", cal)
            return {"status": ACCEPTED, "reason": "", "calibration": self._calibration_state()}

    def _calibration_state(self) -> dict:
        if self.calibration is not None:
            return {"state": "done", **self.calibration.as_dict(), "problem": ""}
        state = {CALIBRATING: "sweeping", CHECKING: "checking"}.get(self.phase, "none")
        return {"state": state, **self.recorder.status()}

    # -- the control loop ------------------------------------------------------------------
    def _control_loop(self) -> None:
        period = self.drive.settings.sync_period_s
        next_t = time.monotonic()
        next_state = next_t
        while not self._stop.is_set():
            if self.link_ok:
                try:
                    self._control_step()
                except Exception as exc:
                    self._link_lost(exc)
            now = time.monotonic()
            if self.on_state is not None and now >= next_state:
                next_state = max(next_state + self.settings.state_period_s, now - period)
                try:
                    self.on_state(self.state())
                except Exception:
                    log.exception("state callback failed")
            next_t += period
            delay = next_t - time.monotonic()
            if delay > 0:
                self._stop.wait(delay)
            elif delay < -10 * period:           # fell far behind (suspended): resync
                next_t = time.monotonic()

    def _control_step(self) -> None:
        now = self._clock()
        target_qc = None
        with self._lock:
            fb = self.drive.feedback()
            self._supervise_drive(fb, now)
            fresh = self._fresh(fb)
            if self.phase == CALIBRATING and fresh and fb.count != self._seen_feedback:
                self._sweep_sample(fb, now)
            self._seen_feedback = fb.count
            if self.envelope.armed:
                measured = self.calibration.angle_deg(fb.position_qc) if fresh else None
                target, tripped = self.envelope.tick(measured)
                if tripped:
                    self._stop_drive(tripped, already_tripped=True)
                elif target is not None:
                    target_qc = round(self.calibration.qc_of(target))
            if self._disable_at is not None and now >= self._disable_at:
                self._disable_at = None
                self.drive.command(ds402.CW_DISABLE_VOLTAGE)
            # under the lock: a setpoint sent meanwhile must not be overtaken by an older target
            self.drive.cycle(target_qc)

    def _supervise_drive(self, fb, now: float) -> None:
        age = self.drive.heartbeat_age(now)
        alive = age <= self.drive.settings.drive_heartbeat_timeout_s
        if alive != self.drive_alive:
            self.drive_alive = alive
            if alive:
                log.info("drive heartbeat: ok")
            else:
                log.error("drive heartbeat lost")
                self._stop_drive("drive heartbeat lost")
        silent = min(age, now - self._configured_at)
        if not alive and self.phase != CONNECTING and silent > self.settings.silent_drive_s:
            # Powered off, or rebooted with its boot-up message lost: either way its
            # configuration and its counter are not to be trusted. Configure it again
            # (retried with backoff until it answers), then a new sweep.
            log.error("drive silent for %.1f s: configuring it again when it answers", silent)
            self._on_bootup("drive silent: calibration lost")
        self._check_nmt(now)
        if self.envelope.armed:
            if not self._fresh(fb):
                self._stop_drive("no feedback from the drive")
            elif fb.state != ds402.OPERATION_ENABLED:
                cause = self.fault or f"drive left operation enabled ({fb.state})"
                self._stop_drive(cause)

    def _check_nmt(self, now: float) -> None:
        """A drive that says it is not operational lost its configuration (a reboot whose
        boot-up message we missed, an NMT command from another host): start over."""
        state = self.drive.heartbeat_state
        if not self.drive_alive or self.phase == CONNECTING or state in (None, NMT_OPERATIONAL):
            self._not_operational_since = None
            return
        if self._not_operational_since is None:
            self._not_operational_since = now
        elif now - self._not_operational_since > 3 * self.drive.settings.drive_heartbeat_period_s:
            log.warning("drive reports NMT state %d, not operational: configuring it again", state)
            self._not_operational_since = None
            self._on_bootup("drive not operational: calibration lost")

    def _sweep_sample(self, fb, now: float) -> None:
        r = self.recorder
        problem = r.problem
        r.add(fb.position_qc, now)
        if r.problem != problem and r.problem:
            log.warning("calibration: %s", r.problem)
        if r.done(now):
            try:
                cal = r.result()
            except CalibrationRefused as exc:
                log.warning("calibration refused: %s; sweep again", exc)
                r.reset()
                r.problem = str(exc)
                return
            self.phase = CHECKING
            self._internal("limits", cal)

    def _fresh(self, fb) -> bool:
        return self._clock() - fb.received_s <= self.settings.feedback_timeout_s

    def _stop_drive(self, reason: str, already_tripped: bool = False) -> None:
        """Quick stop now, power off later; `reason` trips the envelope (none for a disarm)."""
        self._epoch += 1
        if reason and not already_tripped:
            self.envelope.trip(reason)
        if self.phase == ARMED:
            self.phase = READY
        if not self.link_ok:
            return
        try:
            self.drive.command(ds402.CW_QUICK_STOP)
        except Exception as exc:
            log.warning("quick stop not sent: %s", exc)
            return
        self._disable_at = self._clock() + self.settings.quickstop_hold_s

    def _link_lost(self, exc: Exception) -> None:
        with self._lock:
            if not self.link_ok:
                return
            self.link_ok = False
            self.envelope.trip(f"CAN link lost: {exc}")
            self.phase = CONNECTING
            self.drive_alive = False
        log.error("CAN link lost: %s; reconnecting", exc)
        self._internal("connect")

    # -- events from the drive (canopen's receive thread) ----------------------------------
    def _on_emcy(self, emcy: Emcy) -> None:
        with self._lock:
            self.emcy = str(emcy)
            if emcy.is_reset:
                self.fault = ""
                log.info("drive: all errors cleared")
                return
            self.fault = str(emcy)
            log.error("drive %s", emcy)
            self._stop_drive(f"drive {emcy}")

    def _on_bootup(self, reason: str = "drive rebooted: calibration lost") -> None:
        with self._lock:
            self._stop_drive(reason)
            self.calibration = None
            self.envelope.clear_range()
            self.phase = CONNECTING
        self._internal("configure")

    # -- what the service publishes --------------------------------------------------------
    def state(self) -> dict:
        with self._lock:
            fb = self.drive.feedback()
            cal, env = self.calibration, self.envelope
            fresh = self._fresh(fb)
            self._seq += 1
            last = env.last
            target_deg = env.target_deg if env.armed else None
            return {
                "t": time.time_ns(),
                "seq": self._seq,
                "phase": self.phase,
                "armed": env.armed,
                "owner": env.owner,
                "angle_deg": cal.measured_deg(fb.position_qc) if cal is not None and fresh else None,
                "angle_qc": fb.position_qc if fresh else None,
                "target_deg": target_deg,
                "target_qc": self.drive.target_qc if env.armed else None,
                "goal_deg": env.goal_deg,
                "ds402": fb.state if fresh else "unknown",
                "statusword": fb.statusword,
                "following_error_qc": fb.following_error_qc,
                "drive_heartbeat": "ok" if self.drive_alive else "lost",
                "watchdog": "tripped" if env.tripped.startswith("watchdog") else "ok",
                "trip": env.tripped,
                "fault": self.fault or ("drive in fault (no EMCY seen)" if fresh and ds402.is_fault(fb.statusword) else ""),
                "emcy": self.emcy,
                "limits": list(last.limits) if last is not None else [],
                "decision": {"status": last.status, "reason": last.reason} if last is not None else None,
                "calibration": self._calibration_state(),
            }


def _rejected(reason: str) -> dict:
    return {"status": REJECTED, "reason": reason}

