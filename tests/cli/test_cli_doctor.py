"""`viena doctor` (issue 14): one line per check, OK, WARN or FAIL with what to do, and a
non-zero exit if anything failed. The verdicts from made-up inputs (`ip` output, devices,
fixes); the command against the sim profile up and the pi profile on a machine that is not
the car."""
from __future__ import annotations

import json
import re
import socket

import pytest
from vienatest import sim_profile_up, viena

from viena import doctor
from viena.common.paths import compose_dir
from viena.doctor import FAIL, OK, WARN
from viena.profile_security import programs as programs_in

LINE = re.compile(r"^(OK|WARN|FAIL) +\S.*?: .+$")


def ip_link(flags=("UP", "LOWER_UP"), kind="can", bitrate=1_000_000, state="ERROR-ACTIVE") -> str:
    return json.dumps([{"ifname": "can0", "flags": list(flags), "link_type": "can",
                        "linkinfo": {"info_kind": kind,
                                     "info_data": {"state": state, "bittiming": {"bitrate": bitrate}}}}])


@pytest.mark.parametrize("ip, status, says", [
    (ip_link(), OK, "up at 1000000 bit/s, ERROR-ACTIVE"),
    (ip_link(flags=("NOARP",)), FAIL, "can0 is down: `sudo ip link set can0 up type can bitrate 1000000"),
    (ip_link(bitrate=500_000), FAIL, "can0 runs at 500000 bit/s, the drive at 1000000"),
    (ip_link(state="BUS-OFF"), FAIL, "can0 is BUS-OFF: check wiring, termination"),
    (ip_link(state="ERROR-PASSIVE"), WARN, "ERROR-PASSIVE"),
    (ip_link(kind="vcan"), FAIL, "not a CAN interface"),
    ("nonsense", WARN, "not checked"),
])
def test_can_interface_verdicts(ip, status, says):
    check = doctor.check_can("socketcan", "can0", 1_000_000, ip_json=ip)
    assert check.status == status and says in check.detail, check


def test_serial_device_verdicts(tmp_path):
    missing = doctor.check_serial("gnss0", str(tmp_path / "ttyUSB7"))
    assert missing.status == FAIL and "/dev/serial/by-id/" in missing.detail
    device = tmp_path / "ttyUSB0"
    device.write_text("")
    by_id = tmp_path / "usb-FTDI_FT232R_USB_UART_A1B2C3-if00-port0"
    by_id.symlink_to(device)
    found = doctor.check_serial("gnss0", str(by_id))
    assert found.status == OK and found.detail == f"-> {device}"
    unstable = doctor.check_serial("gnss0", "/dev/ttyUSB0")
    assert unstable.status == FAIL or "change between boots" in unstable.detail
    assert doctor.check_serial("gnss0", "").status == FAIL

    with socket.socket() as listening:
        listening.bind(("127.0.0.1", 0))
        listening.listen()
        port = listening.getsockname()[1]
        assert doctor.check_serial("gnss0", f"socket://127.0.0.1:{port}").status == OK
    closed = doctor.check_serial("gnss0", f"socket://127.0.0.1:{port}")
    assert closed.status == FAIL and "nothing answers" in closed.detail


def test_host_minus_gnss_time_per_receiver():
    second = 1_000_000_000
    fixes = [{"unit": "gnss0", "t": 100 * second, "t_host": 100 * second + 50_000_000},
             {"unit": "gnss0", "t": 101 * second, "t_host": 101 * second + 70_000_000},
             {"unit": "gnss0", "t": 102 * second, "t_host": 102 * second + 60_000_000},
             {"unit": "gnss1", "t": 100 * second, "t_host": 98 * second},
             {"unit": "gnss2", "t": 5, "t_host": 5},                # host-stamped: says nothing
             {"unit": "gnss3", "t": None, "t_host": 5}]
    offsets = doctor.gnss_offsets(fixes)
    assert offsets == {"gnss0": pytest.approx(0.060), "gnss1": pytest.approx(-2.0)}


def test_disk_space_verdicts(tmp_path, monkeypatch):
    assert doctor.check_disk("disk", tmp_path / "not" / "yet").status in (OK, WARN)
    monkeypatch.setattr(doctor, "DISK_FAIL_BYTES", float("inf"))
    low = doctor.check_disk("disk", tmp_path)
    assert low.status == FAIL and "make room" in low.detail


def test_a_32_bit_system_is_refused(monkeypatch):
    monkeypatch.setattr(doctor.platform, "machine", lambda: "armv7l")
    [check] = doctor.check_versions()
    assert check.status == FAIL and "64-bit Raspberry Pi OS (Bookworm)" in check.detail


def lines_of(run) -> dict[str, tuple[str, str]]:
    """name -> (status, detail), having checked that every line is one check."""
    assert "Traceback" not in run.stderr, run.stderr
    found = {}
    for line in run.stdout.strip().splitlines():
        assert LINE.match(line), line
        status, rest = line.split(None, 1)
        name, detail = rest.split(": ", 1)
        found[name] = (status, detail)
    return found


@pytest.mark.slow
def test_the_pi_profile_on_a_machine_without_the_car(tmp_path):
    """Every missing piece is a FAIL saying what to do; nothing is tried that cannot work."""
    env_run = viena("doctor", "--profile", "pi", "--keys", tmp_path / "no-keys", timeout=120,
                    env={**__import__("os").environ, "VIENA_RUN": str(tmp_path / "run"),
                         "VIENA_GNSS0_DEVICE": str(tmp_path / "gnss0"), "VIENA_CAN_CHANNEL": "viena-no-can"})
    assert env_run.returncode == 1
    checks = lines_of(env_run)
    gnss0 = checks[f"gnss0 {tmp_path / 'gnss0'}"]        # the device the variable moved it to
    assert gnss0[0] == FAIL and "ls -l /dev/serial/by-id/" in gnss0[1]
    assert checks["can socketcan viena-no-can"][0] in (FAIL, WARN)
    assert checks["keys"][0] == FAIL and "viena keys init" in checks["keys"][1]
    assert checks["versions"][0] == OK and "eclipse-zenoh" in checks["versions"][1]
    assert "check(s) failed" in env_run.stderr


@pytest.mark.slow
@pytest.mark.car
def test_the_sim_profile_up_is_healthy(tmp_path):
    with sim_profile_up(tmp_path / "run") as (env, router):
        run = viena("doctor", "--recordings", tmp_path, env=env, timeout=120)     # the running profile
        checks = lines_of(run)
        assert run.returncode == 0, run.stdout
        names = programs_in(compose_dir() / "sim.conf")              # router, sim, gnss0, gnss1, razor0, ...
        assert {"router", "sim", "gnss0", "gnss1", "razor0", "steering", "estimator"} <= set(names)
        assert checks["profile"] == (OK, f"sim (up): {', '.join(names)}")
        assert checks[f"router {router}"] == (OK, "reachable")
        off = ["caster", "ntrip", "recorder"]                        # `up --rtk`; the black box: `up --record`
        assert checks["programs"] == (OK, f"{len(names) - len(off)} running, {', '.join(off)} off")
        assert checks["ntrip"][0] == OK and checks["ntrip"][1].startswith("off: the profile runs without corrections")
        devices = [name for name in checks if name.startswith(("gnss0 socket://", "razor0 socket://", "can slcan"))]
        assert len(devices) == 3 and all(checks[name] == (OK, "listening") for name in devices)
        # the simulated receivers stamp fixes with GNSS time from the host's clock
        assert checks["clock vs GNSS"][0] == OK and "host minus GNSS time gnss0" in checks["clock vs GNSS"][1]
