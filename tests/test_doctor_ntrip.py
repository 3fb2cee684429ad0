"""`viena doctor` and the corrections chain (issue 28): the caster answers with its source
table and lists the mountpoint, one line each, with what to do when not (down, wrong port,
not a caster, a mountpoint it does not list: the nearest and the likest it does); the
receivers' model, firmware and correction formats from their health. Against the caster
twin on a free port of 127.0.0.1, and `viena doctor --rtk` on the sim profile (not up)."""
from __future__ import annotations

import os
import re
import socket

import pytest
from vienatest import free_port, viena

from viena.doctor import FAIL, OK, WARN, car_position, check_ntrip, check_receivers
from viena.services.ntrip.service import NtripSettings
from viena.services.ntrip.simulator.caster import CasterTwin, Mountpoint

ORIGIN = (38.7369, -9.1395, 100.0)
CAR = (38.7369, -9.1395)


@pytest.fixture(scope="module")
def caster():
    mountpoints = {"VIENA0": Mountpoint.at(ORIGIN, baseline_m=2000, bearing_deg=45.0),
                   "VIENA1": Mountpoint.at(ORIGIN, baseline_m=30_000, station_id=7),
                   "NEAR": Mountpoint.at(ORIGIN, baseline_m=100, vrs=True)}
    with CasterTwin(mountpoints=mountpoints, users={"rover": "secret"}) as twin:
        yield twin


def settings(port: int, mountpoint: str = "VIENA0", credentials: str = "none", **change) -> NtripSettings:
    return NtripSettings(caster="127.0.0.1", port=port, mountpoint=mountpoint, credentials=credentials, **change)


def lines(checks) -> dict[str, tuple[str, str]]:
    return {c.name: (c.status, c.detail) for c in checks}


def test_a_caster_that_lists_the_mountpoint_is_two_ok_lines(caster, tmp_path):
    login = tmp_path / "ntrip.credentials"
    login.write_text("rover:secret\n")
    login.chmod(0o600)
    said = lines(check_ntrip(settings(caster.port, credentials=str(login)), "elettra", CAR))
    assert said[f"ntrip credentials {login}"] == (OK, "one login, readable by its owner only")
    assert said[f"ntrip caster 127.0.0.1:{caster.port}"] == (OK, "answers NTRIP 2.0: 3 mountpoints in its source table")
    status, detail = said["ntrip mountpoint VIENA0"]
    assert status == OK and detail.startswith("listed: RTCM 3") and detail.endswith(", 2.0 km from the car")
    assert "secret" not in repr(said)


def test_a_mountpoint_it_does_not_list_names_the_nearest_and_the_likest(caster):
    said = lines(check_ntrip(settings(caster.port, "VIENNA0"), "elettra", CAR))
    assert said[f"ntrip caster 127.0.0.1:{caster.port}"][0] == OK
    status, detail = said["ntrip mountpoint VIENNA0"]
    assert status == FAIL
    assert detail.startswith("not in the caster's source table; nearest: NEAR (0.1 km), VIENA0 (2.0 km), "
                             "VIENA1 (30 km); names like it: VIENA0, VIENA1")
    assert detail.endswith(f"(`viena ntrip sources 127.0.0.1:{caster.port}`)")
    unplaced = lines(check_ntrip(settings(caster.port, "XYZ"), "elettra", None))["ntrip mountpoint XYZ"]
    assert unplaced[0] == FAIL and "it lists: " in unplaced[1] and "names like it" not in unplaced[1]


def test_a_mountpoint_that_wants_the_cars_position_warns_without_gga(caster):
    said = lines(check_ntrip(settings(caster.port, "NEAR"), "elettra", CAR))
    assert said["ntrip mountpoint NEAR"][0] == WARN and "gga_interval_s > 0" in said["ntrip mountpoint NEAR"][1]
    given = lines(check_ntrip(settings(caster.port, "NEAR", gga_interval_s=5.0), "elettra", CAR))
    assert given["ntrip mountpoint NEAR"][0] == OK


def test_a_caster_that_is_down_or_not_a_caster_is_one_fail_with_what_to_do(caster):
    port = free_port()                                   # nothing listens there
    said = lines(check_ntrip(settings(port), "elettra", CAR, timeout_s=2.0))
    assert said[f"ntrip caster 127.0.0.1:{port}"] == (
        FAIL, "connection refused: nothing listens there: the caster is down, or [ntrip] port is wrong "
              "(casters listen on 2101; with TLS often 443 or 2102)")
    assert said["ntrip mountpoint VIENA0"] == (WARN, "not checked: the caster gave no source table")
    twin = lines(check_ntrip(settings(port), "elettra", CAR, twin_in_profile=True, timeout_s=2.0))
    assert twin[f"ntrip caster 127.0.0.1:{port}"][1].endswith("the caster's twin is not up: `viena up --rtk`")

    caster.answer_html = True
    try:
        html = lines(check_ntrip(settings(caster.port), "elettra", CAR, timeout_s=2.0))
    finally:
        caster.answer_html = False
    status, detail = html[f"ntrip caster 127.0.0.1:{caster.port}"]
    assert status == FAIL and "not NTRIP" in detail and detail.endswith("check [ntrip] caster and port")

    with socket.create_server(("127.0.0.1", 0)) as silent:  # accepts, never answers
        port = silent.getsockname()[1]
        quiet = lines(check_ntrip(settings(port), "elettra", CAR, timeout_s=0.5))
    assert quiet[f"ntrip caster 127.0.0.1:{port}"][0] == FAIL and "in 0.5 s" in quiet[f"ntrip caster 127.0.0.1:{port}"][1]


