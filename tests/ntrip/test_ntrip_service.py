"""`viena-ntrip` as a process: the caster twin's RTCM 3 on gnss/corrections, the client's
state on ntrip/state and its health; a login file others can read stops it at start in one
line; a wrong mountpoint is said and counted; the car's fixes go upstream as GGA; and
`viena ntrip sources` lists the twin's mountpoints by distance."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import time

import pytest
import zenoh
from vienatest import PYTHON, collect, collect_until, free_port, wait_until

from viena.common.samples.corrections import CORRECTIONS, read_corrections
from viena.common.samples.fix import FIX
from viena.common.samples.health import HEALTH
from viena.common.samples.ntrip import STATE, read_state
from viena.services.ntrip.service import ERROR_KINDS
from viena.services.ntrip.simulator.caster import CasterTwin, Mountpoint
from viena.services.ntrip.simulator.timebase import Timebase

pytestmark = [pytest.mark.slow, pytest.mark.timeout(90)]  # the service as a process

ORIGIN = (38.7369, -9.1427, 100.0)
USER, PASSWORD = "rover", "n0t-in-the-logs"



@pytest.fixture(scope="module")
def caster():
    twin = CasterTwin(mountpoints={"VIENA0": Mountpoint.at(ORIGIN, 1000.0, 45.0, station_id=2050),
                                   "VRS": Mountpoint.at(ORIGIN, 0.0, station_id=17, vrs=True)},
                      users={USER: PASSWORD}, timebase=Timebase(rate=10.0)).start()
    yield twin
    twin.stop()


@pytest.fixture
def login(tmp_path):
    path = tmp_path / "ntrip.credentials"
    path.write_text(f"{USER}:{PASSWORD}\n")
    os.chmod(path, 0o600)
    return str(path)


def ntrip(procs, router, car, caster, mountpoint, *extra, **kw):
    return procs.python("-m", "viena.services.ntrip.service", "--connect", router, "--car", car,
                        "--caster", "127.0.0.1", "--port", str(caster.port), "--mountpoint", mountpoint,
                        *extra, **kw)


def states_until(session, car, predicate, timeout=10.0):
    got = collect_until(session, f"viena/{car}/ntrip/state", lambda out: out and predicate(out[-1]),
                        timeout, decode=STATE.decode)
    assert got and predicate(got[-1]), got[-1:] or "no state"
    return got[-1]


def health_until(session, car, predicate, timeout=10.0):
    got = collect_until(session, f"viena/{car}/ntrip/health", lambda out: out and predicate(out[-1]),
                        timeout, decode=HEALTH.decode)
    assert got and predicate(got[-1]), got[-1:] or "no health"
    return got[-1]


def test_corrections_state_and_health_on_zenoh(procs, zrouter, zsession, caster, login):
    proc = ntrip(procs, zrouter, "ntripok", caster, "VIENA0", "--credentials", login)
    got = collect(zsession, "viena/ntripok/gnss/corrections", 12, timeout=20.0, decode=CORRECTIONS.decode)
    assert len(got) == 12
    samples = [read_corrections(s) for s in got]
    assert all(c.source == f"127.0.0.1:{caster.port}/VIENA0" and c.format == "RTCMV3" for c in samples)
    assert all(b.seq == a.seq + 1 for a, b in zip(samples, samples[1:]))
    types = [t for c in samples for t in c.types]
    assert 1004 in types and {c.base_id for c in samples if 1004 in c.types} == {"2050"}
    from pyrtcm import RTCMReader
    for c in samples:                       # whole frames, nothing else, in the order of types
        i, numbers = 0, []
        while i < len(c.data):
            n = ((c.data[i + 1] & 3) << 8 | c.data[i + 2]) + 6
            numbers.append(int(RTCMReader.parse(c.data[i:i + n]).identity))
            i += n
        assert numbers == list(c.types)
    state = states_until(zsession, "ntripok", lambda s: s["state"] == "streaming" and s["bytes_per_s"] > 0)
    st = read_state(state)
    assert st.connected and st.base_id == "2050" and st.messages.get("1004", 0) > 0 and st.why is None
    assert state["caster"] == f"127.0.0.1:{caster.port}" and state["version"] == "2.0"
    health = health_until(zsession, "ntripok", lambda h: h["counts"].get("corrections", 0) > 0)
    assert set(ERROR_KINDS) <= set(health["errors"]) and not any(health["errors"].values())
    assert health["state"]["link"] == "streaming" and health["last_sample_age_s"] < 2.0
    proc.send_signal(signal.SIGTERM)
    out, _ = proc.communicate(timeout=10)
    assert proc.returncode == 0
    assert PASSWORD not in out


def test_a_login_file_others_can_read_stops_the_start_in_one_line(tmp_path, caster):
    loose = tmp_path / "loose"
    loose.write_text(f"{USER}:{PASSWORD}\n")
    os.chmod(loose, 0o644)
    run = subprocess.run([PYTHON, "-m", "viena.services.ntrip.service", "--caster", "127.0.0.1",
                          "--port", str(caster.port), "--mountpoint", "VIENA0", "--credentials", str(loose)],
                         capture_output=True, text=True, timeout=60)
    assert run.returncode == 2 and run.stderr.count("\n") == 1
    assert f"is open to group or others (mode 0644): chmod 600 {loose}" in run.stderr


def test_a_login_file_not_there_yet_is_waited_for_and_said_in_the_state(procs, zrouter, zsession, caster,
                                                                        tmp_path):
    """The sim's caster twin writes the file as it starts, beside this program: a missing
    one does not stop the start; each attempt looks again and the state says what to do."""
    later = tmp_path / "later.credentials"
    ntrip(procs, zrouter, "ntriplater", caster, "VIENA0", "--credentials", str(later))
    state = states_until(zsession, "ntriplater", lambda s: s["state"] == "refused")
    assert state["why"] == (f"credentials file {later} does not exist: write one line user:password "
                            f"into it and chmod 600 it")
    assert not state["connected"] and state["attempts"] == 1


def test_a_wrong_mountpoint_is_said_and_counted(procs, zrouter, zsession, caster, login):
    ntrip(procs, zrouter, "ntripbad", caster, "NOPE", "--credentials", login, "--lost-after-s", "1")
    state = states_until(zsession, "ntripbad", lambda s: s["state"] == "refused")
    assert state["why"] == "mountpoint NOPE not in the caster's source table" and not state["connected"]
    assert 5.0 < state["next_attempt_s"] <= 10.0
    health = health_until(zsession, "ntripbad", lambda h: h["errors"].get("lost", 0) == 1)
    assert health["errors"]["mountpoint_unknown"] == 1
    assert health["state"]["link"].startswith("corrections lost for ")
    assert health["state"]["link"].endswith("s: mountpoint NOPE not in the caster's source table")


def fix_sample(seq: int, lat: float, lon: float, h: float) -> dict:
    import pymap3d
    x, y, z = pymap3d.geodetic2ecef(lat, lon, h)
    t = time.time_ns()
    return {"t": t, "seq": seq, "unit": "gnss0", "protocol": "novatel", "valid": True,
            "pos_status": "SOL_COMPUTED", "pos_type": "SINGLE", "vel_status": "SOL_COMPUTED", "vel_type": "SINGLE",
            "ecef_m": [x, y, z], "ecef_sigma_m": [1.0, 1.0, 1.0], "lat_deg": lat, "lon_deg": lon,
            "height_m": h, "sats_tracked": 12, "sats_used": 9, "gps_week": 2400, "gps_ms": 0, "t_host": t,
            "latency_s": 0.0, "vel_latency_s": 0.0}


def test_the_cars_fix_goes_upstream_to_a_vrs_mountpoint(procs, zrouter, zsession, caster, login):
    here = (38.7401, -9.1388, 95.0)
    pub = zsession.declare_publisher("viena/ntripvrs/gnss/gnss0/fix", encoding=zenoh.Encoding(FIX.encoding))
    proc = ntrip(procs, zrouter, "ntripvrs", caster, "VRS", "--credentials", login, "--gga-interval-s", "0.5")
    try:
        seq = 0

        def publish_and_check() -> bool:
            nonlocal seq
            seq += 1
            pub.put(FIX.encode(fix_sample(seq, *here)))
            time.sleep(0.1)
            return any(c.mountpoint == "VRS" and c.base is not None for c in caster.clients)
        assert wait_until(publish_and_check, 20.0, period=0.0), proc.poll()
        got = collect(zsession, "viena/ntripvrs/gnss/corrections", 3, timeout=10.0, decode=CORRECTIONS.decode)
        assert got and {c["base_id"] for c in got if 1004 in c["types"]} == {"17"}
    finally:
        pub.undeclare()
    client = next(c for c in caster.clients if c.mountpoint == "VRS" and c.base is not None)
    assert abs(client.base.position[0] - here[0]) < 1e-4 and abs(client.base.position[1] - here[1]) < 1e-4
    assert all(",3844.40600,N,00908.32800,W,1,9," in g for g in client.gga)


def test_viena_ntrip_sources_lists_the_twins_mountpoints_nearest_first(caster):
    base = [PYTHON, "-m", "viena.ntrip_cli", "sources", f"127.0.0.1:{caster.port}",
            "--connect", f"tcp/127.0.0.1:{free_port()}"]
    run = subprocess.run([*base, "--near", "38.7369,-9.1427"], capture_output=True, text=True, timeout=60)
    assert run.returncode == 0, run.stderr
    lines = run.stdout.splitlines()
    assert lines[0].startswith("# 2 mountpoints of 127.0.0.1:") and "(--near) first" in lines[0]
    assert lines[1].split()[:2] == ["mountpoint", "km"]
    assert lines[2].split()[:2] == ["VRS", "0.0"] and lines[3].split()[:2] == ["VIENA0", "1.0"]
    assert "RTCM 3.1" in lines[3] and "GPS" in lines[3]
    as_json = subprocess.run([*base, "--near", "38.7369,-9.1427", "--json"], capture_output=True, text=True,
                             timeout=60)
    rows = [json.loads(line) for line in as_json.stdout.splitlines()]
    assert [r["name"] for r in rows] == ["VRS", "VIENA0"] and rows[0]["wants_gga"] is True
    no_fix = subprocess.run(base, capture_output=True, text=True, timeout=60)
    assert no_fix.returncode == 0 and "distances need --near LAT,LON" in no_fix.stderr
    down = subprocess.run([PYTHON, "-m", "viena.ntrip_cli", "sources", f"127.0.0.1:{free_port()}",
                           "--near", "0,0"], capture_output=True, text=True, timeout=60)
    assert down.returncode == 1 and down.stderr.strip().endswith(": connection refused")
    assert down.stderr.count("\n") == 1


def test_viena_ntrip_sources_measures_from_the_cars_fix(zrouter, zsession, caster):
    """Without --near, the distances are from the newest fix on the car's bus."""
    import threading
    pub = zsession.declare_publisher("viena/ntripcli/gnss/gnss1/fix", encoding=zenoh.Encoding(FIX.encoding))
    stop = threading.Event()
    lat, lon, h = caster.mountpoints["VIENA0"].base.position                  # the car at the base

    def publish():
        seq = 0
        while not stop.wait(0.1):
            seq += 1
            pub.put(FIX.encode(fix_sample(seq, lat, lon, h)))
    thread = threading.Thread(target=publish, daemon=True)
    thread.start()
    try:
        run = subprocess.run([PYTHON, "-m", "viena.ntrip_cli", "sources", f"127.0.0.1:{caster.port}",
                              "--connect", zrouter, "--car", "ntripcli"], capture_output=True, text=True, timeout=60)
    finally:
        stop.set()
        thread.join()
        pub.undeclare()
    assert run.returncode == 0, run.stderr
    lines = run.stdout.splitlines()
    assert f"nearest to {lat:.5f}, {lon:.5f} (the car's fix) first" in lines[0]
    assert lines[2].split()[:2] == ["VIENA0", "0.0"] and lines[3].split()[:2] == ["VRS", "1.0"]
