"""Emulators of the lab instruments (``shared/specs/instruments.md``): each speaks a real
instrument's bytes on a pty or a loopback TCP port and is coupled to the simulated unit."""
