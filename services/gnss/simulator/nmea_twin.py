"""An NMEA receiver's twin (a u-blox NEO-M8N, docs/sensors.md#nmea-receivers): 10 Hz epochs of
RMC, VTG, GGA, GSA, GSV and GLL, in u-blox's order, written with pynmea2.

Positions come from the simulated car's truth at the antenna's lever arm plus the same
time-correlated error model as the NovAtel twin, sized to the NEO-M8N's 2.5 m CEP; or from
the 2016 drive recording. Without a fix the receiver keeps talking: GGA quality 0 with
empty position fields, RMC status V. Input (UBX or PUBX configuration) is ignored.
"""
from __future__ import annotations

import math
from collections.abc import Callable
from datetime import UTC, datetime

import numpy as np
import pynmea2

from viena.common.twin.serial_port import ByteTwin
from viena.services.gnss.driver.gpstime import gps_to_utc_ns

from .clock import WEEK_MS, GpsClock
from .errors import CommonErrors, GnssErrorModel, SkyModel
from .replay import DriveReplay, RecordedEpoch
from .solution import Solution, TruthSolver

KNOT_MPS = 1852.0 / 3600.0


def _lat(deg: float) -> tuple[str, str]:
    a = abs(deg)
    d = int(a)
    return f"{d:02d}{(a - d) * 60:08.5f}", "N" if deg >= 0 else "S"


def _lon(deg: float) -> tuple[str, str]:
    a = abs(deg)
    d = int(a)
    return f"{d:03d}{(a - d) * 60:08.5f}", "E" if deg >= 0 else "W"


def _dops(sats_used: int) -> tuple[float, float, float]:
    """Plausible (PDOP, HDOP, VDOP) for a number of satellites in the solution."""
    hdop = 1.2 * math.sqrt(6.0 / max(sats_used, 1))
    vdop = 1.6 * hdop
    return math.hypot(hdop, vdop), hdop, vdop


def _sentence(talker: str, kind: str, fields) -> bytes:
    cls = {"GGA": pynmea2.GGA, "RMC": pynmea2.RMC, "VTG": pynmea2.VTG, "GSA": pynmea2.GSA,
           "GSV": pynmea2.GSV, "GLL": pynmea2.GLL}[kind]
    return (str(cls(talker, kind, tuple(fields))) + "\r\n").encode("ascii")


def nmea_epoch(solution: Solution, utc_ns: int, talker: str = "GP") -> bytes:
    """One epoch's sentences for a solution, as a u-blox M8 writes them."""
    utc = datetime.fromtimestamp(utc_ns / 1e9, tz=UTC)
    hms = utc.strftime("%H%M%S.") + f"{utc.microsecond // 10000:02d}"
    date = utc.strftime("%d%m%y")
    fix = solution.has_fix
    pdop, hdop, vdop = _dops(solution.sats_used)
    if fix:
        lat, lon, h = solution.geodetic()
        (la, ns), (lo, ew) = _lat(lat), _lon(lon)
        e, n, _ = solution.enu_velocity()
        knots = math.hypot(e, n) / KNOT_MPS
        course = f"{math.degrees(math.atan2(e, n)) % 360.0:.2f}" if knots > 0.1 else ""
        msl = f"{h - solution.undulation_m:.1f}"
        sep = f"{solution.undulation_m:.1f}"
        quality, status, mode, fix_type = "1", "A", "A", "3"
        speed_kn, speed_kmh = f"{knots:.3f}", f"{knots * KNOT_MPS * 3.6:.3f}"
    else:
        la = ns = lo = ew = msl = sep = course = speed_kn = speed_kmh = ""
        quality, status, mode, fix_type = "0", "V", "N", "1"
    used = solution.sats_used if fix else 0
    prns = [f"{p:02d}" for p in range(2, 2 + 3 * solution.sats_tracked, 3)][:12]
    out = [
        _sentence(talker, "RMC", (hms, status, la, ns, lo, ew, speed_kn, course, date, "", "",
                                  mode)),
        _sentence(talker, "VTG", (course, "T" if course else "", "", "M", speed_kn, "N",
                                  speed_kmh, "K", mode)),
        _sentence(talker, "GGA", (hms, la, ns, lo, ew, quality, f"{used:02d}",
                                  f"{hdop:.2f}" if fix else "99.99", msl, "M" if fix else "",
                                  sep, "M" if fix else "", "", "")),
        _sentence(talker, "GSA", ("A", fix_type, *(prns[:used] + [""] * 12)[:12],
                                  f"{pdop:.2f}" if fix else "99.99",
                                  f"{hdop:.2f}" if fix else "99.99",
                                  f"{vdop:.2f}" if fix else "99.99")),
    ]
    groups = [prns[i:i + 4] for i in range(0, len(prns), 4)] or [[]]
    for number, group in enumerate(groups, 1):
        sats = []
        for k, prn in enumerate(group):
            sats += [prn, f"{20 + (7 * int(prn)) % 60:02d}", f"{(37 * int(prn)) % 360:03d}",
                     f"{30 + (k * 5) % 20:02d}"]
        out.append(_sentence(talker, "GSV", (str(len(groups)), str(number),
                                             f"{len(prns):02d}", *sats)))
    out.append(_sentence(talker, "GLL", (la, ns, lo, ew, hms, status, mode)))
    return b"".join(out)


