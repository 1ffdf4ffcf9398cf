"""Reports: the calibration certificate of one unit and the fleet report across records (HTML, PDF)."""
