"""Your frame chain: the cone a camera sees, in the world (MIT 16.485 VNAV, lecture 1).

As shipped, ``my_estimate`` holds ONE classic mistake of the lecture's list, on purpose: find
it with vnav-sim rather than by reading (README.md, "Check your own frame chain")::

    .venv/bin/vnav-demo run frame-problem --estimator examples/my_chain.py:my_estimate
    .venv/bin/python -m pytest examples/

The run fails its checks and the frame-bug doctor names the mistake and the chapter; fix it
here, and ``pytest examples/`` passes.
"""

import numpy as np


def my_estimate(obs):
    """The cone's base centre in the world, from one detection.

    Parameters
    ----------
    obs : vnav.plugin.PluginObservation
        One detected cone (every array read-only; docs/CONVENTIONS.md, "Your own estimator"):

        - ``obs.p_c``, shape (3,): the cone's base centre in the camera (optical) frame,
          metres: x right, y down, z forward, as the depth image measures it;
        - ``obs.uv``, shape (2,): its pixel; ``obs.depth_m``: its z; ``obs.K``, (3, 3);
        - ``obs.T_w_b``, (4, 4): the body (x forward, y left, z up) in the world at the
          image's exposure; also ``obs.quat_w_b_xyzw`` (4,) and ``obs.rpy_w_b_deg`` (3,);
        - ``obs.T_b_c``, (4, 4): the camera mount, the optical frame in the body;
        - ``obs.t_s``: the exposure stamp, seconds.

    Returns
    -------
    ndarray, shape (3,)
        The base centre in the world, metres (or None for no estimate).
    """
    R_w_b, t_w_b = obs.T_w_b[:3, :3], obs.T_w_b[:3, 3]
    R_b_c, t_b_c = obs.T_b_c[:3, :3], obs.T_b_c[:3, 3]
    p_b = R_b_c @ obs.p_c + t_b_c  # camera -> body
    p_w = R_w_b.T @ p_b + t_w_b  # body -> world
    return np.asarray(p_w)
