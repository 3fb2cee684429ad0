"""The driver against the EPOS twin on a virtual CAN bus: configuration, DS402, Position
Mode, faults with their EMCY, heartbeats both ways, and the plant fitted to the car."""
from __future__ import annotations

import difflib
from pathlib import Path

import canopen
import pytest
from vienatest import wait_until

from viena.services.steering.driver import EDS_PATH, Emcy, ds402, emcy_name
from viena.services.steering.driver.emcy import FOLLOWING_ERROR, LIFE_GUARD_ERROR
from viena.services.steering.model.calibration import SweepRecorder
from viena.services.steering.simulator import PersonAtTheWheel, TwinSettings

SHARED = Path(__file__).resolve().parents[3] / "shared/data/steering"


# -- the EDS ------------------------------------------------------------------------------
def test_the_shipped_eds_loads_and_the_original_does_not():
    od = canopen.import_od(str(EDS_PATH), 1)
    assert od[0x2062].name == "PositionMode Setting Value" and od[0x2062].pdo_mappable
    assert od[0x201B].data_type == canopen.objectdictionary.DOMAIN
    original = SHARED / "maxon-70_10.eds"
    if not original.exists():
        pytest.skip("shared/data/steering not present")
    with pytest.raises(Exception, match="DataType"):
        canopen.import_od(str(original), 1)
    shipped = EDS_PATH.read_text().splitlines()
    header = next(i for i, line in enumerate(shipped) if not line.startswith(";"))
    assert "201B" in "".join(shipped[:header])         # the change is explained at the top
    diff = [d for d in difflib.ndiff(original.read_text().splitlines(), shipped[header:])
            if d[:1] in "+-"]
    assert diff == ["+ DataType=0x000F", "+ AccessType=ro"]


def test_emcy_codes_have_the_firmware_names():
    assert emcy_name(0x8611) == "Following Error"
    assert emcy_name(0x8130) == "CAN Life Guard Error"
    assert emcy_name(0xFF09) == "Software Position Limit Error"
    assert "Temperature" in emcy_name(0x4299)
    e = Emcy.decode(bytes.fromhex("1186200000000000"))
    assert (e.code, e.register, str(e)) == (0x8611, 0x20, "EMCY 0x8611 Following Error")
    assert Emcy.decode(e.encode()) == e and Emcy.decode(b"\0\0\0").is_reset


# -- configuration ------------------------------------------------------------------------
def test_configure_writes_the_safety_configuration_to_the_drive(configured):
    twin, drive = configured.twin, configured.drive
    assert (drive.read(0x2210, 1), drive.read(0x2210, 2), drive.read(0x2210, 4)) == (3600, 2, 0)
    assert drive.read(0x6065) == 7500
    assert drive.read(0x6060) == -1 and drive.feedback().op_mode == -1
    assert drive.read(0x1017) == 100
    assert drive.read(0x1016, 1) == (100 << 16) | 250
    assert twin.node.nmt.state == "OPERATIONAL"
    fb = drive.feedback()
    assert fb.state == ds402.SWITCH_ON_DISABLED and fb.statusword & ds402.SW_REMOTE
    assert fb.position_qc == 0                    # no index: the counter starts at power-up


def test_setpoints_travel_by_rpdo_and_feedback_by_tpdo_on_sync(configured):
    """After configuration no SDO is needed: the twin's SDO server sees no more requests."""
    rig = configured
    requests = []
    rig.net.subscribe(0x600 + 1, lambda *a: requests.append(a))
    rig.enable()
    start = rig.drive.feedback().position_qc
    for k in range(1, 51):                        # 0.5 s ramp of 5000 qc
        rig.drive.cycle(start + 100 * k)
        rig.run(0.01)
    rig.run(0.3)
    fb = rig.drive.feedback()
    assert abs(fb.position_qc - (start + 5000)) < 200 and fb.demand_qc == start + 5000
    assert requests == []


