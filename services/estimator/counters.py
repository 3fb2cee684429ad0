"""What the estimator counts: inputs used and refused, and why it last reset itself.

One object shared by the estimator's parts, so each counts where it decides, and the
state reports it all (`counts`, `gnss_used`, `gnss_rejected`, `input_rejected`,
`time_refused`, `last_reset`). Counters survive resets: they are the estimator's history, not the
filter's.
"""
from __future__ import annotations


class Counters:
    def __init__(self) -> None:
        self.counts = {"imu": 0, "gnss": 0, "gnss_decimated": 0, "imu_gaps": 0, "resets": 0,
                       "mag_rejected": 0, "nhc": 0, "zupt": 0, "course_used": 0, "inflations": 0,
                       "gnss_kind_changes": 0, "kind_steps_believed": 0}
        self.gnss_used = 0
        self.gnss_rejected: dict[str, int] = {}
        self.input_rejected: dict[str, int] = {}
        self.time_refused: dict[str, int] = {}      # source -> inputs refused for their stamp
        self.last_reset: str | None = None

    def input(self, reason: str, source: str | None = None) -> int:
        """Bad or late input, refused before any filter saw it; `source`, for a refusal for
        its time, is who sent it. Returns how many that source has had refused so."""
        self.input_rejected[reason] = self.input_rejected.get(reason, 0) + 1
        if source is None:
            return 0
        n = self.time_refused[source] = self.time_refused.get(source, 0) + 1
        return n

    def gnss(self, reason: str) -> None:
        """A well-formed fix (or part of one) that the filter refused."""
        self.gnss_rejected[reason] = self.gnss_rejected.get(reason, 0) + 1

    def reset(self, reason: str) -> None:
        self.counts["resets"] += 1
        self.last_reset = reason
