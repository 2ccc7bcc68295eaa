"""Machinery shared by every layer (bottom of the import graph: imports nothing of ours)."""
