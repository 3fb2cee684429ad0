"""The Razor 9DOF IMU (SparkFun SEN-10125) of the car, in the three rooms of every device:

- `driver`: the wire protocols (the car's VIENA firmware frames, the stock Razor AHRS
  firmware), bytes in, frames out; no zenoh, usable from a shell;
- `service`: viena-imu, calibrated samples on zenoh (`sample` owns viena.imu.sample/1);
- `simulator`: twins that speak the same bytes, from the simulated car or a recording.

`calibration` (models and the TOML file), `fitting` (the least squares) and
`calibration_cli` make `viena calibrate imu`; `bench` is `viena bench imu`.
"""
