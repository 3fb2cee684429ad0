"""The DS402 steps of an arm, one control period at a time: from whatever power-off state
the drive is in to operation enabled, holding the wheel where it stands.

    fault                  -> disable voltage, wait two SYNC answers (bit 7 low),
                              fault reset (its 0 -> 1 edge), wait for no fault, disable voltage
    e.g. quick stop active -> disable voltage, wait for switch on disabled
    then                   -> shutdown (hold the measured position), wait for ready to switch on
                           -> enable operation (hold it again), wait for operation enabled

Each wait has `step_timeout_s`. The sequence is plain data: `begin` and `advance` are given
the feedback and the time and return the frames to send, so the core calls them from its
tick and nothing here waits. A fault is reset only here, that is only by an explicit arm.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from enum import Enum

from viena.services.steering.model import ds402
from viena.services.steering.model.actions import Command, SendTarget
from viena.services.steering.model.drive import Feedback

log = logging.getLogger("viena.steering")


class Step(Enum):
    POWER_OFF = "power off first"          # waiting for switch on disabled
    RESET_LOW = "bit 7 low"                # waiting for two SYNC answers after it
    RESET_HIGH = "fault reset"             # waiting for the fault to clear
    SHUTDOWN = "shutdown"                  # waiting for ready to switch on
    ENABLE = "enable operation"            # waiting for operation enabled


@dataclass
class ArmSequence:
    token: object                          # whose arm this is (the runner's reply)
    step_timeout_s: float
    step: Step = Step.SHUTDOWN
    since_s: float = 0.0
    seen: int = 0                          # feedback count when bit 7 went low
    done: bool = False
    failure: str = ""

    @classmethod
    def begin(cls, token, fb: Feedback, now_s: float, step_timeout_s: float,
              fault: str = "") -> tuple[ArmSequence, list]:
        """The sequence for a drive in `fb`'s state, and its first frames."""
        seq = cls(token, step_timeout_s, since_s=now_s)
        if ds402.is_fault(fb.statusword):
            log.info("arm: fault reset (%s)", fault or "fault without EMCY")
            seq.step, seq.seen = Step.RESET_LOW, fb.count
            return seq, [Command(ds402.CW_DISABLE_VOLTAGE)]
        if fb.state not in (ds402.SWITCH_ON_DISABLED, ds402.READY):
            seq.step = Step.POWER_OFF
            return seq, [Command(ds402.CW_DISABLE_VOLTAGE)]
        return seq, seq._go(Step.SHUTDOWN, fb, now_s)

    def advance(self, fb: Feedback, now_s: float, fault: str = "") -> list:
        """One control period: the next frames if this step is done; `done` or `failure`
        (why not) once the sequence is over."""
        if self._reached(fb):
            return self._next(fb, now_s)
        if now_s - self.since_s > self.step_timeout_s:
            self.failure = self._timeout_reason(fb, fault)
        return []

    def _reached(self, fb: Feedback) -> bool:
        if self.step is Step.RESET_LOW:
            return fb.count >= self.seen + 4       # two full SYNC answers (TPDO1 + TPDO2)
        if self.step is Step.RESET_HIGH:
            return not ds402.is_fault(fb.statusword)
        wanted = {Step.POWER_OFF: ds402.SWITCH_ON_DISABLED, Step.SHUTDOWN: ds402.READY,
                  Step.ENABLE: ds402.OPERATION_ENABLED}[self.step]
        return fb.state == wanted

    def _next(self, fb: Feedback, now_s: float) -> list:
        if self.step is Step.RESET_LOW:
            self.step, self.since_s = Step.RESET_HIGH, now_s
            return [Command(ds402.CW_FAULT_RESET)]
        if self.step is Step.RESET_HIGH:
            return [Command(ds402.CW_DISABLE_VOLTAGE), *self._go(Step.SHUTDOWN, fb, now_s)]
        if self.step is Step.POWER_OFF:
            return self._go(Step.SHUTDOWN, fb, now_s)
        if self.step is Step.SHUTDOWN:
            return self._go(Step.ENABLE, fb, now_s)
        self.done = True
        return []

    def _go(self, step: Step, fb: Feedback, now_s: float) -> list:
        """Hold the measured position and send the controlword that leads to `step`'s state."""
        self.step, self.since_s = step, now_s
        cw = ds402.CW_SHUTDOWN if step is Step.SHUTDOWN else ds402.CW_ENABLE_OPERATION
        return [SendTarget(fb.position_qc, cw)]

    def _timeout_reason(self, fb: Feedback, fault: str) -> str:
        if self.step in (Step.RESET_LOW, Step.RESET_HIGH):
            return f"drive fault persists after reset: {fault or fb.state}"
        return {Step.POWER_OFF: "drive did not power off first",
                Step.SHUTDOWN: "drive did not become ready",
                Step.ENABLE: "drive did not enable"}[self.step] + f" ({fb.state})"
