"""The simulated IMU: MuJoCo's accelerometer and gyro at the IMU site, sampled with noise.

The site sits at the IMU's true mount (``sim.config.ImuConfig.T_b_i``, placed by
``sim.world.build_spec``). MuJoCo's ``accelerometer`` reads the specific force at the site in
the site frame (``+g`` up at rest: its spatial accelerations ``cacc``, computed by
``mj_rnePostConstraint`` during the sensor stage, start from the negated gravity), its
``gyro`` the angular velocity in the site frame; ``vnav.imu.specific_force_i`` and
``vnav.imu.angular_rate_i`` give the same from the body's motion (``imu_discrepancy``, to
about 1e-15).

``ImuSampler`` takes reading ``j`` at the physics step nearest ``j / rate_hz``, as the step
is taken (``sim.world.World.on_step``: the state it starts from, its accelerometer under the
controls the step applies, the acceleration MuJoCo's integrator moves the body by; the
forward pass after the previous step had it under that step's controls, a step behind),
moves both sensors to that instant (MuJoCo's gyro reads the rate of the step before, half a
step earlier, and its accelerometer's centripetal term that rate's: ``to_stamp``; the gyro to
fourth order once the step after is known, ``rate_correction_i``), adds the noise of
``vnav.imu.ImuNoiseProcess`` (Kalibr's model: white noise and a bias random walk per axis,
from the run's seed), and stamps it on the IMU's clock.

A run reads the IMU at every physics step: there ``ImuSteps`` keeps each step's state (one
array) and the readings, the chain and the discrepancy are made for every step at once at the
end (``to_stamp_many``, ``chain_imu_many_i``, ``imu_discrepancy_many``,
``ImuSampler.sample_many``), equal to the per-step functions' to the last bit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim import names
from sim.config import ImuConfig
from sim.world import World
from vnav.imu import ImuNoiseProcess, angular_rate_i, specific_force_i

__all__ = [
    "ACCEL_SCALE_M_S2",
    "GYRO_SCALE_RAD_S",
    "ImuReading",
    "ImuSampler",
    "ImuSteps",
    "chain_imu_i",
    "chain_imu_many_i",
    "imu_discrepancy",
    "imu_discrepancy_many",
    "mujoco_imu_i",
    "rate_correction_i",
    "to_stamp",
    "to_stamp_many",
]

ACCEL_SCALE_M_S2 = 1.0
"""Below this magnitude an accelerometer discrepancy is measured absolutely (m/s^2)."""
GYRO_SCALE_RAD_S = 1.0
"""Below this magnitude a gyro discrepancy is measured absolutely (rad/s)."""


@dataclass(frozen=True)
class ImuReading:
    """One IMU reading.

    Attributes
    ----------
    t_s : float
        The stamp, on the IMU's clock, seconds.
    accel_i : ndarray, shape (3,)
        Specific force in the IMU frame, m/s^2 (noise and bias included).
    gyro_i : ndarray, shape (3,)
        Angular rate in the IMU frame, rad/s (noise and bias included).
    """

    t_s: float
    accel_i: np.ndarray
    gyro_i: np.ndarray


def mujoco_imu_i(world: World) -> tuple[np.ndarray, np.ndarray]:
    """MuJoCo's own accelerometer and gyro at the IMU site, now (noise-free).

    Returns
    -------
    accel_i : ndarray, shape (3,)
        m/s^2, site (IMU) axes.
    gyro_i : ndarray, shape (3,)
        rad/s, site (IMU) axes.
    """
    data = world.data.sensordata
    a, g = world.imu_accel_adr, world.imu_gyro_adr
    return data[a : a + 3].copy(), data[g : g + 3].copy()


def chain_imu_i(world: World) -> tuple[np.ndarray, np.ndarray]:
    """What ``vnav.imu``'s chain predicts a noise-free IMU at the site reads, now.

    The chain is fed the body's true motion (``T_w_b``, ``acceleration_w``,
    ``angular_velocity_b``, ``angular_acceleration_b``), the site's mount ``world.T_b_i`` and
    the model's gravity.

    Returns
    -------
    f_i : ndarray, shape (3,)
        Specific force, m/s^2, IMU axes (``vnav.imu.specific_force_i``).
    omega_i : ndarray, shape (3,)
        Angular rate, rad/s, IMU axes (``vnav.imu.angular_rate_i``).
    """
    T_b_i = world.T_b_i
    f_i = specific_force_i(
        world.T_w_b,
        T_b_i,
        world.acceleration_w,
        world.angular_velocity_b,
        world.angular_acceleration_b,
        gravity_w=world.model.opt.gravity,
    )
    return f_i, angular_rate_i(T_b_i, world.angular_velocity_b)


def imu_discrepancy(world: World, chain: tuple[np.ndarray, np.ndarray] | None = None) -> float:
    """How far MuJoCo's sensors are from ``vnav.imu``'s chain, now: the larger of the two
    relative errors ``|mujoco - vnav| / max(|mujoco|, scale)`` (scale: ``ACCEL_SCALE_M_S2``,
    ``GYRO_SCALE_RAD_S``; absolute below it, where a relative error means nothing).

    ``chain`` is ``chain_imu_i(world)`` if the caller has it already (computed here otherwise).
    """
    accel_i, gyro_i = mujoco_imu_i(world)
    f_i, omega_i = chain_imu_i(world) if chain is None else chain
    e_a = np.linalg.norm(accel_i - f_i) / max(float(np.linalg.norm(accel_i)), ACCEL_SCALE_M_S2)
    e_g = np.linalg.norm(gyro_i - omega_i) / max(float(np.linalg.norm(gyro_i)), GYRO_SCALE_RAD_S)
    return float(max(e_a, e_g))


def chain_imu_many_i(
    T_w_b: np.ndarray,
    T_b_i: np.ndarray,
    acceleration_w: np.ndarray,
    angular_velocity_b: np.ndarray,
    angular_acceleration_b: np.ndarray,
    gravity_w: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """``chain_imu_i`` of many states at once, from the body's motion at each.

    The same numpy operations on stacks (``vnav.imu``'s functions are batched), so each row
    equals ``chain_imu_i`` of its state to the last bit (``tests/test_sim_imu.py``).

    Parameters
    ----------
    T_w_b : ndarray, shape (N, 4, 4)
    T_b_i : ndarray, shape (4, 4)
    acceleration_w : ndarray, shape (N, 3)
        m/s^2.
    angular_velocity_b, angular_acceleration_b : ndarray, shape (N, 3)
        rad/s and rad/s^2, body axes.
    gravity_w : ndarray, shape (3,)
        The model's gravity, m/s^2.

    Returns
    -------
    f_i, omega_i : ndarray, shape (N, 3)
        m/s^2 and rad/s, IMU axes.

    Raises
    ------
    ValueError
        As ``vnav.imu.specific_force_i``: a transform not rigid, a vector not (N, 3) or not
        finite.
    """
    f_i = specific_force_i(
        T_w_b,
        T_b_i,
        acceleration_w,
        angular_velocity_b,
        angular_acceleration_b,
        gravity_w=gravity_w,
    )
    return f_i, angular_rate_i(T_b_i, angular_velocity_b)


def imu_discrepancy_many(
    accel_i: np.ndarray, gyro_i: np.ndarray, f_i: np.ndarray, omega_i: np.ndarray
) -> np.ndarray:
    """``imu_discrepancy`` of many states, (N,): MuJoCo's sensors ``accel_i``, ``gyro_i``
    against the chain's ``f_i``, ``omega_i``, each (N, 3).

    The norms are ``np.vecdot``'s, the dot product ``np.linalg.norm`` takes of a vector: each
    element equals ``imu_discrepancy`` of its state to the last bit.
    """

    def norm(v: np.ndarray) -> np.ndarray:
        return np.sqrt(np.vecdot(v, v))

    e_a = norm(accel_i - f_i) / np.maximum(norm(accel_i), ACCEL_SCALE_M_S2)
    e_g = norm(gyro_i - omega_i) / np.maximum(norm(gyro_i), GYRO_SCALE_RAD_S)
    return np.maximum(e_a, e_g)


def to_stamp(
    world: World, accel_i: np.ndarray, gyro_i: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Noise-free readings of the state now (``mujoco_imu_i`` or ``chain_imu_i``) moved to
    what the IMU's motion over the physics steps either side of now is, called as the step is
    taken (``World.on_step``: the accelerations under the controls it applies).

    MuJoCo's (semi-implicit Euler) step ``n`` moves the body by ``v_{n+1} = v_n + dt a_n``,
    ``x_{n+1} = x_n + dt v_{n+1}`` and turns it by ``exp(omega_{n+1} dt)``, with the rate
    after the step, ``omega_{n+1} = omega_n + dt alpha_n``. The gyro's ``omega_n`` is the rate
    over the step *before* now, centred half a step early: the rate now is the mean of the
    steps' either side, ``omega_n + (dt / 2) alpha_n``. The IMU's position ``x + R t_b_i``
    then has the central second difference ``a_n + alpha_n x r + (c(omega_n) +
    c(omega_{n+1})) / 2`` (``c(w) = w x (w x r)``, ``r`` the lever arm): the accelerometer's
    centripetal term ``c(omega_n)`` moves by half the difference (the body-origin and
    tangential terms are already the step's).

    Parameters
    ----------
    world : World
    accel_i, gyro_i : ndarray, shape (3,)
        m/s^2 and rad/s, IMU axes.

    Returns
    -------
    accel_i, gyro_i : ndarray, shape (3,)
        New arrays.
    """
    dt_s = float(world.model.opt.timestep)
    T_b_i = world.T_b_i
    r_b = T_b_i[:3, 3]
    omega_b = world.angular_velocity_b
    omega_next_b = omega_b + dt_s * world.angular_acceleration_b
    c_b = np.cross(omega_b, np.cross(omega_b, r_b))
    c_next_b = np.cross(omega_next_b, np.cross(omega_next_b, r_b))
    # Body to IMU axes, row-wise: v_i = R_i_b v_b = v_b @ R_b_i.
    R_b_i = T_b_i[:3, :3]
    accel = accel_i + (0.5 * (c_next_b - c_b)) @ R_b_i
    gyro = gyro_i + (0.5 * dt_s * world.angular_acceleration_b) @ R_b_i
    return accel, gyro


def to_stamp_many(
    timestep_s: float,
    T_b_i: np.ndarray,
    accel_i: np.ndarray,
    gyro_i: np.ndarray,
    angular_velocity_b: np.ndarray,
    angular_acceleration_b: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """``to_stamp`` of many readings at once, from the body's rate and angular acceleration
    at each reading's step (what ``to_stamp`` reads of the world).

    The same operations on stacks: each row equals ``to_stamp``'s to the last bit
    (``tests/test_sim_imu.py``).

    Parameters
    ----------
    timestep_s : float
        The physics step, seconds.
    T_b_i : ndarray, shape (4, 4)
        The IMU's mount.
    accel_i, gyro_i : ndarray, shape (K, 3)
        m/s^2 and rad/s, IMU axes.
    angular_velocity_b, angular_acceleration_b : ndarray, shape (K, 3)
        rad/s and rad/s^2, body axes.

    Returns
    -------
    accel_i, gyro_i : ndarray, shape (K, 3)
        New arrays.
    """
    dt_s = float(timestep_s)
    r_b = T_b_i[:3, 3]
    omega_b = angular_velocity_b
    omega_next_b = omega_b + dt_s * angular_acceleration_b
    c_b = np.cross(omega_b, np.cross(omega_b, r_b))
    c_next_b = np.cross(omega_next_b, np.cross(omega_next_b, r_b))
    R_b_i = T_b_i[:3, :3]
    accel = accel_i + (0.5 * (c_next_b - c_b)) @ R_b_i
    gyro = gyro_i + (0.5 * dt_s * angular_acceleration_b) @ R_b_i
    return accel, gyro


def rate_correction_i(omega_b: np.ndarray, steps: np.ndarray, R_b_i: np.ndarray) -> np.ndarray:
    """What to add to gyro readings (``to_stamp``'s, second order) for the rate at their
    stamps to fourth order, (K, 3) rad/s in IMU axes.

    MuJoCo turns the body over step ``k - 1 -> k`` at the constant rate ``omega_k``: the
    rates are the averages of the body's rate over the steps, and the rate at the instant
    between two steps is, to fourth order, ``(-omega_{n-1} + 7 omega_n + 7 omega_{n+1} -
    omega_{n+2}) / 12`` (the cubic through four cell averages, as finite-volume schemes
    reconstruct a point value), where ``to_stamp`` gives their mean, off by ``dt^2 / 12``
    times the change of angular acceleration: a camera-IMU calibration (``vnav.imu_calibration``)
    reads that as millimetres of lever arm.

    Parameters
    ----------
    omega_b : ndarray, shape (N + 1, 3)
        The body's rate at steps ``0 .. N`` (``World.angular_velocity_b`` as each step is
        taken, the last the one the last step leaves), rad/s.
    steps : ndarray of int, shape (K,)
        The step of each reading, in ``0 .. N - 1``.
    R_b_i : ndarray, shape (3, 3)
        The IMU's mount rotation.

    Returns
    -------
    ndarray, shape (K, 3)
        The beyond ends are extrapolated linearly (the rate before step 0, after step N).
    """
    w = np.asarray(omega_b, dtype=np.float64).reshape(-1, 3)
    if len(w) < 2:
        return np.zeros((len(steps), 3))
    w = np.concatenate([2.0 * w[:1] - w[1:2], w, 2.0 * w[-1:] - w[-2:-1]])
    n = np.asarray(steps, dtype=np.int64) + 1  # w[n] is omega_n now
    fourth = (-w[n - 1] + 7.0 * w[n] + 7.0 * w[n + 1] - w[n + 2]) / 12.0
    # Body to IMU axes, row-wise.
    return (fourth - 0.5 * (w[n] + w[n + 1])) @ R_b_i


class ImuSampler:
    """The IMU of a ``World``: readings at ``config.rate_hz``, with noise, on the IMU's clock.

    Parameters
    ----------
    config : ImuConfig
        Rate and noise figures (the mount is the world's: its site).
    timestep_s : float
        The physics step, seconds (``world.model.opt.timestep``).
    rng : numpy.random.Generator
        The noise's draws (from the run's seed).
    clock_offset_s : float
        ``t_imu = t_sim + clock_offset_s``: how the simulator's time reads on the IMU's clock.
        With the camera's ``t_pose = t_cam + camera_clock_offset_s`` (the pose clock being the
        simulator's) and Kalibr's ``t_imu = t_cam + time_offset_s``, it is
        ``time_offset_s - camera_clock_offset_s``.

    Raises
    ------
    ValueError
        If the rate exceeds the physics rate, or an argument has the wrong type.
    """

    def __init__(
        self,
        config: ImuConfig,
        timestep_s: float,
        rng: np.random.Generator,
        clock_offset_s: float = 0.0,
    ) -> None:
        if not isinstance(config, ImuConfig):
            raise ValueError(f"config must be an ImuConfig, got {type(config).__name__}")
        if not timestep_s > 0.0:
            raise ValueError(f"timestep_s must be > 0, got {timestep_s!r}")
        if config.rate_hz > 1.0 / timestep_s + 1e-9:
            raise ValueError(
                f"config.rate_hz ({config.rate_hz:g} Hz) must be at most the physics rate, "
                f"{1.0 / timestep_s:g} Hz"
            )
        self.config = config
        self.timestep_s = float(timestep_s)
        self.clock_offset_s = float(clock_offset_s)
        self.process = ImuNoiseProcess(config.noise, 1.0 / config.rate_hz, rng)
        self.count = 0
        """Readings taken so far (the next one is reading ``count``)."""

    @property
    def next_step(self) -> int:
        """The physics step after which the next reading is due: nearest ``count / rate_hz``."""
        return round(self.count / self.config.rate_hz / self.timestep_s)

    def due(self, world: World) -> bool:
        """Whether the world's current physics step is the next reading's."""
        return round(world.time_s / self.timestep_s) >= self.next_step

    def sample(self, world: World) -> ImuReading:
        """The next reading, from the world's state now: MuJoCo's sensors, the gyro's moved to
        the stamp's instant, plus the noise.

        Called as step ``n`` is taken (``World.on_step``), its controls set, so that the
        accelerometer reads the acceleration the step applies; both sensors are then moved to
        the motion about the stamp (``to_stamp``): the reading is the IMU's rate and the
        central second difference of its positions, to second order."""
        accel_i, gyro_i = to_stamp(world, *mujoco_imu_i(world))
        if not self.config.noise.is_zero:
            da, dg = self.process.next()
            accel_i += da
            gyro_i += dg
        self.count += 1
        return ImuReading(world.time_s + self.clock_offset_s, accel_i, gyro_i)

    def take_due(self, world: World) -> bool:
        """Whether the world's current physics step is the next reading's; if so, counts it
        as taken (its value is made afterwards, with the others, by ``sample_many``)."""
        if self.due(world):
            self.count += 1
            return True
        return False

    def sample_many(
        self, time_s: np.ndarray, accel_i: np.ndarray, gyro_i: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The readings of noise-free sensors already moved to their stamps (``to_stamp_many``),
        at simulated times ``time_s``: the noise of as many readings added, stamped on the
        IMU's clock.

        The noise is ``ImuNoiseProcess.series``'s, which equals as many ``sample`` calls' to
        the last bit when the process starts with zero biases (a new sampler's): made once,
        at the end of a run, this is what ``sample`` at each reading would have given.

        Parameters
        ----------
        time_s : ndarray, shape (K,)
            Simulated seconds.
        accel_i, gyro_i : ndarray, shape (K, 3)
            m/s^2 and rad/s, IMU axes.

        Returns
        -------
        t_s : ndarray, shape (K,)
            The stamps, IMU clock, seconds.
        accel_i, gyro_i : ndarray, shape (K, 3)
            New arrays.
        """
        accel_i, gyro_i = accel_i.copy(), gyro_i.copy()
        if not self.config.noise.is_zero:
            da, dg = self.process.series(len(time_s))
            accel_i += da
            gyro_i += dg
        return time_s + self.clock_offset_s, accel_i, gyro_i


# Columns of a step's row: the time, MuJoCo's accelerometer and gyro, the body's rate,
# its acceleration and angular acceleration (the free joint's qacc), its pose.
_STEP_COLUMNS = {
    "time_s": slice(0, 1),
    "accel_i": slice(1, 4),
    "gyro_i": slice(4, 7),
    "angular_velocity_b": slice(7, 10),
    "acceleration_w": slice(10, 13),
    "angular_acceleration_b": slice(13, 16),
    "R_w_b": slice(16, 25),
    "t_w_b": slice(25, 28),
}


class ImuSteps:
    """What the IMU reads of a ``World`` at each physics step, kept as the step is taken
    (``take``, from ``World.on_step``) and stacked afterwards (``stacked``): the readings, the
    chain and the discrepancy are then computed for every step at once (``to_stamp_many``,
    ``chain_imu_many_i``, ``imu_discrepancy_many``), equal to the last bit to what the
    per-step functions give, at a few microseconds a step instead of a millisecond.

    Parameters
    ----------
    world : World
        The world whose steps are read (its model's addresses are looked up once).
    """

    def __init__(self, world: World) -> None:
        m = world.model
        self._accel = slice(world.imu_accel_adr, world.imu_accel_adr + 3)
        self._gyro = slice(world.imu_gyro_adr, world.imu_gyro_adr + 3)
        dof = int(m.joint(names.DRONE_JOINT).dofadr[0])
        self._omega = slice(dof + 3, dof + 6)
        self._qacc = slice(dof, dof + 6)
        self._body = world.body_id
        self._rows: list[np.ndarray] = []

    def __len__(self) -> int:
        return len(self._rows)

    def take(self, world: World) -> None:
        """Keep the world's state now (one array a step: no other object is made)."""
        d = world.data
        sd = d.sensordata
        self._rows.append(
            np.concatenate(
                (
                    (d.time,),
                    sd[self._accel],
                    sd[self._gyro],
                    d.qvel[self._omega],
                    d.qacc[self._qacc],
                    d.xmat[self._body],
                    d.xpos[self._body],
                )
            )
        )

    def stacked(self) -> dict[str, np.ndarray]:
        """Every step's state: ``time_s`` (N,), ``accel_i``, ``gyro_i`` (MuJoCo's sensors,
        IMU axes), ``angular_velocity_b``, ``acceleration_w``, ``angular_acceleration_b``
        (N, 3) and ``T_w_b`` (N, 4, 4), as ``World``'s properties read them."""
        rows = np.array(self._rows).reshape(-1, 28)
        # Contiguous columns, as the properties' copies are (numpy's kernels for a strided
        # operand could sum in another order).
        out = {k: np.ascontiguousarray(rows[:, c]) for k, c in _STEP_COLUMNS.items()}
        out["time_s"] = out["time_s"][:, 0]
        T_w_b = np.zeros((len(rows), 4, 4))
        T_w_b[:, :3, :3] = out.pop("R_w_b").reshape(-1, 3, 3)
        T_w_b[:, :3, 3] = out.pop("t_w_b")
        T_w_b[:, 3, 3] = 1.0
        out["T_w_b"] = T_w_b
        return out
