"""The estimator's settings: the [estimator] table of the TOML file, and what `Estimator`
takes offline (as this dataclass, or a dict of some of its names)."""
from __future__ import annotations

from dataclasses import dataclass

from viena.common.settings import setting


@dataclass(frozen=True)
class EstimatorSettings:
    """How the filters are tuned, and what input they accept."""
    # frames
    origin: tuple[float, ...] = setting((), "the ENU origin [lat_deg, lon_deg, height_m]; [] = the "
                                            "first good fix", metavar=("LAT_DEG", "LON_DEG", "HEIGHT_M"))
    gnss_lever_arm_m: dict[str, tuple[float, ...]] = setting(
        {}, "each receiver's antenna, unit = [x right, y forward, z up] from the body origin")
    default_lever_arm_m: tuple[float, ...] = setting((0.0, 0.0, 0.0),
                                                     "the antenna of a unit not listed there")
    # attitude
    align_s: float = setting(1.0, "IMU time averaged for the initial roll and pitch (car still)")
    madgwick_beta: float = setting(0.01, "Madgwick's gain while the car stands (or nothing tells "
                                         "its own acceleration), rad/s")
    madgwick_beta_coast: float = setting(0.001, "Madgwick's gain while GNSS velocity is missing, rad/s")
    madgwick_beta_aided: float = setting(0.0, "Madgwick's gain while GNSS velocity corrects the tilt "
                                              "through the Kalman filter, rad/s")
    use_magnetometer: bool = setting(True, "yaw from the magnetometer when its reading is plausible")
    mag_yaw_sigma_deg: float = setting(3.0, "sigma of one magnetometer yaw (at constraint_interval_s)")
    mag_declination_deg: float = setting(-2.48, "positive east; Lisbon 2017 is 2.48 deg west")
    mag_field_nT: tuple[float, ...] = setting((-1121.5, 26479.8, -34884.7),
                                              "the expected field, ENU, to reject disturbances")
    mag_norm_tolerance: float = setting(0.15, "relative error of the field's strength still accepted")
    mag_dip_tolerance_deg: float = setting(5.0, "error of the field's dip still accepted")
    course_heading: bool = setting(True, "yaw from the GNSS course over ground when moving")
    course_min_speed_mps: float = setting(1.0, "slowest speed whose course is used")
    gyro_noise_psd: float = setting(1e-6, "gyro noise of the heading filter, (rad/s)^2/Hz")
    gyro_bias_walk_psd: float = setting(1e-9, "gyro bias random walk, (rad/s)^2/s")
    max_gyro_bias_dps: float = setting(1.0, "the gyro bias learnt stays within this, deg/s")
    # position and velocity
    accel_psd: float = setting(0.05, "accelerometer noise plus tilt errors, (m/s^2)^2/Hz")
    accel_bias_walk_psd: float = setting(1e-6, "accelerometer bias random walk, (m/s^2)^2/s")
    accel_bias_sigma_mps2: tuple[float, ...] = setting(
        (0.05, 0.05, 0.2), "initial accelerometer bias sigma, body x, y, z (levelling takes the "
                           "horizontal bias into the tilt)", metavar=("X", "Y", "Z"))
    tilt_sigma_deg: float = setting(0.5, "initial sigma of the tilt (roll, pitch) once aligned")
    tilt_walk_psd: float = setting(1e-7, "tilt random walk of the attitude, rad^2/s")
    free_accel_psd: float = setting(4.0, "acceleration noise when the IMU cannot drive the "
                                         "prediction, (m/s^2)^2/Hz")
    constraint_interval_s: float = setting(0.1, "period of the non-holonomic and zero-velocity updates")
    nonholonomic: bool = setting(True, "the car does not slide sideways nor jump")
    nhc_sigma_mps: float = setting(0.1, "sigma of the non-holonomic constraint")
    imu_mount_sigma_deg: float = setting(3.0, "how far the IMU's axes may be off the car's before GNSS "
                                              "velocity has shown it (mount.py); 0: the mount is "
                                              "calibrated, nothing is learnt")
    zupt_sigma_mps: float = setting(0.02, "sigma of a zero-velocity update")
    still_gyro_radps: float = setting(0.0, "standstill: gyro rms below this (0: learnt, 3 x what "
                                           "align_s parked show, GNSS not saying it moves, within "
                                           "0.01 .. 0.05) ...")
    still_accel_mps2: float = setting(0.0, "... and specific force this close to gravity (0: learnt, "
                                           "3 x align_s parked, within 0.2 .. 1.0) ...")
    still_speed_mps: float = setting(0.3, "... and GNSS and filter speeds below this")
    gate_chi2: float = setting(16.27, "innovation test (3 dof, 99.9 %)")
    max_pos_sigma_m: float = setting(50.0, "fixes with a larger position sigma are not used")
    vel_sigma_default_mps: float = setting(0.2, "velocity sigma of a fix that carries none")
    use_vel_latency: bool = setting(True, "a fix's velocity is older than its t by its latency")
    gnss_vel_latency_s: dict[str, float] = setting(
        {}, "each receiver's velocity latency, unit = s, instead of the fix's vel_latency_s "
            "(receivers that do not send it: NMEA)")
    admit_hold_s: float = setting(10.0, "a receiver's fixes pass every check this long before it is used "
                                        "(admission.py; PX4 EKF2's 10 s)")
    admit_min_sats: int = setting(5, "admission: fewest satellites in the solution (when the fix says; "
                                     "PX4: 6, the car's OEM4 mostly has 5-7)")
    admit_max_sigma_h_m: float = setting(10.0, "admission: largest horizontal sigma (PX4: 3 m for a drone's "
                                               "receiver; the car's OEM4 reports 3-4 m, up to 15)")
    admit_max_sigma_v_m: float = setting(15.0, "admission: largest vertical sigma")
    admit_max_speed_sigma_mps: float = setting(2.0, "admission: largest horizontal speed sigma (the car's "
                                                    "OEM4: 0.6 m/s typical)")
    admit_max_drift_mps: float = setting(1.0, "admission: while the car stands, the fixes' smoothed motion "
                                              "and reported speed stay below this (PX4: 0.1 for a u-blox; a "
                                              "standalone receiver parked in multipath moves more)")
    gnss_reset_s: float = setting(5.0, "good fixes rejected this long: trust GNSS, reinitialise")
    gnss_max_rate_hz: float = setting(10.0, "fixes used per second and receiver; 0 = every fix")
    # what makes GNSS errors correlated
    gnss_bias_tau_s: float = setting(600.0, "correlation time of a receiver's slowly wandering error")
    gnss_common_fraction: float = setting(0.8, "correlation of two receivers' wandering errors (one sky; each "
                                                  "antenna has its own multipath and satellites)")
    gnss_consider_errors: bool = setting(True, "the receivers' wandering errors widen every gain and "
                                               "covariance but are never estimated (Schmidt)")
    gnss_white_fraction: float = setting(0.1, "share of a fix's variance taken as white until the "
                                              "fixes show theirs")
    gnss_sigma_floor_m: dict[str, tuple[float, ...]] = setting(
        {"sbas": (0.5, 1.0), "dgps": (0.5, 1.0), "float": (0.1, 0.2), "fixed": (0.02, 0.04)},
        "the least sigma a fix of each solution kind is taken with, kind = [horizontal, vertical] "
        "in m (an over-optimistic receiver cannot make the filter brittle); float and fixed: their "
        "white noise, the rest of their sigma wanders")
    imu_time_sigma_s: float = setting(0.02, "how far the IMU's stamps may be off the GNSS clock, s")
    # time
    late_window_s: float = setting(1.0, "how late a GNSS fix may be and still be used")
    imu_timeout_s: float = setting(0.5, "IMU silent this long: not live")
    imu_gap_s: float = setting(0.2, "larger steps between IMU samples are not integrated (and the "
                                    "sample after one waits for the next to confirm it)")
    gnss_timeout_s: float = setting(2.0, "no usable fix from a receiver this long: it is not live")
    max_future_s: float = setting(2.0, "inputs further ahead of the clock are rejected")
    # input limits
    max_accel_g: float = setting(16.0, "larger accelerations are rejected (the ADXL345's range)")
    max_gyro_dps: float = setting(2000.0, "larger rotation rates are rejected (the ITG-3200's range)")
