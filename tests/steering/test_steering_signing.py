"""Signed setpoints (model/signing.py): the code is the documented HMAC, any client can
make it from the spec, and the helper for the `zenoh` CLI prints one the steering takes."""
from __future__ import annotations

import hashlib
import hmac
import json
import struct
import time

from viena.services.steering.client import main as steer
from viena.services.steering.client import next_seq
from viena.services.steering.model.requests import Setpoint, parse_setpoint
from viena.services.steering.model.signing import setpoint_mac, signed_setpoint


def test_the_code_is_the_documented_hmac_of_the_fixed_width_message():
    """docs/steering.md#signed-setpoints, written out again by hand: a client in another
    language that follows the spec makes the same code."""
    message = b"viena.setpoint/1" + b"deg" + struct.pack(">d", 5.0) + struct.pack(">q", 17) + struct.pack(">q", 99)
    expected = hmac.new(b"the-lease", message, hashlib.sha256).hexdigest()[:32]
    assert setpoint_mac("the-lease", "deg", 5.0, 17, 99) == expected
    payload = signed_setpoint("the-lease", 5.0, seq=17, t_ns=99)
    assert payload == {"angle_deg": 5.0, "seq": 17, "t": 99, "mac": expected}
    assert setpoint_mac("the-lease", "deg", 5.0, 17, None) == setpoint_mac("the-lease", "deg", 5.0, 17, 0)


def test_every_part_of_the_setpoint_and_the_lease_change_the_code():
    base = setpoint_mac("L", "deg", 5.0, 1, 2)
    others = [setpoint_mac("M", "deg", 5.0, 1, 2), setpoint_mac("L", "rad", 5.0, 1, 2),
              setpoint_mac("L", "deg", 5.000001, 1, 2), setpoint_mac("L", "deg", 5.0, 2, 2),
              setpoint_mac("L", "deg", 5.0, 1, 3)]
    assert base not in others and len(set(others)) == len(others)


def test_the_counter_grows_on_every_call():
    seqs = [next_seq() for _ in range(10_000)]
    assert all(b > a for a, b in zip(seqs, seqs[1:]))
    assert abs(seqs[-1] - time.time_ns()) < 10 ** 9        # nanoseconds since 1970: grows across processes too


def test_an_angle_in_radians_is_signed_as_sent():
    request = parse_setpoint(signed_setpoint("L", angle_rad=0.1, seq=1))
    assert isinstance(request, Setpoint) and request.unit == "rad"
    assert request.signed_by("L") == request.mac and request.signed_by("M") != request.mac


def test_viena_steer_sign_prints_a_setpoint_for_the_zenoh_cli(capsys):
    assert steer(["--sign", "the-lease", "--angle-deg", "5"]) == 0
    payload = json.loads(capsys.readouterr().out)
    assert "lease" not in payload and set(payload) == {"angle_deg", "seq", "mac"}
    request = parse_setpoint(payload)
    assert request.signed_by("the-lease") == request.mac
    assert steer(["--sign", "the-lease", "--angle-deg", "5", "--stamp"]) == 0
    request = parse_setpoint(json.loads(capsys.readouterr().out))
    assert request.signed_by("the-lease") == request.mac and abs(time.time_ns() - request.t_ns) < 10 ** 9
    assert request.seq > payload["seq"]
