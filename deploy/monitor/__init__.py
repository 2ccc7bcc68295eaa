"""The operator's view: a local web page fed live from Zenoh (``deploy.monitor.server``)."""