def test_the_software_position_limits_clip_the_demand_and_fault_an_overshoot(configured):
    """Position Mode clips the setting value to 0x607D; an actual position beyond a limit is
    a Software Position Limit Error (firmware 2030h applies the limits to both)."""
    rig = configured
    rig.drive.set_position_limits((-3000, 3000))
    assert rig.drive.read(0x607D, 1) == -3000          # negative limits written signed
    rig.enable()
    demands = []
    for k in range(1, 41):
        rig.drive.cycle(150 * k)                       # a ramp toward 6000
        rig.run(0.01)
        demands.append(rig.drive.feedback().demand_qc)
    rig.run(0.5)
    assert max(demands) == 3000
    assert rig.drive.feedback().state == ds402.FAULT
    assert [e.code for e in rig.drive.emcy_log] == [0xFF09]


# -- DS402 --------------------------------------------------------------------------------
def test_the_state_machine_follows_the_controlword(configured):
    rig, d = configured, configured.drive
    d.command(ds402.CW_ENABLE_OPERATION)               # not from switch on disabled
    rig.run(0.01)
    assert d.feedback().state == ds402.SWITCH_ON_DISABLED
    rig.enable()
    d.command(ds402.CW_QUICK_STOP)
    rig.run(0.01)
    assert d.feedback().state == ds402.QUICK_STOP_ACTIVE
    d.command(ds402.CW_ENABLE_OPERATION)               # transition 16
    rig.run(0.01)
    assert d.feedback().state == ds402.OPERATION_ENABLED
    d.command(ds402.CW_SWITCH_ON)                      # disable operation
    rig.run(0.01)
    assert d.feedback().state == ds402.SWITCHED_ON
    d.command(ds402.CW_DISABLE_VOLTAGE)
    rig.run(0.01)
    assert d.feedback().state == ds402.SWITCH_ON_DISABLED


def test_fault_reset_needs_a_real_rising_edge_of_bit_7(configured):
    rig, d, twin = configured, configured.drive, configured.twin
    d.command(ds402.CW_FAULT_RESET)                    # bit 7 already high before the fault
    rig.run(0.01)
    twin.inject_error(0x4210)
    rig.run(0.02)
    assert d.feedback().state == ds402.FAULT
    for _ in range(3):                                 # bit 7 held high: no edge, no reset
        d.command(ds402.CW_FAULT_RESET)
        rig.run(0.01)
    assert d.feedback().state == ds402.FAULT
    d.command(ds402.CW_DISABLE_VOLTAGE)
    rig.run(0.01)
    d.command(ds402.CW_FAULT_RESET)
    rig.run(0.01)
    assert d.feedback().state == ds402.SWITCH_ON_DISABLED
    assert [e.code for e in d.emcy_log] == [0x4210, 0x0000]


def test_a_following_error_faults_the_drive_with_its_emcy(configured):
    rig, d = configured, configured.drive
    rig.enable()
    d.cycle(d.feedback().position_qc + 20_000)         # a step far beyond 0x6065 = 7500 qc
    rig.run(0.2)
    fb = d.feedback()
    assert fb.state == ds402.FAULT
    assert [str(e) for e in d.emcy_log] == ["EMCY 0x8611 Following Error"]
    assert rig.twin.statusword & ds402.SW_FOLLOWING_ERROR
    assert d.read(0x1001) & 0x20                       # error register: device profile specific


def test_the_drive_faults_by_itself_when_the_hosts_heartbeat_stops(configured):
    rig, twin = configured, configured.twin
    rig.enable()
    rig.run(0.2, heartbeat=False)                      # 200 ms of silence: within 250 ms
    assert twin.state == ds402.OPERATION_ENABLED
    rig.run(0.1, heartbeat=False)
    assert twin.state in (ds402.FAULT_REACTION, ds402.FAULT) and twin.errors == [LIFE_GUARD_ERROR]
    rig.run(0.05)                                       # the host is back: the EMCY reached it
    assert rig.drive.emcy_log[-1].code == LIFE_GUARD_ERROR and rig.drive.feedback().state == ds402.FAULT
    for cw in (ds402.CW_DISABLE_VOLTAGE, ds402.CW_FAULT_RESET):   # heartbeats again: resettable
        rig.drive.command(cw)
        rig.run(0.01)
    assert rig.drive.feedback().state == ds402.SWITCH_ON_DISABLED


