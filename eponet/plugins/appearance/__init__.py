"""Appearance stages: per-frame feature maps for the fusion stage."""
