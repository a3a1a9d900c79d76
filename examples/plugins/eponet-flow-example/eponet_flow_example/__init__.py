"""Example third-party eponet plugin package (see plugin.py)."""
