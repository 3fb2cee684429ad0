"""What the NovAtel twin logs and when: the logs it holds (LOG's trigger, period, offset,
hold), each log's body of a solution (through the logs' one definition, driver/novatel/logs.py),
the header's time tag, and the output of every epoch that is due: ONTIME on GPS-time
multiples of the period (at most 20 Hz), ONNEW/ONCHANGED at each new solution, ONNEXT and
ONCE once; a replayed drive's epochs at its recorded pace.
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

from viena.services.gnss.driver.gpstime import gps_to_utc_ns
from viena.services.gnss.driver.novatel.commands import SbasControl
from viena.services.gnss.driver.novatel.enums import (
    Dynamics,
    MessageId,
    Port,
    SbasKeyword,
    SbasSystem,
    TimeStatus,
    Trigger,
)
from viena.services.gnss.driver.novatel.framing import BINARY_MESSAGE_TYPE, Header, frame_of, pack_header
from viena.services.gnss.driver.novatel.logs import BestPos, BestVel, BestXyz

from .clock import WEEK_MS
from .ports import FACTORY_BAUD
from .replay import EPOCH_MS
from .rtk import FACTORY_DGPS_TIMEOUT_S, Source
from .solution import Solution

if TYPE_CHECKING:
    from .novatel_twin import NovatelTwin

#: The OEM4-G2L computes and logs at up to 20 Hz.
MIN_PERIOD_MS = 50
MAX_LOGS = 30                   # "The OEM4 family of receivers can handle 30 logs at a time"
SW_VERSION = 1522
IDLE_TIME = 160                 # 80 % idle, in the header's half-percent units
OWN_PORT = Port.COM1
ACTIVE_TRIGGERS = (Trigger.ONNEW, Trigger.ONCHANGED, Trigger.ONTIME, Trigger.ONNEXT)


@dataclass
class LogEntry:
    message: MessageId
    trigger: Trigger
    period_ms: int
    offset_ms: int
    hold: bool
    after_ms: int = -1              # requested at this GPS time: only later epochs come out

    def fires_at(self, gps_ms: int, epoch_ms: int) -> bool:
        """Whether a solution epoch at ``gps_ms`` is output by this log."""
        if gps_ms <= self.after_ms:
            return False
        if self.trigger == Trigger.ONTIME and self.period_ms > epoch_ms:
            return gps_ms % self.period_ms == self.offset_ms
        return self.trigger in ACTIVE_TRIGGERS


@dataclass
class ReceiverConfig:
    """What SAVECONFIG stores and RESET restores. SBAS as the receiver understood it: the
    keyword is its meaning (the OEM4 table's name), whatever number carried it."""

    logs: tuple = ()
    baud: int = FACTORY_BAUD
    dynamics: Dynamics = Dynamics.AIR
    sbas: SbasControl = SbasControl(SbasKeyword.DISABLE, SbasSystem.AUTO)   # "DISABLE AUTO 0 NONE"
    ports: tuple = ()               # (com, baud, rxtype, txtype, responses) of the other ports, and COM1's modes
    dgps_timeout_s: float = FACTORY_DGPS_TIMEOUT_S
    psr_source: Source = Source()
    rtk_source: Source = Source()


def bestxyz_of(s: Solution) -> BestXyz:
    return BestXyz(*_bestxyz_fields(s))


def _bestxyz_fields(s: Solution) -> tuple:
    return (s.pos_status, s.pos_type, s.ecef_m, s.ecef_sigma_m, s.vel_status, s.vel_type, s.vel_ecef_mps,
            s.vel_sigma_mps, s.station_id, s.vel_latency_s, s.diff_age_s, s.sol_age_s, s.sats_tracked, s.sats_used,
            s.sats_l1_rtk, s.sats_l2_rtk)


def bestpos_of(s: Solution) -> BestPos:
    lat, lon, h = s.geodetic()
    e, n, u = s.enu_sigma()
    return BestPos(s.pos_status, s.pos_type, lat, lon, h - s.undulation_m, s.undulation_m,
                   lat_sigma_m=n, lon_sigma_m=e, height_sigma_m=u, station_id=s.station_id,
                   diff_age_s=s.diff_age_s, sol_age_s=s.sol_age_s, sats_tracked=s.sats_tracked,
                   sats_used=s.sats_used, sats_l1_rtk=s.sats_l1_rtk, sats_l2_rtk=s.sats_l2_rtk)


def bestvel_of(s: Solution) -> BestVel:
    e, n, u = s.enu_velocity()
    track = math.degrees(math.atan2(e, n)) % 360.0
    return BestVel(s.vel_status, s.vel_type, s.vel_latency_s, s.diff_age_s, math.hypot(e, n),
                   track, u)


LOG_MAKERS: dict[int, Callable[[Solution], object]] = {
    MessageId.BESTXYZ: bestxyz_of, MessageId.BESTPOS: bestpos_of, MessageId.BESTVEL: bestvel_of,
}
#: each log's body, as LOG_MAKERS[id](solution).body(); BESTXYZ, every epoch, without making its log
LOG_BODIES: dict[int, Callable[[Solution], bytes]] = {
    MessageId.BESTXYZ: lambda s: BestXyz.pack(*_bestxyz_fields(s)),
    MessageId.BESTPOS: lambda s: bestpos_of(s).body(), MessageId.BESTVEL: lambda s: bestvel_of(s).body(),
}


class LogOutput:
    """The twin's log output on COM1: which logs are due at an epoch, and their frames."""

    def __init__(self, twin: NovatelTwin):
        self.twin = twin
        self.next_epoch_ms: int | None = None
        self.last_solution: Solution | None = None

    def header(self, message_id: int, gps_ms: int, *, message_type=BINARY_MESSAGE_TYPE,
                sequence: int = 0, time_status: TimeStatus | None = None, port_address: int = OWN_PORT) -> Header:
        time_status, week, ms = self.time_tag(gps_ms, time_status)
        return Header(message_id, message_type=message_type, port_address=port_address,
                      sequence=sequence, idle_time=IDLE_TIME, time_status=time_status,
                      week=week, milliseconds=ms, sw_version=SW_VERSION)

    def time_tag(self, gps_ms: int, time_status: TimeStatus | None = None) -> tuple[TimeStatus, int, int]:
        """A header's time status, week and milliseconds for an epoch."""
        if time_status is None:
            last = self.last_solution
            time_status = (TimeStatus.FREEWHEELING if last is not None and not last.has_fix
                           else TimeStatus.FINESTEERING)
        if self.twin.solver is not None and gps_ms < self.twin.solver.no_fix_until_ms:
            # cold start: the receiver does not know the time yet and counts from week 0
            time_status = TimeStatus.UNKNOWN
            gps_ms = max(0, gps_ms - self.twin._boot_gps_ms)
        week, ms = divmod(gps_ms, WEEK_MS)
        return time_status, week, ms

    def emit(self, messages, solution: Solution) -> None:
        # encode_frame(self.header(message, gps_ms), body) without making the Header
        time_status, week, ms = self.time_tag(solution.gps_ms)
        for message in messages:
            body = LOG_BODIES[message](solution)
            header = pack_header(message, BINARY_MESSAGE_TYPE, OWN_PORT, len(body), 0, IDLE_TIME, time_status,
                                 week, ms, sw_version=SW_VERSION)
            self.twin._out += frame_of(header, body)

    def solve(self, gps_ms: int) -> Solution:
        last = self.last_solution
        if last is not None and last.gps_ms == gps_ms:
            return last
        assert self.twin.solver is not None, "solved only without a replay: then the twin was given truth"
        solution = self.twin.solver.solve(gps_ms, gps_to_utc_ns(*divmod(gps_ms, WEEK_MS)))
        self.last_solution = solution
        return solution

    def solve_due(self, now_s: float) -> None:
        """Output the logs of every solution epoch that is due by now."""
        if not self.twin.logs:
            self.next_epoch_ms = None
            return
        last_due = self.twin._gps_ms(now_s - self.twin.output_delay_s)
        if self.next_epoch_ms is None or self.next_epoch_ms < last_due - 1000:
            # start (or, after a stall of over a second, resume) at the latest epoch
            self.next_epoch_ms = last_due // MIN_PERIOD_MS * MIN_PERIOD_MS
        while self.next_epoch_ms <= last_due and self.twin.logs:
            gps_ms = self.next_epoch_ms
            self.next_epoch_ms += MIN_PERIOD_MS
            due = [m for m, e in self.twin.logs.items() if e.fires_at(gps_ms, MIN_PERIOD_MS)]
            if due:
                self.emit(due, self.solve(gps_ms))
                self.drop_onnext(due)

    def drop_onnext(self, messages) -> None:
        for m in messages:
            if self.twin.logs[m].trigger == Trigger.ONNEXT:
                del self.twin.logs[m]

    def current_solution(self, now_s: float) -> Solution | None:
        """The latest solution (for ONCE and the first ONCHANGED output)."""
        if self.twin.replay is not None:
            return self.twin.replay.last
        gps_ms = self.twin._gps_ms(now_s - self.twin.output_delay_s) // MIN_PERIOD_MS * MIN_PERIOD_MS
        if self.last_solution is not None and self.last_solution.gps_ms > gps_ms:
            return self.last_solution
        return self.solve(gps_ms)

    def begin_replay(self, now_s: float) -> None:
        replay = self.twin.replay
        assert replay is not None, "called for a twin that replays"
        replay.begin(now_s, self.twin._gps_ms(now_s))
        if not replay.retime:                   # the receiver lives in the recording's time
            self.twin.clock.anchor(now_s, replay.host_gps_ms(0))

    def replay_due(self, now_s: float) -> None:
        assert self.twin.replay is not None, "called for a twin that replays"
        for solution in self.twin.replay.due(now_s):
            self.last_solution = solution
            due = [m for m, e in self.twin.logs.items() if e.fires_at(solution.gps_ms, EPOCH_MS)]
            if due:
                self.emit(due, solution)
                self.drop_onnext(due)
