"""A recorded drive replayed through a fresh estimator reproduces the estimator's live
output exactly: in virtual time the replay puts every sample on the bus at the very
instant it reached the recorder live, so the estimator meets the same inputs at the same
times and must give the same states. (In real time, a GNSS fix landed beside another IMU
sample as the replay's pace grew: 3-4 cm p95 at 2x; that bound was the machine's, not the
estimator's.)"""
from __future__ import annotations

from viena.common import clock
from viena.common.recording import KeyFilter, Recording, RecordingWriter
from viena.common.samples.estimator import STATE
from viena.lockstep_car import LockstepCar
from viena.record import Recorder
from viena.replay import Player

SENSORS = ["viena/elettra/imu/**", "viena/elettra/gnss/*/fix"]
STATE_KEY = "viena/elettra/estimator/state"


def driven_s(states: list[dict]) -> float:
    moving = [s["t"] for s in states if s["position_valid"] and s["speed_mps"] > 1]
    return (moving[-1] - moving[0]) / 1e9 if moving else 0.0


def record(car: LockstepCar, path, keyexprs: list[str]) -> Recorder:
    recorder = Recorder(car.session("recorder"), keyexprs, RecordingWriter(path))
    recorder.start()
    return recorder


def states_in(path) -> dict[int, bytes]:
    return {m.publish_time: m.data for m in Recording(path).messages(KeyFilter([STATE_KEY]))}


def test_a_replayed_drive_through_a_fresh_estimator_gives_the_same_states(tmp_path):
    drive, replayed = tmp_path / "drive.mcap", tmp_path / "replayed.mcap"
    with LockstepCar(seed=4, programs=["sim", "gnss0", "gnss1", "razor0", "estimator"]) as car:
        recorder = record(car, drive, ["viena/elettra/**"])
        live = car.collect(STATE_KEY, STATE.decode)
        assert car.run_until(lambda: driven_s(live) >= 16.0, within_s=60)   # 10 s parked first
        assert recorder.stop() == drive

    sensors = list(Recording(drive).messages(KeyFilter(SENSORS)))
    with LockstepCar(seed=4, programs=["estimator"]) as car:
        recorder = record(car, replayed, [STATE_KEY])
        car.run_to(sensors[0].log_time)                      # the replay starts where the drive did
        player = Player(car.session("replay"), rate=1.0)
        player.play(sensors, clock.Event())
        car.run_for(0.5)                                     # the last state is out
        assert recorder.stop() == replayed
    # never late on the virtual clock: at most the float rounding of `due` (1e-13 s)
    assert player.stats.samples == len(sensors) and max(player.stats.lateness_s) < 1e-9

    recorded, again = states_in(drive), states_in(replayed)
    assert len(recorded) > 1500
    assert again == recorded                                 # byte for byte, every state
