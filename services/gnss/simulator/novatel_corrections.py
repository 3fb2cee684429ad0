"""The NovAtel twin's corrections side: what its RTCMV3 ports' lines carried, read by the
receiver (rtcm_in.py), into its rover (rover.py: the solution-type machine of rtk.py and the
differential solution of differential.py), made when the first corrections are read; and
what the corrections came to, for the sim's health.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from viena.services.gnss.driver.novatel.enums import InterfaceMode

from .rover import Rover
from .rtcm_in import BasePosition

if TYPE_CHECKING:
    from .novatel_twin import NovatelTwin


class CorrectionsIntake:
    """The receiver's corrections: `read` what the lines carried, `rover` once any came."""

    def __init__(self, twin: NovatelTwin):
        self.twin = twin
        self.rover: Rover | None = None

    def health(self) -> dict:
        """What corrections came to, for the sim's health ({} while none came): the ages at
        the read (p50/p95/max, s), what the ports lost or skipped, the latest solution."""
        rover = self.rover
        lost = (self.twin.overruns + self.twin.rtcm_crc_errors + sum(self.twin.rtcm_ignored.values())
                + sum(self.twin.rtcm_malformed.values()) + self.twin.unread_bytes)
        if rover is None and not lost:
            return {}
        out: dict = {"overruns": self.twin.overruns, "rtcm_crc_errors": self.twin.rtcm_crc_errors,
                     "rtcm_ignored": sum(self.twin.rtcm_ignored.values()),
                     "rtcm_malformed": sum(self.twin.rtcm_malformed.values()), "unread_bytes": self.twin.unread_bytes}
        ages = self.twin.correction_ages_s
        if ages:
            p50, p95 = np.percentile(ages, [50, 95])
            out.update(corrections_read=len(ages), correction_age_p50_s=round(float(p50), 3),
                       correction_age_p95_s=round(float(p95), 3), correction_age_max_s=round(max(ages), 3))
        if rover is not None:
            out.update(solution=rover.status.phase, base_id=rover.status.base_id or None)
        return out

    def read(self, now_s: float) -> None:
        """What the RTCMV3 ports' lines have carried by now, read by the receiver."""
        for port in (self.twin.com1, self.twin.com2):
            if port.rxtype != InterfaceMode.RTCMV3:
                continue
            data = port.line.receive(now_s)
            if not data:
                continue
            messages = port.rtcm.feed(data)
            rover = self.rover_for_corrections() if messages else None
            if rover is None:
                continue
            gps_ms = self.twin._gps_ms(now_s)
            for m in messages:
                if isinstance(m, BasePosition):
                    rover.base_position(gps_ms, m.base_id, m.ecef_m)
                else:
                    rover.observe(gps_ms, m.tow_ms, m.base_id, m.l2)

    def rover_for_corrections(self) -> Rover | None:
        """The receiver's differential side, made when it first reads corrections (until
        then its solutions are exactly those of a receiver that takes none)."""
        twin, solver = self.twin, self.twin.solver
        if self.rover is None and solver is not None:
            self.rover = Rover(solver.errors, twin.engine, seed=twin.seed, figures=twin.rtk_figures)
            self.apply_settings()
            solver.rover = self.rover
        return self.rover

    def apply_settings(self) -> None:
        if self.rover is not None:
            machine = self.rover.machine
            machine.dgps_timeout_s = self.twin.dgps_timeout_s
            machine.psr_source, machine.rtk_source = self.twin.psr_source, self.twin.rtk_source
