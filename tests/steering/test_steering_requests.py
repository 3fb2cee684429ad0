"""Requests are parsed and checked in one place: a payload becomes a typed request, or a
refusal saying what is wrong with it (the envelope's tests cover the setpoints' reasons)."""
from __future__ import annotations

import math

import pytest

from viena.services.steering.model.requests import (
    Arm,
    BadSetpoint,
    CalibrationRequest,
    Disarm,
    Estop,
    Refused,
    Setpoint,
    parse_request,
)


@pytest.mark.parametrize("kind, payload, typed", [
    ("arm", {"arm": True}, Arm(None)),
    ("arm", {"arm": True, "lease": "L"}, Arm("L")),
    ("arm", {"arm": False, "lease": "L"}, Disarm("L")),
    ("setpoint", {"angle_deg": 5, "lease": "L"}, Setpoint(5.0, "L")),
    ("setpoint", {"angle_rad": math.pi / 2, "lease": "L", "t": 7, "seq": "x"}, Setpoint(90.0, "L", 7, "x")),
    ("estop", None, Estop()),
    ("estop", {"anything": [1, 2]}, Estop()),
    ("calibration", None, CalibrationRequest("status")),
    ("calibration", {}, CalibrationRequest("status")),
    ("calibration", {"restart": False}, CalibrationRequest("status")),
    ("calibration", {"restart": True}, CalibrationRequest("restart")),
    ("calibration", {"finish": True}, CalibrationRequest("finish")),
])
def test_well_formed_payloads_become_typed_requests(kind, payload, typed):
    assert parse_request(kind, payload) == typed


@pytest.mark.parametrize("kind, payload, reason", [
    ("arm", [1, 2], "expected a map"),
    ("arm", {"arm": "yes"}, "arm must be true or false"),
    ("arm", {"arm": True, "force": True}, "unknown field 'force' (known: arm, lease)"),
    ("arm", {"arm": True, "lease": 7}, "lease must be text"),
    ("calibration", {"reset": 1}, "expected {} (status)"),
    ("calibration", "restart", "expected {} (status)"),
    ("steer", {}, "unknown request steer"),
])
def test_malformed_requests_are_refused_with_the_reason(kind, payload, reason):
    request = parse_request(kind, payload)
    assert isinstance(request, Refused) and reason in request.reason


def test_a_malformed_setpoint_keeps_the_angle_it_asked_for_when_there_was_one():
    assert parse_request("setpoint", {"angle_deg": 2.5}) == \
        BadSetpoint("missing lease: arm first, then send its lease", 2.5)
    assert parse_request("setpoint", {"angle_deg": 2.5, "lease": "L", "t": 1.5}) == \
        BadSetpoint("t must be an integer time in ns UTC", 2.5)
    assert parse_request("setpoint", {"angle_deg": "left", "lease": "L"}) == \
        BadSetpoint("angle_deg must be a number, got str")
