"""End to end: the simulated car serves two NovAtel twins at different lever arms (as on
the real car), two `viena-gnss` processes publish their fixes, and every fix lies within
its noise of where the truth puts that antenna."""
from __future__ import annotations

import bisect

import numpy as np
import pymap3d
import pytest
from vienatest import collect, free_port

from viena.common.rotation import quat_to_matrix
from viena.common.samples.fix import FIX
from viena.common.samples.truth import TRUTH

pytestmark = pytest.mark.slow  # the sim and two services as processes

LEVER_ARMS = {"gnss0": (-0.5, 1.0, 1.5), "gnss1": (0.5, 1.0, 1.5)}


@pytest.mark.timeout(90)
def test_sim_twins_to_fixes_within_noise_of_truth(procs, router, session, tmp_path):
    ports = {unit: free_port() for unit in LEVER_ARMS}
    tables = "".join(
        f"[sim.{unit}]\nkind = 'novatel'\nport = {ports[unit]}\n"
        f"lever_arm_m = {list(arm)}\noutage_interval_s = 0.0\n"
        for unit, arm in LEVER_ARMS.items())
    config = tmp_path / "sim.toml"
    config.write_text(f"car = 'gnsse2e'\n[sim]\nparked_s = 1.0\ndevices = {list(LEVER_ARMS)}\n{tables}")
    procs.python("-m", "viena.services.sim.service", "--connect", router, "--config", config)
    for unit in LEVER_ARMS:
        procs.python("-m", "viena.services.gnss.service", "--connect", router, "--car", "gnsse2e",
                     "--unit", unit, "--port", f"socket://127.0.0.1:{ports[unit]}")
    truth = collect(session, "viena/gnsse2e/sim/truth", 1, timeout=20)   # the car is up
    assert truth
    truths: list[dict] = []
    sub = session.declare_subscriber("viena/gnsse2e/sim/truth",
                                     lambda s: truths.append(TRUTH.decode(s.payload.to_bytes())))
    try:
        got = {unit: collect(session, f"viena/gnsse2e/gnss/{unit}/fix", 40, timeout=20,
                             decode=FIX.decode) for unit in LEVER_ARMS}
    finally:
        sub.undeclare()
    times = [t["t"] for t in truths]
    checked = 0
    for unit, fixes in got.items():
        assert len(fixes) == 40
        for fix in fixes:
            assert fix["valid"] and fix["unit"] == unit
            i = bisect.bisect_left(times, fix["t"])
            if i == 0 or i >= len(times):
                continue
            t = truths[i]
            dt = (fix["t"] - t["t"]) / 1e9
            rot = quat_to_matrix(t["quat"])
            antenna = (np.array(t["enu_m"]) + rot @ np.array(LEVER_ARMS[unit])
                       + np.array(t["vel_enu_mps"]) * dt)
            enu = np.array(pymap3d.ecef2enu(*fix["ecef_m"], *t["origin"]))
            error = np.linalg.norm(enu - antenna)
            assert error < 4 * np.linalg.norm(fix["ecef_sigma_m"]), (unit, error)
            checked += 1
    assert checked > 50                           # all but those before the first truth
