"""When each input is used: the estimator's clock, kept apart from its filters.

As robot_localization separates its filter maths (FilterBase, Ekf) from the node that
orders measurements in time (RosFilter's queue and history), the estimator's filters are
told what happened and when; this module decides the when:

- the state's time `t_state` moves with the IMU samples (or, without IMU, with the fixes);
- IMU samples must come in order of their `t`: an older or equal one is refused
  (`imu_late`, `imu_duplicate`); one unit drives the filter, another takes over only
  after `imu_timeout_s` of silence;
- a fix is late by its latency: it may be up to `late_window_s` older than the state
  (the trajectory history has the state of its time), older is refused (`gnss_late`);
- a fix from the IMU's future waits until the IMU passes it, as long as IMU samples keep
  arriving and it is less than `imu_timeout_s` (or `late_window_s`, if longer) ahead of
  their stamps (a clock half a second off is a clock, not a dead IMU); if the IMU goes
  quiet, it is used as it is (the constant-velocity model carries the state);
- an input more than `max_future_s` ahead of the clock is refused (`future`; offline,
  without a clock, an hour ahead of the state);
- `NEW_TIMELINE` inputs in a row refused for their time mean the earlier times were the
  wrong ones: the estimator is told (`check_future` returns True, or `admit_imu` raises
  `NewTimeline`) and starts over on the new times;
- one sample's stamp never blocks the others (issue 15): an IMU sample more than
  `imu_gap_s` past its unit's last one, or a fix more than the wait ahead of a live IMU,
  is held back (`time_jump`) until its source's next stamp follows it (then the time
  really jumped: a gap); if the next one goes on from before, it was a lie, and the stream
  was never stopped. Each refusal for time names its source (`Rejected.source`).
"""
from __future__ import annotations

import heapq

from viena.services.estimator.inputs import Rejected
from viena.services.estimator.settings import EstimatorSettings

#: this many inputs in a row refused for their time (late, or an hour ahead offline) mean
#: the earlier times were wrong, not these
NEW_TIMELINE = 200
#: this many fixes arriving with no IMU sample between them: the IMU has gone quiet
QUIET_FIXES = 4
_HOUR_NS = 3600 * 10**9


class NewTimeline(Exception):
    """The inputs keep disagreeing with the time so far: the time so far was wrong.
    `rejected` is the reason the last of them was refused for (to count it)."""

    def __init__(self, why: str, rejected: str):
        super().__init__(why)
        self.rejected = rejected