def test_the_heartbeat_fault_persists_while_the_host_stays_silent(configured):
    rig, twin = configured, configured.twin
    rig.run(0.3, heartbeat=False)
    assert twin.state == ds402.FAULT
    twin.controlword = 0
    twin._on_controlword(ds402.CW_FAULT_RESET)        # a reset with the host still silent
    assert twin.state == ds402.FAULT


def test_a_power_cycle_announces_itself_and_restarts_the_counter(configured):
    d, twin = configured.drive, configured.twin
    booted = []
    d.add_bootup_listener(lambda: booted.append(True))
    twin.plant.x = 12_345.0
    twin.power_cycle()
    assert d.wait_feedback(lambda fb: True, 0.1)
    wait_until(lambda: booted, 1.0)
    assert booted and twin.position_qc == 0 and twin.true_zero_qc == -12_345


def test_an_index_encoder_setting_is_caught_when_enabling(make_rig):
    rig = make_rig(sensor_type=1)                     # the car's index track is damaged
    rig.drive.configure()
    rig.run(0.02)
    hold = rig.drive.feedback().position_qc
    rig.drive.send_target(hold, ds402.CW_SHUTDOWN)
    rig.run(0.01)
    rig.drive.command(ds402.CW_ENABLE_OPERATION)
    rig.run(0.05)
    assert rig.drive.feedback().state == ds402.FAULT
    assert rig.drive.emcy_log[-1].name == "Index Processing Error"


# -- the person and the plant --------------------------------------------------------------
def test_the_twin_sweeps_lock_to_lock_after_power_up_and_the_sweep_is_accepted(make_rig):
    rig = make_rig(TwinSettings(sweep=True, sweep_speed_qc_s=150_000, sweep_delay_s=0.1, power_up_qc=2_000))
    rig.drive.configure()
    rec = SweepRecorder()
    for _ in range(500):
        rig.run(0.01)
        rec.add(rig.drive.feedback().position_qc, rig.clock.t)
        if rec.done(rig.clock.t):
            break
    cal = rec.result()
    assert 95_000 <= cal.span_qc <= 96_500
    assert abs(cal.zero_qc - rig.twin.true_zero_qc) <= 600
    for _ in range(300):                       # the person holds the centre a moment, then lets go
        if not rig.twin.sweeping:
            break
        rig.run(0.01)
    assert not rig.twin.sweeping and FOLLOWING_ERROR not in rig.twin.errors


def test_a_sweep_cut_short_is_swept_again_by_the_person_at_the_wheel(make_rig):
    """A host that missed the first half of the sweep (a stall: the service restarted it
    as a glitch) sees half a span, keeps calibrating, and the person sweeps again."""
    rig = make_rig(TwinSettings(sweep=True, sweep_speed_qc_s=150_000, sweep_delay_s=0.1))
    rig.drive.configure()
    person = PersonAtTheWheel([rig.twin], clock=rig.clock)
    rec, seen_left_stop, asked, cal = SweepRecorder(), False, 0, None
    for _ in range(2000):
        rig.run(0.01)
        qc = rig.drive.feedback().position_qc
        seen_left_stop = seen_left_stop or qc < -40_000
        if seen_left_stop:
            rec.add(qc, rig.clock.t)
        if rec.done(rig.clock.t):
            cal = rec.result()
            break
        asked += person.read({"phase": "calibrating", "armed": False})
    assert asked == 1 and cal is not None and 95_000 <= cal.span_qc <= 96_500
    assert not person.read({"phase": "ready", "armed": False})


@pytest.mark.slow  # fits the plant to the recordings
def test_the_plant_constants_reproduce_the_cars_recordings():
    pytest.importorskip("scipy")
    from viena.services.steering.simulator.fit import load_recording, rms_error
    from viena.services.steering.simulator.plant import CHIRP005, TRAJ01
    if not SHARED.is_dir():
        pytest.skip("shared/data/steering not present")
    traj = load_recording(SHARED / "traj01.mat")
    assert rms_error(traj, TRAJ01) < 0.04 * traj.meas_qc.std()      # 250 qc of a 25 000 qc move
    chirp = load_recording(SHARED / "chirp005.mat")
    assert rms_error(chirp, CHIRP005) < 0.95 * chirp.meas_qc.std()  # better than standing still
    assert rms_error(chirp, TRAJ01) > rms_error(chirp, CHIRP005)    # the soft loop is different
