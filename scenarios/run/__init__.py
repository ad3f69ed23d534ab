"""Running a scenario: the simulator loop (``runner``), the sensor streams and their timing
(``streams``), feeding each tick to the estimator and comparing with the truth (``evaluate``),
the per-tick records a run leaves (``records``) and aborting several observers at once
(``observers``)."""
