"""Foxglove's view of the stack: well-known messages derived from ours, and the live WebSocket server.

``derive`` turns our messages into Foxglove's well-known schemas (image, transforms, 3D scene, log);
the recorder writes them beside the raw channels and ``live`` serves the same channels to Foxglove's
app over its WebSocket protocol, so a recording and the live stack open in the same layout
(``configs/foxglove_layout.json``).
"""
