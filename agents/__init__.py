"""Controllers, SB3 training support and the benchmark for NeckTrack-v0."""
