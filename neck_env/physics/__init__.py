"""Pure, batched physics of the SMA neck (no Gym, no I/O)."""
