"""Plumbing every layer of the station uses: atomic files and output sets, bounded YAML, text safe
to print, tables, units, lazy exports and the old module paths."""
