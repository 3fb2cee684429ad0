"""The black box: `viena-recorder` records every key of the car, always, into a drive of
split MCAP files within a disk budget (common/drive_files.py writes them, common/recorder.py
listens). A service with no device: no driver, model or simulator room."""
