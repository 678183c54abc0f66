"""Calibration procedures (paper §3-4): image circle, fisheye, extrinsic, time offset,
validation, sensitivity."""
