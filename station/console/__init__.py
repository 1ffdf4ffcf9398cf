"""What commands show on the terminal: status and phase lines, summaries, the options commands share,
and data placed in Rich markup (:mod:`station.console.markup`)."""
