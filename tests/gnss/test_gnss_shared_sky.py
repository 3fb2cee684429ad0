"""Two antennas, one sky (issue 12): the GNSS twins on one car draw the satellite clock,
orbit and atmosphere errors (the error budget's first four rows, docs/sensors.md#two-antennas-one-sky) from one source, and only
multipath and receiver noise apart (standalone receivers: also their satellite selection), so two receivers' errors are
mostly the same error."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pymap3d
import pytest
from gnss_helpers import TwinHarness, still

from viena.services.gnss.driver.novatel import Log, MessageId, Trigger
from viena.services.gnss.simulator import NovatelTwin, make_novatel_device
from viena.services.gnss.simulator.errors import (
    CEP_PER_SIGMA,
    SEED_TABLE_5_2,
    CommonErrors,
    GnssErrorModel,
)
from viena.services.sim.model.car import SimCar
from viena.services.sim.model.truth import IST_ORIGIN

GPS_MS = 2_300_000_000_000             # some instant, on the 50 ms grid


def own_sigma_per_axis(cep_m: float = 1.8) -> float:
    """The horizontal sigma per axis of a receiver's own sources (multipath, noise)."""
    w = np.array([s.up_to_m for s in SEED_TABLE_5_2])
    own = np.array([not s.common for s in SEED_TABLE_5_2])
    return cep_m / CEP_PER_SIGMA * np.linalg.norm(w[own]) / np.linalg.norm(w)


def pair_errors(shared: bool, seeds=range(400), t_s: float = 0.0, profile: str = "gauss_markov"):
    """East errors of two receivers on one car at the same instant, over many skies."""
    a, b = [], []
    for seed in seeds:
        rng = np.random.default_rng(seed)
        sky = CommonErrors(np.random.default_rng([seed, 1])) if shared else None
        first = GnssErrorModel(rng, common=sky, profile=profile)
        second = GnssErrorModel(np.random.default_rng([seed, 2]), common=sky, profile=profile)
        a.append(first.step(t_s, GPS_MS)[0][0])
        b.append(second.step(t_s, GPS_MS)[0][0])
    return np.array(a), np.array(b)


def test_one_sky_makes_two_receivers_errors_nearly_the_same():
    a, b = pair_errors(shared=True)
    assert np.corrcoef(a, b)[0, 1] > 0.95
    # what differs is each antenna's multipath and noise: sqrt(2) x their sigma
    assert np.std(a - b) == pytest.approx(np.sqrt(2) * own_sigma_per_axis(), rel=0.15)
    # and each receiver alone is still the OEM4's 1.8 m CEP
    assert np.std(a) * CEP_PER_SIGMA == pytest.approx(1.8, rel=0.12)


def test_standalone_receivers_under_one_sky_share_most_of_their_error():
    """Each standalone receiver also has its own satellite selection (its steps), multipath
    bursts and Student-t noise (test_gnss_twin_errors.py): two of them a metre apart differ
    by about a metre per axis, still far less than two under skies of their own."""
    a, b = pair_errors(shared=True, seeds=range(1000), profile="standalone")
    assert 0.7 < np.corrcoef(a, b)[0, 1] < 0.95
    apart = pair_errors(shared=False, seeds=range(1000), profile="standalone")
    assert 0.7 < np.std(a - b) < 1.3 and np.std(a - b) < 0.6 * np.std(apart[0] - apart[1])


@pytest.mark.parametrize("profile, seeds", [("gauss_markov", range(400)), ("standalone", range(2000))])
def test_own_skies_are_independent(profile, seeds):
    a, b = pair_errors(shared=False, seeds=seeds, profile=profile)
    assert abs(np.corrcoef(a, b)[0, 1]) < (0.15 if len(seeds) < 1000 else 0.07)


def test_the_shared_part_is_the_same_for_the_same_instant_whoever_asks_first():
    sky = CommonErrors(np.random.default_rng(3))
    ahead = [sky.at(GPS_MS + 50 * k) for k in range(40)]
    behind = [sky.at(GPS_MS + 50 * k) for k in range(40)]       # a receiver lagging behind
    assert all((x == y).all() for x, y in zip(ahead, behind))
    assert not (ahead[0] == ahead[-1]).all()                        # and it moves on
    later = sky.at(GPS_MS + 3_600_000)                              # after a long pause
    assert later.shape == (4, 3) and (sky.at(GPS_MS + 3_600_000) == later).all()


def test_a_receiver_with_sbas_scales_the_shared_part_by_its_own_size():
    sky = CommonErrors(np.random.default_rng(5))
    plain = GnssErrorModel(np.random.default_rng(1), common=sky, profile="gauss_markov")
    sbas = GnssErrorModel(np.random.default_rng(2), common=sky, cep_m=0.9, profile="gauss_markov")
    e1, e2 = plain.step(0.0, GPS_MS)[0], sbas.step(0.0, GPS_MS)[0]
    assert np.linalg.norm(e2) < np.linalg.norm(e1)
    assert np.corrcoef(e1, e2)[0, 1] > 0.8


def test_two_novatel_twins_on_one_car_see_the_same_sky():
    """Through the twins' own logs (standalone errors): the fixes of two antennas 1 m apart
    differ by the lever arm plus about a metre at most, not by metres."""
    def fixes(shared: bool, seed: int):
        sky = CommonErrors(np.random.default_rng([seed, 9])) if shared else None
        out = []
        for k, arm in enumerate(((-0.5, 1.0, 1.5), (0.5, 1.0, 1.5))):
            h = TwinHarness(NovatelTwin(still(), arm, seed=seed * 10 + k, outage_interval_s=0.0,
                                        common_errors=sky))
            h.command(Log(message=MessageId.BESTXYZ, trigger=Trigger.ONTIME, period=1.0))
            h.run(3.0)
            out.append(np.array([m.data.position_m for m in h.logs]))
        return out
    medians = {}
    for shared in (True, False):
        spreads = []
        for seed in range(12):
            a, b = fixes(shared, seed)
            enu = np.array([pymap3d.ecef2enu(*(b[i] - a[i] + _origin()), *IST_ORIGIN)
                            for i in range(min(len(a), len(b)))])
            spreads.append(np.hypot(enu[:, 0] - 1.0, enu[:, 1]).mean())   # minus the arm (east)
        medians[shared] = np.median(spreads)
        if shared:
            assert max(spreads) < 2.0
    assert medians[True] < 1.0 and medians[False] > 1.5


def _origin() -> np.ndarray:
    return np.array(pymap3d.geodetic2ecef(*IST_ORIGIN))


def test_the_sims_receivers_share_the_cars_sky_unless_told_not_to():
    car = SimCar()
    service = SimpleNamespace(settings=SimpleNamespace(seed=2, host="127.0.0.1"),
                              args=SimpleNamespace(config="sim.toml"))
    devices = [make_novatel_device(name, table, car, service) for name, table in (
        ("gnss0", {"lever_arm_m": [-0.5, 1.0, 1.5]}), ("gnss1", {"lever_arm_m": [0.5, 1.0, 1.5]}),
        ("gnss2", {"shared_sky": False}))]
    try:
        skies = [d.twin.solver.errors.common for d in devices]
    finally:
        for d in devices:
            d.stop()
    assert skies[0] is not None and skies[0] is skies[1] and skies[2] is None
