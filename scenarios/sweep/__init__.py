"""Sweeps: one scenario run over a grid of parameter values and many seeds.

``vnav-demo sweep FILE.toml`` (``scenarios.commands.sweep``)::

    plan      scenarios.sweep.plan      the sweep file; every grid point parsed as a scenario
    rows      scenarios.sweep.rows      an episode's row and estimates: the columns
    episode   scenarios.sweep.episode   one (point, seed): run, judge, one row of numbers
    engine    scenarios.sweep.engine    episodes in this process or on Ray actors
    store     scenarios.sweep.store     journal, results.parquet, estimates.parquet, --resume
    summary   scenarios.sweep.summary   summary.json: statistics per grid point, worst seeds
    plots     scenarios.sweep.plots     PNG: error against each swept key and against range

Ray and pyarrow are the optional extra ``vnav-sim[sweep]``; only ``engine`` (Ray) and
``store`` (pyarrow) import them, when a sweep runs.
"""
