"""The ``vnav-demo`` verbs, one module each (``run``, ``sweep``, ``calibrate``, ``lecture``,
``list``, ``show``), and what they share (``common``: exit codes, input errors, signal
handling, output locking; ``console``: writing to the terminal)."""