class Timeline:
    """The state's time, the IMU's, and the fixes waiting for the IMU to reach them."""

    def __init__(self, settings: EstimatorSettings, clock=None):
        self.clock = clock
        self.late_ns = int(settings.late_window_s * 1e9)
        self.imu_timeout_ns = int(settings.imu_timeout_s * 1e9)
        self.future_ns = int(settings.max_future_s * 1e9)
        self.t_state: int | None = None     # the time the state refers to, ns
        self.t_imu: int | None = None       # the last IMU sample used
        self.imu_unit: str | None = None    # the unit that drives the filter
        self._pending: list = []            # heap of (t, n, fix) waiting for the IMU
        self._fixes_since_imu = 0           # fixes arrived since the last IMU sample
        self.wait_ns = max(self.imu_timeout_ns, self.late_ns)
        self._n = 0
        self._refused = 0                   # inputs refused for their time, in a row
        self.jump_ns = int(settings.imu_gap_s * 1e9)
        self._held: dict[str, int] = {}     # a source's stamp that jumped ahead, held back

    def restart(self) -> None:
        """Forget every time (not the IMU unit): the next inputs set them again."""
        self.t_imu = self.t_state = None
        self._pending.clear()
        self._refused = 0
        self._held.clear()

    # -- admission ---------------------------------------------------------------------------
    def check_future(self, t: int, source: str) -> bool:
        """Rejected("future") for an input of `source` too far ahead of the host clock (or,
        offline, of the state). True when such inputs keep coming offline: they are the
        right times, and a new timeline must start (`restart`) before this input is used."""
        if self.clock is not None:
            if t - self.clock() > self.future_ns:
                raise Rejected("future", source=source)
        elif self.t_state is not None and t - self.t_state > _HOUR_NS:
            # offline there is no clock: an hour ahead of everything so far is a bad time,
            # unless it goes on (a recording made of two sessions)
            self._refused += 1
            if self._refused < NEW_TIMELINE:
                raise Rejected("future", "an hour ahead of the state", source)
            return True
        return False

    def _jumped(self, source: str, t: int, step_ns: int) -> None:
        """`source`'s stamp t jumped ahead of its stream: Rejected("time_jump") unless the
        source's previous stamp was held back and t follows it within `step_ns` (the time
        really jumped, and this confirms it; the next may follow this one)."""
        held = self._held.get(source)
        self._held[source] = t
        if held is not None and 0 < t - held <= step_ns:
            return
        raise Rejected("time_jump", "ahead of its own stream", source)

    def admit_imu(self, unit: str, t: int) -> tuple[float, bool]:
        """(seconds since the last IMU sample, 0 for a unit's first; True if this unit just
        took over from another). Rejected for a sample out of order or from another unit
        while the first is live; NewTimeline after NEW_TIMELINE refusals in a row."""
        takeover = False
        if unit != self.imu_unit:
            if self.imu_unit is not None:
                # one IMU drives the filter; another takes over only when it has gone quiet
                if self.t_imu is not None and t - self.t_imu < self.imu_timeout_ns:
                    raise Rejected("imu_other_unit")
                self.t_imu = None
                takeover = True
            self.imu_unit = unit
        last = self.t_imu
        if last is not None:
            if t <= last:
                reason = "imu_late" if t < last else "imu_duplicate"
                self._refused += 1
                if self._refused >= NEW_TIMELINE:
                    raise NewTimeline("IMU times went back", reason)
                raise Rejected(reason, source=unit)
            if t - last > self.jump_ns:
                self._jumped(unit, t, self.jump_ns)
        self._refused = 0
        self._fixes_since_imu = 0
        self.t_imu = t
        return (0.0 if last is None else (t - last) * 1e-9), takeover

    def admit_fix(self, unit: str, t: int) -> None:
        """Rejected("gnss_late") for a fix older than the state by more than late_window_s;
        Rejected("time_jump") for one further ahead of a live IMU than a fix may wait, until
        the receiver's next fix follows it."""
        if self.t_state is not None and t < self.t_state - self.late_ns:
            raise Rejected("gnss_late", source=unit)
        t_imu = self.t_imu
        if t_imu is not None and self._fixes_since_imu < QUIET_FIXES and t > t_imu + self.wait_ns:
            self._jumped(unit, t, self.wait_ns)
        elif self._held:
            self._held.pop(unit, None)

    # -- fixes and the IMU -------------------------------------------------------------------
    def schedule(self, fix) -> list:
        """The fixes to use now, in order, given a new one: those the IMU has kept waiting
        too long, and this one unless it is from the IMU's near future (then it waits in
        the queue until `due` hands it out).

        Whether the IMU is live is judged by arrivals, not stamps: an IMU whose stamps run
        half a second behind the GNSS clock still sends its samples between the fixes,
        and a fix must wait for the samples of its time. So a fix waits while IMU samples
        keep coming (fewer than QUIET_FIXES fixes since the last one) and it is less than
        `wait` ahead of the IMU's stamps (imu_timeout_s, or late_window_s if longer)."""
        self._fixes_since_imu += 1
        pending = self._pending
        t_imu = self.t_imu
        quiet = t_imu is None or self._fixes_since_imu > QUIET_FIXES
        now = []
        while pending and (quiet or pending[0][0] < fix.t - self.wait_ns):
            now.append(heapq.heappop(pending)[2])
        if not quiet and t_imu is not None and t_imu < fix.t < t_imu + self.wait_ns:   # (quiet if None)
            self._n += 1
            heapq.heappush(pending, (fix.t, self._n, fix))
        else:
            now.append(fix)
        return now

    def due(self, t: int) -> list:
        """The waiting fixes the IMU has now passed, in order of their time."""
        pending = self._pending
        out = []
        while pending and pending[0][0] <= t:
            out.append(heapq.heappop(pending)[2])
        return out

    # -- the state's time --------------------------------------------------------------------
    def step_state(self, t: int) -> float:
        """An IMU sample at t moves the state's time: the seconds it moved (0 if the state
        was already ahead, after a spell without IMU)."""
        t_prev = self.t_state
        if t_prev is None:
            self.t_state = t
            return 0.0
        dt = (t - t_prev) * 1e-9
        if dt < 0.0:
            return 0.0
        self.t_state = t
        return dt

    def coast_to(self, t: int) -> float:
        """No IMU: the state's time goes to a fix's; the seconds it moved (0 if not ahead)."""
        if self.t_state is None:
            self.t_state = t
            return 0.0
        if t <= self.t_state:
            return 0.0
        dt = (t - self.t_state) * 1e-9
        self.t_state = t
        return dt

    def catch_up(self, t: int) -> None:
        """The state was just set from a fix of time t."""
        if self.t_state is None or self.t_state < t:
            self.t_state = t

    def imu_live_at(self, t: int) -> bool:
        """An IMU sample came within imu_timeout_s of t."""
        return self.t_imu is not None and abs(t - self.t_imu) < self.imu_timeout_ns

    @property
    def imu_live(self) -> bool:
        """An IMU sample came within imu_timeout_s of the state's time."""
        t = self.t_state
        return t is not None and self.t_imu is not None and t - self.t_imu < self.imu_timeout_ns
