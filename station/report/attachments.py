"""The names a factory record gives the files the reports read and write (``Attachment.name``).

Kept apart from the report modules so that reading them (the fleet report links certificates)
imports nothing heavy.
"""

RAW_CAPTURE = "raw capture"
"""The sequence's labelled capture (``capture.csv``): the certificate's residuals per pose."""
PARAMS_ATTACHMENT = "parameter file"
"""The run's parameter file (``params.yaml``): the certificate's parameters."""
CERTIFICATE_NAME = "calibration certificate"
"""The certificate a factory run writes beside its record (``certificate.html``)."""
