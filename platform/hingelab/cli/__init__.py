"""The ``hingelab`` command: one module per verb, registered in ``main``."""
