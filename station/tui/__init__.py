"""The operator's station in the terminal (textual): connect, live view, sequence wizard, results,
long recordings for Allan deviation and temperature sweeps. Nothing imports it but the ``tui`` command."""
