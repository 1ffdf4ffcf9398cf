"""Sub-commands of ``imu-station``: one module each, registered in ``station.cli.COMMANDS``."""
