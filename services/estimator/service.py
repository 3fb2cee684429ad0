"""viena-estimator: the car's state from its IMU and GNSS samples, on zenoh.

    viena-estimator [--imu-key imu/razor0/sample] [--gnss-key 'gnss/*/fix'] [--origin LAT LON H]

Subscribes to viena.imu.sample/1 and viena.gnss.fix/1 samples (key expressions relative to
viena/<car>/, settings `imu_key` and `gnss_key`), feeds them to `Estimator` on one worker
thread, and publishes viena.estimator.state/2 on viena/<car>/estimator/state after every
IMU sample it uses (after every fix when there is no IMU). Thin on purpose: everything
the estimator does is in estimator.py (and the modules it wires) and runs the same offline.
Routes and the way to the next checkpoint are the pilot's (services/pilot).
"""
from __future__ import annotations

import queue
from dataclasses import dataclass

from viena.common import clock
from viena.common.errors import ConfigError, InputError
from viena.common.samples import topics
from viena.common.schema import unpack
from viena.common.service import Service, run_service
from viena.common.settings import part, setting
from viena.services.estimator.estimator import Estimator
from viena.services.estimator.settings import EstimatorSettings


@dataclass(frozen=True)
class EstimatorServiceSettings:
    """[estimator]: where the samples come from, and the estimator's own settings."""
    imu_key: str = setting(topics.IMU_SAMPLE.key(), "IMU samples, key relative to `viena/<car>/`; one unit is used",
                           metavar="KEYEXPR")
    gnss_key: str = setting(topics.GNSS_FIX.key(), "GNSS fixes, key relative to `viena/<car>/`; one or more receivers",
                            metavar="KEYEXPR")
    queue_size: int = setting(2000, "samples waiting for the worker (~10 s of input)")
    estimator: EstimatorSettings = part(EstimatorSettings, "the filters (estimator.py, also offline)")


class EstimatorService(Service):
    """Attitude, position and velocity of the car from its IMU and GNSS receivers."""

    name = "estimator"
    settings_class = EstimatorServiceSettings

    def start(self) -> None:
        s = self.settings
        try:
            self.estimator = Estimator(s.estimator, clock=clock.time_ns, log=self.log)
        except ValueError as exc:
            raise ConfigError(f"[estimator]: {exc}") from None
        self._queue = clock.Queue(maxsize=max(10, s.queue_size))
        self.state_pub = self.publisher(topics.ESTIMATOR_STATE)
        imu_key, gnss_key = self.keys.key(s.imu_key), self.keys.key(s.gnss_key)
        self.declare_subscriber(imu_key, lambda sample: self._enqueue("imu", sample))
        self.declare_subscriber(gnss_key, lambda sample: self._enqueue("gnss", sample))
        self.log.info("estimating from %s and %s", imu_key, gnss_key)
        self._last_health = 0.0
        self._thread = clock.Thread(target=self._run, name="estimator", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self.stopping.set()
        thread = getattr(self, "_thread", None)
        if thread is not None:
            thread.join(timeout=1.0)

    # -- zenoh callbacks: never block -----------------------------------------------------------
    def _enqueue(self, kind: str, sample) -> None:
        try:
            self._queue.put_nowait((kind, sample.payload.to_bytes()))
        except queue.Full:
            self.health.error("queue_full")

    # -- the worker -----------------------------------------------------------------------------
    def _run(self) -> None:
        while not self.stopping.is_set():
            try:
                kind, payload = self._queue.get(timeout=0.2)
            except queue.Empty:
                continue
            try:
                self._handle(kind, payload)
            except Exception:                    # noqa: BLE001 - the worker must survive anything
                self.health.error("internal")
                self.log.exception("estimator failed on a %s sample", kind)

    def _handle(self, kind: str, payload: bytes) -> None:
        est = self.estimator
        try:
            sample = unpack(payload, kind)
        except InputError:
            self.health.error(f"bad_{kind}_payload")
            return
        self.health.count(kind)
        if kind == "imu":
            if est.add_imu(sample):
                self.health.mark_sample()
                self._publish()
        elif est.add_gnss(sample) and not est.imu_live:
            self._publish()

    def _publish(self) -> None:
        state = self.estimator.state()
        if self.state_pub.put(state):
            self.health.count("state")
        now = clock.monotonic()
        if now - self._last_health >= 1.0:
            self._last_health = now
            for name in ("mode", "heading_source", "gnss_live", "gnss_used", "gnss_rejected",
                         "input_rejected", "time_refused", "last_reset", "sigma_h_m",
                         "imu_time_offset_hint_s", "imu_mount_hint_deg", "nis", "test_ratio",
                         "process_noise_scale", "gnss_admission", "gnss_kind", "gnss_diff_age_s"):
                self.health.set(name, state[name])
            self._report_clock(state["imu_time_offset_hint_s"])

    def _report_clock(self, hint_s) -> None:
        """Once, when the fixes start pointing at an IMU clock offset (and when they stop)."""
        rounded = None if hint_s is None else round(hint_s, 2)
        if rounded == getattr(self, "_clock_hint", None):
            return
        self._clock_hint = rounded
        if hint_s is None:
            self.log.info("the IMU's stamps agree with the GNSS clock again")
        else:
            self.log.warning("the GNSS course turns %.0f ms %s the gyro by the IMU's stamps: the IMU "
                             "clock looks off; its time_offset_s should be about %+.3f s",
                             abs(hint_s) * 1e3, "before" if hint_s < 0 else "after", hint_s)


def main(argv: list[str] | None = None) -> int:
    return run_service(EstimatorService, argv)


if __name__ == "__main__":
    raise SystemExit(main())