class NmeaTwin(ByteTwin):
    """An NMEA receiver streaming at ``rate_hz`` from truth or from a recording.

        NmeaTwin(car.truth, lever_arm_m=(0.0, 1.0, 1.4), seed=5)
        NmeaTwin(replay=load_drive(), replay_loop=True)
    """

    def __init__(self, truth: Callable | None = None, lever_arm_m=(0.0, 0.0, 0.0), *,
                 seed: int = 0, rate_hz: float = 10.0, cep_m: float = 2.5,
                 outage_interval_s: float = 64.0, outages=(), undulation_m: float = 55.0,
                 output_delay_s: float = 0.03, talker: str = "GP",
                 replay: list[RecordedEpoch] | None = None, replay_speed: float = 1.0,
                 replay_loop: bool = False, replay_retime: bool = True,
                 common_errors: CommonErrors | None = None):
        if truth is None and replay is None:
            raise ValueError("an NmeaTwin needs truth or a recording to replay")
        rng = np.random.default_rng(seed)
        self.solver = None if truth is None else TruthSolver(
            truth, lever_arm_m, errors=GnssErrorModel(rng, cep_m=cep_m, common=common_errors),
            sky=SkyModel(rng, outage_interval_s=outage_interval_s, outages=outages),
            undulation_m=undulation_m, hold_limit_s=0.0)
        self.replay = (None if replay is None
                       else DriveReplay(list(replay), replay_speed, replay_loop, replay_retime,
                                        undulation_m))
        self.period_ms = int(round(1000.0 / rate_hz))
        self.output_delay_s = output_delay_s
        self.talker = talker
        self.undulation_m = undulation_m
        self.clock = GpsClock()
        self._next_epoch_ms: int | None = None
        self._out = bytearray()

    def on_connect(self, now_s: float) -> None:
        self.clock.ensure(now_s)
        self._out.clear()
        if self.replay is not None and not self.replay.started:
            self.replay.begin(now_s, self.clock.gps_ms(now_s))
            if not self.replay.retime:
                self.clock.anchor(now_s, self.replay.host_gps_ms(0))

    def feed(self, data: bytes, now_s: float) -> None:
        """Configuration messages are not modelled: the receiver streams regardless."""

    def poll(self, now_s: float) -> bytes:
        self.clock.ensure(now_s)
        if self.replay is not None:
            for solution in self.replay.due(now_s):
                self._out += self._epoch(solution)
        else:
            last_due = self.clock.gps_ms(now_s - self.output_delay_s)
            if self._next_epoch_ms is None or self._next_epoch_ms < last_due - 1000:
                self._next_epoch_ms = last_due // self.period_ms * self.period_ms
            while self._next_epoch_ms <= last_due:
                gps_ms = self._next_epoch_ms
                self._next_epoch_ms += self.period_ms
                utc_ns = gps_to_utc_ns(*divmod(gps_ms, WEEK_MS))
                assert self.solver is not None, "no replay: the twin was given truth"
                self._out += self._epoch(self.solver.solve(gps_ms, utc_ns))
        out = bytes(self._out)
        self._out.clear()
        return out

    def next_due(self, now_s: float) -> float:
        if self._out:
            return now_s
        if self.replay is not None:
            due = self.replay.next_time()
            return now_s + 0.1 if due is None else max(now_s, due)
        if self._next_epoch_ms is None:
            return now_s
        return max(now_s, self.clock.now_of(self._next_epoch_ms) + self.output_delay_s)

    def _epoch(self, solution: Solution) -> bytes:
        utc_ns = gps_to_utc_ns(*divmod(solution.gps_ms, WEEK_MS))
        return nmea_epoch(solution, utc_ns, self.talker)
