"""The IEEE 952 noise terms by name, without the fit's libraries (the command line's help needs them)."""

from __future__ import annotations

TERMS = ("Q", "N", "B", "K", "R")
"""Quantization, white noise (angle / velocity random walk), bias instability, rate random walk, rate ramp."""
