"""Fusion stages: appearance features and the motion map to the foreground probability."""
