"""Grading a user's estimator (``vnav.plugin``) from a test: a scenario's flight run once and
kept, each function judged on its stored detections (``verdict``), and the pytest plugin that
offers it as the ``vnav_judge`` fixture and the ``--vnav-estimator`` option
(``pytest_plugin``, registered through the ``pytest11`` entry point)."""
