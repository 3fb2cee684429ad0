"""`viena-sim`: the simulated car, the hardware of every simulated device.

It steps the bicycle model at a fixed rate, publishes ground truth on viena/<car>/sim/truth,
and serves each device twin on its own local endpoint (serial devices as
`socket://127.0.0.1:PORT` for pyserial, the steering drive as a CAN adapter), so the
device services run their real drivers against it.
"""
from __future__ import annotations

from dataclasses import dataclass

from viena.common import clock
from viena.common.errors import SampleError
from viena.common.samples import topics
from viena.common.samples.steering import STATE as STEERING_STATE
from viena.common.service import Service, run_service
from viena.common.settings import part, setting
from viena.services.sim.devices import start_devices
from viena.services.sim.model.car import CarParams, SimCar
from viena.services.sim.model.truth import IST_ORIGIN, truth_sample
from viena.services.steering.simulator import PersonAtTheWheel


@dataclass(frozen=True)
class SimSettings:
    """[sim]: the simulated car, its truth and the device twins it serves."""
    rate_hz: float = setting(100.0, "steps of the car, and truth samples, per second")
    origin: tuple[float, ...] = setting(IST_ORIGIN, "the local ENU frame's origin (IST campus)",
                                        metavar=("LAT_DEG", "LON_DEG", "HEIGHT_M"))
    host: str = setting("127.0.0.1", "where the device twins' endpoints listen")
    seed: int = setting(1, "random seed the twins' errors derive from")
    devices: tuple[str, ...] = setting((), "device twins to serve, each with a `[sim.<name>]` table",
                                       metavar="NAME", flags=("--device",))
    car: CarParams = part(CarParams, "the car's shape and how it drives the loop")


class SimService(Service):
    """The simulated car: kinematic bicycle model at the IST campus, driving a loop."""

    name = "sim"
    settings_class = SimSettings

    def start(self) -> None:
        s = self.settings
        self.car = SimCar(s.car, origin=s.origin)
        self._truth_pub = self.publisher(topics.SIM_TRUTH)
        self.devices = start_devices(self, self.car)
        wheels = [d.twin for d in self.devices if hasattr(getattr(d, "twin", None), "ask_for_sweep")]
        if wheels:
            self._person = PersonAtTheWheel(wheels)
            self.declare_subscriber(self.keys.of(topics.STEERING_STATE), self._on_steering_state)
        self._thread = clock.Thread(target=self._loop, name="sim-car", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self.stopping.set()
        if hasattr(self, "_thread"):
            self._thread.join(timeout=1)
        for device in getattr(self, "devices", []):
            device.stop()

    def _on_steering_state(self, sample) -> None:
        """The simulated person reads the steering's state as a person reads the monitor."""
        try:
            state = STEERING_STATE.decode(sample.payload.to_bytes())
        except SampleError:
            return
        if self._person.read(state):
            self.log.info("the person at the wheel sweeps it lock to lock, as the steering asks")

    def _loop(self) -> None:
        """Fixed-rate stepping on absolute deadlines, so the rate does not drift."""
        dt = 1.0 / self.settings.rate_hz
        self.car.start_clock(clock.time_ns() - int(dt * 1e9))   # the first step ends now
        next_t = clock.monotonic()
        steps, per_second = 0, max(1, round(self.settings.rate_hz))
        while not self.stopping.is_set():
            truth = self.car.step(dt)
            if self._truth_pub.put(truth_sample(truth)):
                self.health.count("truth")
                self.health.mark_sample()
            steps += 1
            if steps % per_second == 0:
                self._device_figures()
            next_t += dt
            delay = next_t - clock.monotonic()
            if delay > 0:
                self.stopping.wait(delay)
            elif delay < -0.5:                 # fell far behind (suspended, starved): say so, catch up
                # The world did not stop meanwhile: the car is stepped through the time it
                # missed (publishing none of it), so its clock stays on the wall clock. Skipping
                # the time instead left every later truth and GNSS time behind the IMU's, which
                # its service stamps on arrival: the estimator then fused fixes a second old.
                missed = int(-delay / dt)
                self.log.warning("behind by %.1f s: the car catches up %d steps", -delay, missed)
                self.health.error("overrun")
                for _ in range(missed):
                    self.car.step(dt)
                next_t += missed * dt
        self.health.set("position_enu_m", [round(v, 2) for v in self.car.truth().enu_m])


    def _device_figures(self) -> None:
        """What a twin says of itself (a receiver: the corrections it read, their age at
        the read), into the sim's health under the device's name, once a second."""
        for name, device in zip(self.settings.devices, self.devices):
            figures = device.health() if hasattr(device, "health") else None
            if figures:
                self.health.set(name, figures)


def main(argv=None) -> int:
    return run_service(SimService, argv)


if __name__ == "__main__":
    raise SystemExit(main())
