"""Frame descriptions of common boards (schema ``imu-station/frame/1``), shipped as package data.

Each is usable by name: ``--protocol frame:witmotion``. See ``station.frames.reader``.
"""
