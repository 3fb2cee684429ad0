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
    ("setpoint", {"angle_deg": 5, "seq": 1, "mac": "M"}, Setpoint(5.0, "M", 1, None, "deg", 5.0)),
    ("setpoint", {"angle_rad": math.pi / 2, "mac": "M", "t": 7, "seq": 2},
     Setpoint(90.0, "M", 2, 7, "rad", math.pi / 2)),
    ("estop", None, Estop()),
    ("estop", {"anything": [1, 2]}, Estop()),
    ("estop", {"by": "alice"}, Estop("alice")),
    ("estop", {"by": "\x1b[31mmallory"}, Estop("?[31mmallory")),
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
        BadSetpoint("missing mac: sign the setpoint with the lease the arm gave you", 2.5)
    assert parse_request("setpoint", {"angle_deg": 2.5, "mac": "M", "seq": 1, "t": 1.5}) == \
        BadSetpoint("t must be an integer time in ns UTC", 2.5)
    assert parse_request("setpoint", {"angle_deg": "left", "mac": "M", "seq": 1}) == \
        BadSetpoint("angle_deg must be a number, got str")


@pytest.mark.parametrize("seq", [-1, 2 ** 63, 1.0, True, "1", None])
def test_a_setpoints_seq_is_a_63_bit_counter(seq):
    request = parse_request("setpoint", {"angle_deg": 1.0, "mac": "M", "seq": seq})
    assert isinstance(request, BadSetpoint) and "seq must be an integer" in request.reason


def test_a_clients_text_comes_back_printable_and_short():
    """An unknown field's name is echoed in the reason, which the state shows to every
    subscriber: no terminal escapes, no 3 KB names."""
    name = "\x1b[2J\x1b[31m" + "x" * 3000
    for kind, payload in (("setpoint", {"angle_deg": 1.0, name: 1}), ("arm", {"arm": True, name: 1})):
        reason = parse_request(kind, payload).reason
        assert "\x1b" not in reason and len(reason) < 160 and "(+" in reason, reason
