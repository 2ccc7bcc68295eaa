"""The wire: typed topics and protobuf messages, Zenoh sessions (``Bus``), signing, access control, the
learner session and the ``Node`` lifecycle every process shares. Knows nothing of what the nodes do."""
