"""Names of the elements of the MuJoCo models, in one place.

Code looks elements up by these names (``model.body(names.DRONE_BODY)``), never by raw index.
"""

from __future__ import annotations

DRONE_BODY = "drone"
"""The quadrotor's body; its origin is the centre of mass (vnav frame ``b``)."""
DRONE_JOINT = "drone_root"
"""The free joint of the quadrotor."""
IMU_SITE = "imu"
"""The IMU's site on the drone body: at the true mount of a declared ``[imu]``
(``sim.world.build_spec``), else at the body origin."""
IMU_ACCEL = "imu_accel"
"""MuJoCo's accelerometer at ``IMU_SITE``: specific force in the site frame, m/s^2."""
IMU_GYRO = "imu_gyro"
"""MuJoCo's gyro at ``IMU_SITE``: angular velocity in the site frame, rad/s."""
THRUST_SITES: tuple[str, ...] = ("thrust_fl", "thrust_rl", "thrust_rr", "thrust_fr")
"""Rotor sites: front-left, rear-left, rear-right, front-right (thrust along site +z)."""
MOTORS: tuple[str, ...] = ("motor_fl", "motor_rl", "motor_rr", "motor_fr")
"""Rotor thrust actuators, in the order of ``THRUST_SITES``."""

ONBOARD_CAMERA = "onboard"
"""The body-mounted camera (MuJoCo/OpenGL convention inside sim, optical outside)."""
CHASE_CAMERA = "chase"
"""An external camera that follows the drone from behind and above (shows the drone)."""

GROUND_GEOM = "ground"
SUN_LIGHT = "sun"


def cone_body(index: int) -> str:
    """Name of the body of cone ``index``."""
    return f"cone_{index}"


def cone_base_geom(index: int) -> str:
    """Name of the base-plate geom of cone ``index``."""
    return f"cone_{index}_base"


def cone_shell_geom(index: int) -> str:
    """Name of the conical-body geom of cone ``index``."""
    return f"cone_{index}_shell"


CONE_MESH = "traffic_cone"
CONE_MATERIAL = "cone_orange"

DRONE_GEOM_GROUP = 3
"""Geom group of every drone geom; the onboard view disables it, external views enable it."""
