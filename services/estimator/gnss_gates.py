"""Which GNSS fixes go on to be measured, before any geometry: the first gates.

A fix needs a solution (its status), is used at most `gnss_max_rate_hz` per receiver (a
receiver's errors are correlated over a second or more: fixes at 20 Hz are not 20
independent measurements a second; fewer cost less and lose nothing), and its sigmas must
be below `max_pos_sigma_m`. Every usable fix counts as its receiver being alive, and its
Doppler speed is kept (doppler.py), used or not.
"""
from __future__ import annotations

from viena.common.samples.fix import Fix
from viena.services.estimator.doppler import DopplerSpeeds
from viena.services.estimator.settings import EstimatorSettings


class FixGates:
    """The gates, and each receiver's last usable and last used fix."""

    def __init__(self, settings: EstimatorSettings) -> None:
        rate = settings.gnss_max_rate_hz
        # a fix due at the rate is used even if it comes a little early (5 ms of jitter)
        self.fix_interval_ns = int(1e9 / rate) - 5_000_000 if rate > 0 else 0
        self.max_sigma_m = settings.max_pos_sigma_m
        self.last_fix_t: dict[str, int] = {}    # last usable fix per unit
        self.used_fix_t: dict[str, int] = {}    # last fix used per unit (rate limit)
        self.doppler = DopplerSpeeds(settings.admit_max_speed_sigma_mps)  # every receiver's speed

    def forget_times(self) -> None:
        """A new timeline: the receivers' times so far mean nothing."""
        self.last_fix_t.clear()
        self.used_fix_t.clear()
        self.doppler.forget()

    def live_units(self, t: int, timeout_ns: int) -> list[str]:
        return sorted(u for u, tf in self.last_fix_t.items() if t - tf < timeout_ns)

    def refuse(self, fix: Fix) -> str | None:
        """Why `fix` goes no further ("status", "decimated", "sigma"), or None."""
        if not fix.usable:
            return "status"
        unit = fix.unit
        self.last_fix_t[unit] = max(fix.t, self.last_fix_t.get(unit, fix.t))
        self.doppler.add(fix)
        used = self.used_fix_t.get(unit)
        if used is not None and 0 <= fix.t - used < self.fix_interval_ns:
            return "decimated"
        self.used_fix_t[unit] = fix.t
        sigma = fix.enu_sigma_m or fix.ecef_sigma_m
        assert sigma is not None, "read_fix refuses a fix with neither ECEF nor ENU sigmas"
        if max(sigma) > self.max_sigma_m:
            return "sigma"
        return None
