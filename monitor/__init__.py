"""The operator's view and the record: the local web page fed live from Zenoh (``monitor.server``),
the Foxglove channels derived from our messages (``monitor.foxglove``), the MCAP recorder
(``monitor.recording``)."""