def test_a_credentials_file_others_can_read_fails_but_the_caster_is_still_asked(caster, tmp_path):
    login = tmp_path / "open.credentials"
    login.write_text("rover:secret\n")
    login.chmod(0o644)
    said = lines(check_ntrip(settings(caster.port, credentials=str(login)), "elettra", CAR))
    status, detail = said[f"ntrip credentials {login}"]
    assert status == FAIL and f"chmod 600 {login}" in detail and "secret" not in detail
    assert said["ntrip mountpoint VIENA0"][0] == OK
    missing = lines(check_ntrip(settings(caster.port, credentials=str(tmp_path / "none-yet")), "elettra", CAR,
                                twin_in_profile=True))
    assert missing[f"ntrip credentials {tmp_path / 'none-yet'}"][0] == WARN       # the twin writes it


def health(state: dict) -> dict:
    return {"t": 1, "seq": 1, "service": "gnss", "unit": "gnss0", "uptime_s": 60.0, "rates_hz": {}, "counts": {},
            "errors": {}, "state": state}


def test_the_receivers_say_their_model_firmware_and_formats_from_health():
    said = lines(check_receivers({
        "gnss0": health({"receiver_model": "OEM4-G2 (G2L-3151W)", "receiver_firmware": "2.310",
                         "receiver_rtk": "RT-2", "receiver_formats": ["RTCM", "RTCMV3", "RTCA", "CMR"],
                         "corrections": "RTCMV3", "corrections_state": "flowing", "corrections_refused": ""}),
        "gnss1": health({"receiver_model": "OEM4-G2L", "receiver_firmware": "1.200", "receiver_formats": ["RTCM"],
                         "corrections": "RTCMV3",
                         "corrections_refused": "firmware 1.200 takes no RTCMV3 (RTCM, RTCA)"}),
        "gnss2": health({"receiver_version_error": "no VERSION in 2 s", "corrections": "RTCMV3"}),
        "gnss3": health({"fix": "valid"}),               # says nothing of its receiver: no line
    }))
    assert said["receiver gnss0"] == (OK, "OEM4-G2 (G2L-3151W), firmware 2.310, RTK RT-2; takes RTCM, RTCMV3, "
                                          "RTCA, CMR; given RTCMV3 (flowing)")
    assert said["receiver gnss1"] == (FAIL, "OEM4-G2L, firmware 1.200; takes RTCM; given RTCMV3: refused: "
                                            "firmware 1.200 takes no RTCMV3 (RTCM, RTCA)")
    assert said["receiver gnss2"] == (WARN, "model unknown (no VERSION in 2 s); given RTCMV3: whether it "
                                            "takes RTCMV3 is not known")
    assert "receiver gnss3" not in said


def test_the_cars_position_is_the_median_of_its_valid_fixes():
    fixes = [{"valid": True, "lat_deg": 38.0 + i * 1e-5, "lon_deg": -9.0} for i in range(5)]
    assert car_position(fixes + [{"valid": False, "lat_deg": 0.0, "lon_deg": 0.0}]) == (38.00002, -9.0)
    assert car_position([]) is None


@pytest.mark.slow                                       # `viena doctor` as a process (its router check waits 3 s)
def test_doctor_rtk_on_the_sim_profile_checks_its_caster(caster, tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    login = run / "ntrip.credentials"                    # where compose/sim.toml's [ntrip] reads it
    login.write_text("rover:secret\n")
    login.chmod(0o600)
    env = {**os.environ, "VIENA_RUN": str(run), "VIENA_CASTER_PORT": str(caster.port)}
    env.pop("VIENA_RTK", None)
    done = viena("doctor", "--profile", "sim", "--rtk", "--recordings", tmp_path, env=env, timeout=120)
    assert "Traceback" not in done.stderr, done.stderr
    said = dict(re.match(r"^(OK|WARN|FAIL) +(.+?): (.+)$", line).group(2, 1) for line in done.stdout.splitlines())
    assert said[f"ntrip credentials {login}"] == OK
    assert said[f"ntrip caster 127.0.0.1:{caster.port}"] == OK
    assert said["ntrip mountpoint VIENA0"] == OK
    plain = viena("doctor", "--profile", "sim", "--recordings", tmp_path, env=env, timeout=120)
    assert re.search(r"^OK +ntrip: off: the profile runs without corrections", plain.stdout, re.M), plain.stdout
    assert "ntrip caster" not in plain.stdout
