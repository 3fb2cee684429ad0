"""`viena up --rtk`: the whole corrections chain as processes, on real TCP and real zenoh.

The caster's twin serves RTCM 3 from a base station beside the loop, viena-ntrip brings it
onto gnss/corrections, each GNSS service writes it to its receiver twin's COM2, the
receivers move to a fixed RTK solution, and the estimator rests on it. What each part does
with bad input is tested part by part (tests/ntrip, tests/gnss/test_gnss_corrections_*,
tests/gnss/test_novatel_twin_rtk*); this is the wiring, as a person runs it.
"""
from __future__ import annotations

import stat

import pytest
from vienatest import collect_until, open_session, sim_profile_up, viena

from viena.common.samples.fix import solution_kind
from viena.common.schema import unpack

pytestmark = [pytest.mark.slow, pytest.mark.car(seconds=60)]

UNITS = {"gnss0", "gnss1"}


def fixed_units(fixes: list[dict]) -> set[str]:
    return {f["unit"] for f in fixes if f.get("valid") and solution_kind(f.get("pos_type")) == "fixed"}


def test_up_rtk_brings_both_receivers_to_a_fixed_solution_the_estimator_rests_on(tmp_path):
    run = tmp_path / "run"
    # a base 100 m away: the twin fixes in about 20 s (a kilometre: about 30 s)
    with sim_profile_up(run, flags=("--rtk",), VIENA_RTK_BASELINE_M="100") as (env, router), \
            open_session(router) as car:
        states = collect_until(car, "viena/elettra/ntrip/state",
                               lambda got: bool(got) and got[-1].get("connected") is True, timeout=40, decode=unpack)
        assert states and states[-1]["connected"], states[-1:]
        fixes = collect_until(car, "viena/elettra/gnss/*/fix", lambda got: fixed_units(got) >= UNITS,
                              timeout=120, decode=unpack)
        assert fixed_units(fixes) >= UNITS, {f["unit"]: f["pos_type"] for f in fixes[-4:]}
        last = {f["unit"]: f for f in fixes}
        for unit in UNITS:
            assert last[unit]["base_id"] and 0 <= last[unit]["diff_age_s"] < 5.0, last[unit]
        estimates = collect_until(car, "viena/elettra/estimator/state",
                                  lambda got: bool(got) and got[-1].get("gnss_kind") == "fixed", timeout=20,
                                  decode=unpack)
        assert estimates and estimates[-1]["gnss_kind"] == "fixed", estimates[-1:]
        # the login the caster's twin made is its owner's alone, and no log holds the password
        credentials = run / "ntrip.credentials"
        assert stat.S_IMODE(credentials.stat().st_mode) & 0o077 == 0
        password = credentials.read_text().strip().split(":", 1)[1]
        for log in run.glob("*.log"):
            assert password not in log.read_text(errors="replace"), log.name
        # `viena doctor` finds the caster and the mountpoint of the running profile
        doctor = viena("doctor", "--profile", "sim", env=env, timeout=60)
        assert "ntrip mountpoint VIENA0: listed" in doctor.stdout, doctor.stdout

