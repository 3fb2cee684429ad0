"""GNSS fixes made from a real drive's reference trajectory, at standalone grade.

A public GNSS/INS drive carries a centimetre reference (RTK, or a post-processed
navigation-grade INS) and a raw MEMS IMU. What the car's receivers give is metres, so the
bench degrades the reference the way a single-point receiver errs, and knows exactly what
it added:

- "wandering": white noise (1.5 m per horizontal axis, 2.5 m up) plus a slowly wandering
  error of about 1 m per axis (a first-order Gauss-Markov process, 300 s: orbits, clocks and
  the atmosphere), and the honest sigma of the sum in every fix;
- "white": the white part only, honest too (what a filter can remove all of);
- velocity (Doppler) with 0.1 m/s white noise, or none (a position-only receiver: NMEA GGA
  without RMC/VTG, a NovAtel without BESTVEL).

The wandering part is returned with the fixes: no filter sees it without another
reference, so "the error beyond the receiver's own wandering error" is what a filter can
be asked to remove.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pymap3d

WHITE_SIGMA_M = (1.5, 1.5, 2.5)
WANDER_SIGMA_M = (1.0, 1.0, 1.5)
WANDER_TAU_S = 300.0
VEL_SIGMA_MPS = 0.1


@dataclass(frozen=True)
class GnssCase:
    """How the fixes are made: rate, errors, velocity, and time windows without fixes."""
    rate_hz: float = 4.0
    errors: str = "wandering"           # "wandering" or "white"
    velocity: bool = True
    outages: tuple = ()                 # (start_s, end_s) in the drive's seconds
    seed: int = 1


@dataclass
class Fixes:
    t_s: np.ndarray                     # drive seconds of each fix
    samples: list                       # viena.gnss.fix/1 dicts, in time order
    wander_enu_m: np.ndarray            # the wandering error each fix carries (zeros when white)
    error_enu_m: np.ndarray             # each fix's whole error


def make_fixes(drive, case: GnssCase, unit: str = "gnss0") -> Fixes:
    """Fixes of `drive` (a RealDrive) as `case` says, at the reference's point; with
    errors "receiver", the drive's own receiver's fixes (its real errors, not known apart)."""
    if case.errors == "receiver":
        return receiver_fixes(drive, case, unit)
    rng = np.random.default_rng(case.seed)
    step = 1.0 / case.rate_hz
    t0, t1 = drive.t_ref_s[0], drive.t_ref_s[-1]
    t = np.arange(math.ceil(t0 / step) * step, t1, step)
    for a, b in case.outages:
        t = t[(t < a) | (t >= b)]
    ref = np.column_stack([np.interp(t, drive.t_ref_s, drive.ref_enu_m[:, k]) for k in range(3)])
    vel = np.column_stack([np.interp(t, drive.t_ref_s, drive.ref_vel_enu_mps[:, k]) for k in range(3)])
    white = rng.standard_normal((len(t), 3)) * WHITE_SIGMA_M
    wander = np.zeros((len(t), 3))
    if case.errors == "wandering":
        z = rng.standard_normal(3)
        dt = np.diff(t, prepend=t[0])
        for i, d in enumerate(dt):
            a = math.exp(-d / WANDER_TAU_S)
            z = a * z + math.sqrt(1.0 - a * a) * rng.standard_normal(3)
            wander[i] = z
        wander *= WANDER_SIGMA_M
        sigma = np.hypot(WHITE_SIGMA_M, WANDER_SIGMA_M)
    elif case.errors == "white":
        sigma = np.array(WHITE_SIGMA_M, float)
    else:
        raise ValueError(f"errors: 'wandering' or 'white', not {case.errors!r}")
    error = white + wander
    enu = ref + error
    lat0, lon0, h0 = drive.origin
    x, y, zz = pymap3d.enu2ecef(enu[:, 0], enu[:, 1], enu[:, 2], lat0, lon0, h0)
    vel_noisy = vel + rng.standard_normal((len(t), 3)) * VEL_SIGMA_MPS
    ve, vn, vu = vel_noisy.T
    vx, vy, vz = pymap3d.enu2uvw(ve, vn, vu, lat0, lon0)
    samples = []
    for i, ti in enumerate(t):
        fix = {"t": drive.t_ns(ti), "unit": unit, "valid": True, "pos_status": "SOL_COMPUTED",
               "ecef_m": [float(x[i]), float(y[i]), float(zz[i])],
               "enu_sigma_m": [float(v) for v in sigma]}
        if case.velocity:
            fix.update(vel_status="SOL_COMPUTED", vel_type="DOPPLER_VELOCITY",
                       vel_ecef_mps=[float(vx[i]), float(vy[i]), float(vz[i])],
                       vel_sigma_mps=[VEL_SIGMA_MPS] * 3, vel_latency_s=0.0)
        samples.append(fix)
    return Fixes(t, samples, wander, error)


def receiver_fixes(drive, case: GnssCase, unit: str = "gnss0") -> Fixes:
    """The drive's own receiver, at most `case.rate_hz`, with the sigmas the drive's source
    names (its receiver's figures); velocity only where it gave one and `case.velocity`."""
    if drive.gnss_t_s is None:
        raise ValueError(f"{drive.name}: no receiver of its own in the data")
    t_all = np.asarray(drive.gnss_t_s, float)
    keep, last = [], -np.inf
    for i, ti in enumerate(t_all):                  # at most rate_hz, as the estimator's own decimation
        if ti - last >= 1.0 / case.rate_hz - 1e-3 and not any(a <= ti < b for a, b in case.outages):
            keep.append(i)
            last = ti
    t = t_all[keep]
    enu = np.asarray(drive.gnss_enu_m, float)[keep]
    ref = np.column_stack([np.interp(t, drive.t_ref_s, drive.ref_enu_m[:, k]) for k in range(3)])
    lat0, lon0, h0 = drive.origin
    x, y, z = pymap3d.enu2ecef(enu[:, 0], enu[:, 1], enu[:, 2], lat0, lon0, h0)
    has_vel = case.velocity and drive.gnss_vel_enu_mps is not None
    if has_vel:
        vel = np.asarray(drive.gnss_vel_enu_mps, float)[keep]
        vx, vy, vz = pymap3d.enu2uvw(vel[:, 0], vel[:, 1], vel[:, 2], lat0, lon0)
    samples = []
    for i, ti in enumerate(t):
        fix = {"t": drive.t_ns(float(ti)), "unit": unit, "valid": True, "pos_status": "SOL_COMPUTED",
               "ecef_m": [float(x[i]), float(y[i]), float(z[i])],
               "enu_sigma_m": [float(v) for v in drive.gnss_sigma_m]}
        if has_vel:
            fix.update(vel_status="SOL_COMPUTED", vel_type="DOPPLER_VELOCITY",
                       vel_ecef_mps=[float(vx[i]), float(vy[i]), float(vz[i])],
                       vel_sigma_mps=[0.2, 0.2, 0.2], vel_latency_s=0.0)
        samples.append(fix)
    return Fixes(t, samples, np.zeros((len(t), 3)), enu - ref)
