"""The ``twin`` command line: the top of the stack. It wires estimation, the wire, the twin and the scenes
together; nothing below imports it."""
