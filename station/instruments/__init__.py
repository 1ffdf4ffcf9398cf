"""The lab's instruments as the station uses them: opened by URL from their description files,
held to the plan's limits, and left safe on any way out (``shared/specs/instruments.md``)."""
