"""The EPOS device in the simulated car: the sim's factory, and a setpoint turning the car."""
from __future__ import annotations

import math
import types

import pytest
from vienatest import FAST_SWEEP, calibrated_with_a_person_at, signed, wait_until

from viena.common.errors import ConfigError
from viena.services.sim.model.car import SimCar
from viena.services.sim.service import SimSettings
from viena.services.steering.controller import SteeringController
from viena.services.steering.driver import DriveSettings, EposDrive
from viena.services.steering.model.calibration import CalibrationSettings
from viena.services.steering.model.safety import Envelope
from viena.services.steering.model.speed import SpeedSettings
from viena.services.steering.simulator import make_epos_device


def fake_service():
    return types.SimpleNamespace(args=types.SimpleNamespace(config="sim.toml"), settings=SimSettings())


@pytest.fixture
def device():
    car = SimCar()
    dev = make_epos_device("epos0", {"port": 0, **FAST_SWEEP}, car, fake_service())
    yield dev, car
    dev.stop()


def test_the_factory_serves_the_twin_as_an_slcan_adapter_and_drives_the_wheels(device):
    dev, car = device
    assert dev.url.startswith("socket://127.0.0.1:") and dev.port > 0
    truth = car.step(0.01)
    assert truth.wheel_angle_rad == pytest.approx(dev.twin.wheel_angle_rad())
    assert math.degrees(truth.wheel_angle_rad) == pytest.approx(-7.5014e-4 * 1500)


@pytest.mark.parametrize("table, match", [
    ({"colour": "red"}, "unknown setting 'colour'"),
    ({"plant": "rocket"}, "plant must be one of"),
])
def test_bad_device_settings_are_config_errors(table, match):
    with pytest.raises(ConfigError, match=match):
        make_epos_device("epos0", table, SimCar(), fake_service())


@pytest.fixture
def steering(device):
    """A steering controller on the device over slcan, as the service runs it, and
    `calibrated()`: whether it is past its calibration (a person at the wheel sweeps again
    if a stalled test process made it throw a sweep away)."""
    dev, car = device
    drive = EposDrive(DriveSettings(interface="slcan", channel=dev.url,
                                    bus_options={"sleep_after_open": 0, "timeout": 0.01}))
    ctl = SteeringController(drive, Envelope(speed_settings=SpeedSettings(speed_conservative_mps=0.0)), CalibrationSettings(sweep_settle_s=0.2))
    ctl.start()
    ready = calibrated_with_a_person_at(dev.twin)
    try:
        yield ctl, lambda: ready(ctl.state())
    finally:
        ctl.stop()


@pytest.mark.slow  # a calibration sweep in real time
def test_a_setpoint_over_slcan_turns_the_simulated_car(device, steering):
    dev, car = device
    ctl, calibrated = steering
    assert wait_until(calibrated, 10.0), ctl.state()
    lease = ctl.request("arm", {"arm": True})["lease"]

    def steering_left():
        ctl.request("setpoint", signed({"angle_deg": 6.0, "lease": lease}))
        return abs(math.degrees(car.step(0.02).wheel_angle_rad) - 6.0) < 0.3
    assert wait_until(steering_left, 3.0, period=0.02)


@pytest.mark.slow  # two calibration sweeps in real time
def test_the_controller_reconnects_when_the_adapter_comes_back(device, steering):
    from viena.common.twin.slcan_hub import SlcanHub
    dev, car = device
    ctl, calibrated = steering
    assert wait_until(calibrated, 10.0), ctl.state()
    ctl.request("arm", {"arm": True})
    dev.hub.stop()                                  # the USB adapter is pulled out
    assert wait_until(lambda: not ctl.link_ok and ctl.phase == "connecting", 2.0)
    assert not ctl.envelope.armed and "CAN link lost" in ctl.state()["trip"]
    dev.hub = SlcanHub(dev.hub.channel, port=dev.port).start()    # and plugged back in
    assert wait_until(calibrated, 15.0), ctl.state()
    assert ctl.request("arm", {"arm": True})["status"] == "accepted"
