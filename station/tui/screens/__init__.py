"""The screens of the station's TUI, one module each."""
