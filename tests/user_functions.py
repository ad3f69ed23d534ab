"""Users' estimator functions as source text, for the tests that write them to a file and
judge them (``tests/test_plugin.py`` through ``vnav-demo run --estimator``,
``tests/test_grading.py`` through ``scenarios.grading`` and its pytest plugin).

Each text is top-level code that needs ``numpy`` imported as ``np``; ``SHARED`` holds the
three both files judge, separated as a module's functions are.
"""

from __future__ import annotations

import textwrap

TRANSPOSED = textwrap.dedent("""\
    def transposed(obs):
        # The lecture's classic mistake: R_w_b^T where R_w_b is meant.
        T_w_b = obs.T_w_b.copy()
        T_w_b[:3, :3] = T_w_b[:3, :3].T
        return (T_w_b @ obs.T_b_c @ np.append(obs.p_c, 1.0))[:3]
""")
"""The rotation transposed: the frame-bug doctor's "rotation transposed"."""

RAISES = textwrap.dedent("""\
    def raises(obs):
        raise RuntimeError(f"no idea at t = {obs.t_s:.3f}")
""")
"""A function that raises at every call, naming the image's time."""

NOTHING = textwrap.dedent("""\
    def nothing(obs):
        return None
""")
"""A function that never gives an estimate."""

SHARED = "\n\n".join([TRANSPOSED, RAISES, NOTHING])
"""``transposed``, ``raises`` and ``nothing``, two blank lines apart."""
