"""The IEEE 952 noise terms by name and unit, without the fit's libraries (the command line's help needs
them; the parameter file, the plots and the certificate print them)."""

from __future__ import annotations

import math

from protocols.units import STANDARD_GRAVITY

DEG = 180.0 / math.pi

TERMS = ("Q", "N", "B", "K", "R")
"""Quantization, white noise (angle / velocity random walk), bias instability, rate random walk, rate ramp."""

# SI unit of each term, then (datasheet unit, factor from SI)
UNITS: dict[str, dict[str, tuple[str, str, float]]] = {
    "gyro": {
        "N": ("rad/s/sqrt(Hz)", "deg/sqrt(h)", DEG * 60.0),  # angle random walk
        "K": ("rad/s^2/sqrt(Hz)", "deg/h/sqrt(h)", DEG * 3600.0 * 60.0),  # rate random walk
        "B": ("rad/s", "deg/h", DEG * 3600.0),  # bias instability
        "Q": ("rad", "deg", DEG),  # angle quantization
        "R": ("rad/s^2", "deg/h^2", DEG * 3600.0**2),  # rate ramp
    },
    "accel": {
        "N": ("m/s^2/sqrt(Hz)", "m/s/sqrt(h)", 60.0),  # velocity random walk
        "K": ("m/s^3/sqrt(Hz)", "m/s^2/sqrt(h)", 60.0),  # acceleration random walk
        "B": ("m/s^2", "ug", 1e6 / STANDARD_GRAVITY),  # bias instability
        "Q": ("m/s", "mm/s", 1e3),  # velocity quantization
        "R": ("m/s^3", "m/s^2/h", 3600.0),  # acceleration ramp
    },
}
NAMES = {"N": "white noise (angle / velocity random walk)", "K": "rate random walk", "B": "bias instability",
         "Q": "quantization", "R": "rate ramp"}
SENSOR_AXES = {"gyro": ("gx", "gy", "gz"), "accel": ("ax", "ay", "az")}
