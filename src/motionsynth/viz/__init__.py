"""Plots, animations and BVH export."""
