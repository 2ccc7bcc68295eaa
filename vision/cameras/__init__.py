"""Camera backends behind one protocol (``protocol.Camera``): ``sim`` (PyBullet) and ``realsense``."""
