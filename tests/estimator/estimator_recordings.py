"""The car's real recordings (shipped in data/) as samples in the agreed schemas.

Only what the estimator's tests need: the 2016 NovAtel BESTXYZ drive as viena.gnss.fix/1
dicts and the 2017 parked Razor recordings as viena.imu.sample/1 dicts.
"""
from __future__ import annotations

import csv
import math
from datetime import UTC, datetime
from pathlib import Path

DATA = Path(__file__).resolve().parents[2] / "data"          # the copies the product ships
GNSS_DRIVE = DATA / "novatel_bestxyz_drive_2016-06-01.csv"
IMU_PARKED = sorted((DATA / "imu").glob("razor_parked_*.csv"))
G = 9.80665
#: the Razor firmware's loop rate; the CSV's host times come in USB bursts
RAZOR_RATE_HZ = 82.5
#: BESTXYZ solution status (NovAtel OEM4 vol. 2, table 48; docs/sensors.md#logs-used): the
#: ones in the recording
SOL_STATUS = {0: "SOL_COMPUTED", 1: "INSUFFICIENT_OBS", 2: "NO_CONVERGENCE"}


def _utc_ns(text: str) -> int:
    stamp = datetime.strptime(text.strip(), "%Y-%m-%d %H:%M:%S.%f").replace(tzinfo=UTC)
    return int(round(stamp.timestamp() * 1e6)) * 1000


def gnss_drive_fixes(path: Path = GNSS_DRIVE) -> list[dict]:
    fixes = []
    with open(path, newline="") as f:
        for seq, row in enumerate(csv.DictReader(f)):
            row = {k.strip(): v.strip() for k, v in row.items()}
            ecef = [float(row["X"]), float(row["Y"]), float(row["Z"])]
            pos_status = SOL_STATUS.get(int(row["PSolStatus"]), "UNKNOWN")
            vel_status = SOL_STATUS.get(int(row["VSolStatus"]), "UNKNOWN")
            no_fix = ecef == [100.0, 0.0, 0.0]
            fixes.append({
                "t": _utc_ns(row["Time"]), "seq": seq, "unit": "gnss0", "protocol": "novatel",
                "valid": pos_status == "SOL_COMPUTED" and not no_fix,
                "pos_status": pos_status, "pos_type": "NONE" if no_fix else "SINGLE",
                "vel_status": vel_status, "vel_type": "DOPPLER_VELOCITY",
                "ecef_m": ecef,
                "ecef_sigma_m": [float(row["stdX"]), float(row["stdY"]), float(row["stdZ"])],
                "vel_ecef_mps": [float(row["VX"]), float(row["VY"]), float(row["VZ"])],
                "vel_sigma_mps": [float(row["stdVX"]), float(row["stdVY"]), float(row["stdVZ"])],
                "vel_latency_s": float(row["VLatency"]), "sol_age_s": float(row["SolAge"]),
                "sats_used": int(row["SolSatNumber"]),
            })
    return fixes


def razor_parked_samples(path: Path, t0_ns: int = 1_494_412_739_000_000_000) -> list[dict]:
    """Samples at the firmware's rate from the row index, SI units, no magnetometer (its
    counts are uncalibrated here and the traction motor disturbs them)."""
    samples = []
    with open(path, newline="") as f:
        for row in csv.DictReader(f):
            row = {k.strip(): v.strip() for k, v in row.items()}
            i = int(row["Index"])
            acc = [float(row[k]) for k in ("accx", "accy", "accz")]
            gyr = [float(row[k]) for k in ("gyrox", "gyroy", "gyroz")]
            samples.append({
                "t": t0_ns + int(round(i * 1e9 / RAZOR_RATE_HZ)), "seq": i, "unit": "imu0",
                "firmware": "viena",
                "accel_mps2": [a * G for a in acc],
                "gyro_radps": [math.radians(w) for w in gyr],
                "mag_T": None,
                "raw": {"accel_g": acc, "gyro_dps": gyr,
                        "mag_counts": [float(row[k]) for k in ("magx", "magy", "magz")],
                        "euler_deg": [float(row[k]) for k in ("yaw", "pitch", "roll")]},
                "board_id": int(row["ID"]),
            })
    return samples
