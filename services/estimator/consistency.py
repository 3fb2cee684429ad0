"""How the filter judges each source, and whether it should judge itself instead.

Every update's normalised innovation squared (NIS, d2 = nu^T S^-1 nu) says how far a
measurement fell from what the filter expected, in the filter's own units: about the
number of its dimensions on average when the filter is honest (Bar-Shalom 2001, ch. 5.4).
Per kind (`position`, `velocity`, `course`, `heading`), the state carries

- `test_ratio`: the last update's d2 over the gate (PX4 EKF2's innovation test ratio:
  above 1 the measurement was refused), and
- `nis`: d2 per dimension, averaged over about the last `AVERAGE_UPDATES` updates
  (1 when the filter is consistent, much more when it is too sure of itself).

A receiver whose fixes fail now and then is that receiver's doing; a filter that refuses
fix after fix, or whose NIS stays high, is wrong about itself (an IMU worse than its
settings say, a mount or clock off). Two answers, before the last resort of a reset:

- the process noise is scaled up while more than `REFUSED_SHARE` of the recent velocity
  updates are refused (or their average NIS is above `HIGH_NIS`), and back down, slowly,
  while none are and the NIS is below `LOW_NIS` (an adaptive Q in the sense of Mehra 1970
  and Groves 2013 ch. 3): the filter trusts its prediction as much as the data show it
  deserves. The velocity judges because a receiver's own position errors (a multipath
  burst, a jump when the satellites change) leave its Doppler velocity alone; for a
  receiver without velocity, the positions judge;
- after refusals in a row of one kind from one receiver for half of `gnss_reset_s` (and
  at least `REFUSALS_TO_INFLATE` of them: a burst of multipath is refused, seconds of
  disagreement are not the receiver's alone), the covariance of that block grows by the
  disagreement itself (nu nu^T), so the next measurement is weighed against an
  uncertainty that admits it, and the estimate follows GNSS again instead of coasting on
  a prediction it has no reason to believe. The reset of gnss_update.py stays the last
  resort, for a disagreement that survives this for the whole `gnss_reset_s`.
"""
from __future__ import annotations

import math

#: the NIS average spans about this many updates of a kind
AVERAGE_UPDATES = 20
#: the process noise grows while more than this share of the last AVERAGE_UPDATES position
#: or velocity updates were refused, or their average NIS per dimension is above HIGH_NIS;
#: it shrinks back while none was refused and the average is below LOW_NIS
REFUSED_SHARE = 0.15
HIGH_NIS = 2.0
LOW_NIS = 1.0
#: the process noise scale moves by these factors, once per AVERAGE_UPDATES updates at most
GROW, SHRINK = 2.0, 1.25
MAX_SCALE = 100.0
#: refusals in a row (of one kind, one receiver) that mean the filter, not the receiver, is off
REFUSALS_TO_INFLATE = 3
#: courses refused in a row that mean the heading filter, not the receiver, is off
COURSE_REFUSALS_TO_INFLATE = 10

KINDS = ("position", "velocity", "course", "heading")


class Consistency:
    def __init__(self, inflate_after_s: float = 2.5):
        self.inflate_after_ns = int(inflate_after_s * 1e9)
        self.nis: dict[str, float | None] = {k: None for k in KINDS}          # average d2 per dimension
        self.test_ratio: dict[str, float | None] = {k: None for k in KINDS}   # last d2 / gate
        self._velocity_seen = AVERAGE_UPDATES     # updates since the last velocity one
        self._report: tuple | None = None         # the rounded figures, until they change
        self.restart()

    def restart(self) -> None:
        """A new estimate: what the old one's innovations said no longer holds."""
        self.q_scale = 1.0
        self._report = None
        self._since_scale = 0
        self._refused: dict[tuple[str, str], tuple[int, int]] = {}    # refusals in a row, since
        self._refused_share = {"position": 0.0, "velocity": 0.0}

    def seen(self, kind: str, d2: float, dof: int, gate: float, judges: bool = True) -> None:
        """One update of `kind` was tested: its NIS d2 with `dof` dimensions against `gate`.
        `judges`: it may move the process noise (not a velocity made from the positions)."""
        if not math.isfinite(d2):
            return
        self._report = None
        self.test_ratio[kind] = d2 / gate
        per_dof = min(d2 / dof, 100.0)                  # one wild measurement is not an average
        avg = self.nis[kind]
        self.nis[kind] = per_dof if avg is None else avg + (per_dof - avg) / AVERAGE_UPDATES
        share = self._refused_share.get(kind)
        if share is None or not judges:
            return
        self._refused_share[kind] = share + ((d2 > gate) - share) / AVERAGE_UPDATES
        if kind == "velocity":
            self._velocity_seen = 0
        else:
            self._velocity_seen += 1
        self._since_scale += 1
        if self._since_scale >= AVERAGE_UPDATES:
            self._rescale()

    def _rescale(self) -> None:
        """The process noise follows the velocity's judgement when the receivers send one: a
        multipath burst or a jump at a satellite change moves the positions, not the Doppler
        velocity, and is the receiver's doing, not the filter's. A position-only receiver
        leaves the positions to judge by."""
        kind = "velocity" if self._velocity_seen < AVERAGE_UPDATES else "position"
        nis, refused = self.nis[kind], self._refused_share[kind]
        if nis is None:
            return
        self._since_scale = 0
        if (refused > REFUSED_SHARE or nis > HIGH_NIS) and self.q_scale < MAX_SCALE:
            self.q_scale = min(MAX_SCALE, self.q_scale * GROW)
        elif refused < 0.01 and nis < LOW_NIS and self.q_scale > 1.0:
            self.q_scale = max(1.0, self.q_scale / SHRINK)

    def refused(self, unit: str, kind: str, ok: bool, t: int | None = None,
                after_s: float | None = None) -> bool:
        """Count a refusal (or an acceptance) of `kind` from `unit` at time t (ns); True
        when the refusals in a row, at least REFUSALS_TO_INFLATE of them over at least
        `inflate_after_s`, mean the filter should widen that block. Without a time (the
        courses: one per fix), COURSE_REFUSALS_TO_INFLATE in a row. `after_s` stands for
        `inflate_after_s` (positions refused while the receiver's velocity agrees)."""
        key = (unit, kind)
        if ok:
            self._refused.pop(key, None)
            return False
        n, since = self._refused.get(key, (0, t or 0))
        n += 1
        after_ns = self.inflate_after_ns if after_s is None else int(after_s * 1e9)
        if (t is None and n >= COURSE_REFUSALS_TO_INFLATE) or (
                t is not None and n >= REFUSALS_TO_INFLATE and t - since >= after_ns):
            self._refused.pop(key, None)
            return True
        self._refused[key] = (n, since)
        return False

    def report(self) -> dict:
        """The state's fields (every state has them; they change only with an update)."""
        if self._report is None:
            rnd = lambda v: None if v is None else round(v, 3)      # noqa: E731
            self._report = ({k: rnd(v) for k, v in self.nis.items()},
                            {k: rnd(v) for k, v in self.test_ratio.items()}, round(self.q_scale, 3))
        nis, test_ratio, scale = self._report
        return {"nis": dict(nis), "test_ratio": dict(test_ratio), "process_noise_scale": scale}
