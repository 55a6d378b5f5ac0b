"""The items of `scripts/probe_safety.py`, by area; `kit` holds what they share."""
