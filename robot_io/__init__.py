"""robot_io."""
