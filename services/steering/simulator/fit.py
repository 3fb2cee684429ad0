"""Fit the twin's steering plant to the car's recorded EPOS tests (needs scipy).

    python -m viena.services.steering.simulator.fit [DATA_DIR]

Each recording (shared/data/steering/*.mat, written by the old Matlab tools) holds the
position setpoints sent to the drive and the positions read back, both in qc with their
host times. The fit replays the setpoints through `PositionPlant` and minimises the RMS
distance to what the drive reported. The printed constants are the ones in plant.py.
"""
from __future__ import annotations

import sys
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from viena.services.steering.simulator.plant import DT_S, PlantParams, PositionPlant


@dataclass
class Recording:
    name: str
    t_cmd: np.ndarray          # s, when each setpoint was written
    cmd_qc: np.ndarray
    t_meas: np.ndarray         # s, when each position was read
    meas_qc: np.ndarray
    gains: dict


def load_recording(path: str | Path) -> Recording:
    """chirp005.mat (tin/inVar, tout/outVar) or traj01.mat (tx/x, ty/y)."""
    from scipy.io import loadmat

    with warnings.catch_warnings():          # the files carry a duplicated opaque 'None'
        warnings.simplefilter("ignore")
        m = loadmat(str(path), squeeze_me=True, struct_as_record=False)
    config = m.get("config")
    gains = {k: int(getattr(config, k)) for k in getattr(config, "_fieldnames", [])}
    if "tx" in m:
        t_cmd, cmd, t_meas, meas = m["tx"], m["x"], m["ty"], m["y"]
    else:
        cmd, meas = m["inVar"], m["outVar"]
        t_cmd, t_meas = m["tin"][:len(cmd)], m["tout"][:len(meas)]
    return Recording(Path(path).stem, np.asarray(t_cmd, float), np.asarray(cmd, float),
                     np.asarray(t_meas, float), np.asarray(meas, float), gains)


def replay(rec: Recording, params: PlantParams) -> np.ndarray:
    """The plant's position at each measurement time, for the recorded setpoints."""
    plant = PositionPlant(params, rec.meas_qc[0])
    out = np.empty_like(rec.meas_qc)
    t, i_cmd, setpoint = 0.0, -1, rec.cmd_qc[0]
    for k, t_q in enumerate(rec.t_meas):
        while t < t_q:
            while i_cmd + 1 < len(rec.t_cmd) and rec.t_cmd[i_cmd + 1] <= t:
                i_cmd += 1
                setpoint = rec.cmd_qc[i_cmd]
            plant.step(setpoint, DT_S)
            t += DT_S
        out[k] = plant.x
    return out


def rms_error(rec: Recording, params: PlantParams) -> float:
    return float(np.sqrt(np.mean((replay(rec, params) - rec.meas_qc) ** 2)))


def fit(rec: Recording, start: PlantParams, max_iter: int = 300) -> tuple[PlantParams, float]:
    """Nelder-Mead on log-parameters (all must stay positive)."""
    from scipy.optimize import minimize

    def params(z):
        wn, zeta, kd, fs, fc, delay = np.exp(z)
        return PlantParams(float(wn), float(zeta), float(kd), float(fs), float(fc), float(delay))

    z0 = np.log([start.wn, start.zeta, start.kd, max(start.fs, 1.0), max(start.fc, 1.0),
                 max(start.delay_s, DT_S)])
    res = minimize(lambda z: rms_error(rec, params(z)), z0, method="Nelder-Mead",
                   options={"maxiter": max_iter, "xatol": 1e-3, "fatol": 0.5})
    return params(res.x), float(res.fun)


def main(argv=None) -> int:
    from viena.services.steering.simulator.plant import CHIRP005, TRAJ01

    argv = sys.argv[1:] if argv is None else argv
    data = Path(argv[0]) if argv else Path(__file__).resolve().parents[4] / "shared/data/steering"
    for name, start in (("traj01.mat", TRAJ01), ("chirp005.mat", CHIRP005)):
        rec = load_recording(data / name)
        before = rms_error(rec, start)
        fitted, after = fit(rec, start)
        print(f"{name}: gains {rec.gains}; measured std {rec.meas_qc.std():.0f} qc; "
              f"shipped constants RMS {before:.0f} qc; refit RMS {after:.0f} qc")
        print(f"  {fitted}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

