"""ritactl, the operator's client (a laptop needs only the bus library)."""
