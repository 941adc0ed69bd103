"""The tracker core of paper Section III: pure, deterministic, no I/O, no clock, no randomness.

Nothing here imports Zenoh, Rerun, torch or OpenCV.
"""
