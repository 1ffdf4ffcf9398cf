"""PNG plots of engine results (matplotlib, Agg backend)."""
